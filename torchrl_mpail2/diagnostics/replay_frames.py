r"""Are a run's camera frames renders? Reads the frames a run stored in its replay and flags those that cannot be a
render of the scene: noise (uninitialised memory) or mostly black.

    python -m torchrl_mpail2.diagnostics replay_frames RUN_OR_CHECKPOINT [--plot FILE] [--out FILE]

``RUN_OR_CHECKPOINT`` is a run folder (its live ``replay_storage``) or a checkpoint folder (its ``replay/storage``).
A frame is flagged when its roughness, the mean absolute difference of horizontally adjacent pixels,

.. math:: \rho = \frac{1}{3 H (W - 1)} \sum_{c, y, x} |I_{c, y, x + 1} - I_{c, y, x}|,

exceeds ``NOISE_ROUGHNESS`` (rendered 64 x 64 frames of Lift and Push: at most about 12; uniform noise: about 85),
or when more than ``BLACK_FRACTION`` of its pixels are black (a render of these scenes has almost none): the check
of :func:`~torchrl_mpail2.envs.robosuite_observations.unrendered`, which the robosuite envs run on every frame. A frame
read from a GL context that rendered nothing is whatever the buffer held: noise, black, or an old frame; the last
passes this check, so the counts are a lower bound. Episodes are counted from the replay's ``is_init`` flags.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch
from tensordict import TensorDict
from torch import Tensor

from torchrl_mpail2.diagnostics.figures import save_figure
from torchrl_mpail2.envs.robosuite_observations import unrendered


def storage_path(path: str | Path) -> Path:
    """The replay storage folder of a run folder or a checkpoint folder.

    Raises:
        FileNotFoundError: neither ``path`` nor its ``replay_storage`` or ``replay/storage`` holds a storage.
    """
    path = Path(path)
    for candidate in (path / "replay_storage", path / "replay" / "storage", path):
        if (candidate / "meta.json").exists():
            return candidate
    raise FileNotFoundError(f"{path}: no replay storage (looked for replay_storage/, replay/storage/ and the folder "
                            "itself)")


def broken_frames(frames: Tensor) -> Tensor:
    """``[N, 3, H, W]`` uint8 frames -> ``[N]`` bool: noise or mostly black
    (:func:`~torchrl_mpail2.envs.robosuite_observations.unrendered`)."""
    return torch.from_numpy(np.asarray(unrendered(frames.numpy()))).reshape(frames.shape[0])


def frame_report(path: str | Path) -> dict:
    """Per image key of the replay at ``path``: stored frames, flagged frames, and the flagged fraction per
    episode."""
    td = TensorDict.load_memmap(storage_path(path))
    filled = td["next", "step_count"].reshape(-1) > 0  # every stored transition has taken a step
    stored = int(filled.nonzero().max()) + 1 if filled.any() else 0
    episode = td["is_init"].reshape(-1)[:stored].long().cumsum(0)  # 1 for the first episode
    report = {"path": str(path), "transitions": stored, "episodes": int(episode.max()) if stored else 0, "keys": {}}
    for key in ("external_image", "wrist_image"):
        if key not in td.keys():
            continue
        flagged = torch.cat([broken_frames(td[key][start:min(start + 1000, stored)])
                             for start in range(0, stored, 1000)]) if stored else torch.zeros(0, dtype=torch.bool)
        per_episode = torch.zeros(report["episodes"]).index_add_(0, episode - 1, flagged.float())
        per_episode /= torch.bincount(episode - 1, minlength=report["episodes"]).clamp_min(1)
        bad = (per_episode > 0.5).nonzero().flatten() + 1
        report["keys"][key] = {
            "flagged": int(flagged.sum()), "flagged_fraction": round(float(flagged.float().mean()), 4) if stored else 0.0,
            "first_flagged_transition": int(flagged.nonzero()[0]) if flagged.any() else None,
            "last_flagged_transition": int(flagged.nonzero()[-1]) if flagged.any() else None,
            "episodes_mostly_flagged": [int(e) for e in bad],
            "flagged_per_episode": [round(float(v), 3) for v in per_episode]}
    return report


def draw_frames(path: str | Path, indices: list[int], out: str | Path, key: str = "external_image") -> Path:
    """The stored ``key`` frames at replay ``indices`` side by side, each titled with its episode and step."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    td = TensorDict.load_memmap(storage_path(path))
    episode = td["is_init"].reshape(-1).long().cumsum(0)
    fig, axes = plt.subplots(1, len(indices), figsize=(1.6 * len(indices), 2.0), squeeze=False)
    for ax, index in zip(axes[0], indices):
        frame = td[key][index]
        ax.imshow(frame.permute(1, 2, 0).numpy())
        flag = " (flagged)" if bool(broken_frames(frame[None])[0]) else ""
        ax.set_title(f"episode {int(episode[index])}\nstep {int(td['next', 'step_count'][index])}{flag}", fontsize=7)
        ax.set_xticks([])
        ax.set_yticks([])
    return save_figure(fig, out)


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(prog="python -m torchrl_mpail2.diagnostics replay_frames", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("path", help="a run folder or a checkpoint folder")
    p.add_argument("--plot", help="draw stored table-camera frames, the first of each stretch of flagged episodes and "
                                  "the one before it, into this file")
    p.add_argument("--frames", type=int, nargs="*", help="replay indices to draw with --plot (default: chosen)")
    p.add_argument("--out", help="write the report as JSON here")
    args = p.parse_args(argv)
    report = frame_report(args.path)
    for key, row in report["keys"].items():
        print(f"{key}: {row['flagged']} of {report['transitions']} frames flagged ({row['flagged_fraction']:.2f}); "
              f"episodes mostly flagged: {_ranges(row['episodes_mostly_flagged']) or 'none'}")
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(report, indent=1))
    if args.plot:
        key = next(iter(report["keys"]))
        row = report["keys"][key]
        indices = args.frames or sorted({0, *(i for t in (row["first_flagged_transition"], row["last_flagged_transition"])
                                              if t is not None for i in (max(t - 1, 0), t, min(t + 1, report["transitions"] - 1)))})
        draw_frames(args.path, indices, args.plot, key)
    return report


def _ranges(values: list[int]) -> str:
    """``[6, 7, 8, 12]`` -> ``"6-8, 12"``."""
    spans: list[list[int]] = []
    for v in values:
        if spans and v == spans[-1][1] + 1:
            spans[-1][1] = v
        else:
            spans.append([v, v])
    return ", ".join(f"{a}-{b}" if a != b else f"{a}" for a, b in spans)
