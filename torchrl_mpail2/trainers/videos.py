"""Evaluation videos: frames from ``env.render()`` written as mp4 files (imageio with its ffmpeg plugin) and shaped
for TorchRL's loggers."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

__all__ = ["VIDEO_FPS", "check_can_film", "video_tensor", "write_videos"]

#: Frame rate of the videos: the robosuite control rate (the point mass has no clock of its own).
VIDEO_FPS = 20


def check_can_film(env) -> None:
    """Raises a clear error, before any training, when ``train.video`` cannot work."""
    if not callable(getattr(env, "render", None)):
        raise ValueError(f"train.video=true needs an env with render(); {type(env).__name__} has none")
    try:
        import imageio_ffmpeg  # noqa: F401
    except ImportError as error:
        raise ImportError("train.video=true writes mp4 with imageio-ffmpeg: pip install 'torchrl-mpail2[video]'") from error


def write_videos(videos: list[np.ndarray], folder: Path, stem: str) -> list[Path]:
    """Writes each ``[T, H, W, 3]`` uint8 array as ``folder/{stem}_{i}.mp4`` (via a temporary name); returns the paths."""
    import imageio

    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for i, frames in enumerate(videos):
        path = folder / f"{stem}_{i}.mp4"
        tmp = path.with_suffix(".tmp.mp4")
        with imageio.get_writer(tmp, fps=VIDEO_FPS, macro_block_size=1) as writer:
            for frame in frames:
                writer.append_data(frame)
        tmp.replace(path)
        paths.append(path)
    return paths


def video_tensor(videos: list[np.ndarray]) -> torch.Tensor:
    """The ``[B, T, C, H, W]`` uint8 tensor of TorchRL's ``Logger.log_video`` from ``B`` arrays ``[T_i, H, W, 3]``;
    a shorter episode holds its last frame to the longest one's end."""
    length = max(len(frames) for frames in videos)
    padded = [np.concatenate([frames, np.repeat(frames[-1:], length - len(frames), axis=0)]) for frames in videos]
    return torch.from_numpy(np.stack(padded)).permute(0, 1, 4, 2, 3).contiguous()
