"""The replay_frames diagnostic flags stored camera frames that cannot be renders: noise and black frames."""
import json

import pytest
import torch
from tensordict import TensorDict

from torchrl_mpail2.diagnostics import replay_frames


def _replay(tmp_path, frames, episode_length):
    n = frames.shape[0]
    step = torch.arange(n) % episode_length
    td = TensorDict({"external_image": frames, "is_init": (step == 0)[:, None],
                     "next": {"step_count": (step + 1)[:, None]}}, batch_size=[n])
    padded = torch.cat([td, td.clone().zero_()])  # storage not filled yet: zeros past the stored transitions
    padded.memmap_(tmp_path / "run" / "replay_storage")
    return tmp_path / "run"


def test_noise_and_black_frames_are_flagged_per_episode(tmp_path):
    generator = torch.Generator().manual_seed(0)
    ramp = torch.linspace(60, 250, 64).round().to(torch.uint8)
    scene = ramp.expand(3, 64, 64).clone()  # smooth, like a render: roughness about 3
    frames = scene.expand(12, 3, 64, 64).clone()
    frames[4:8] = torch.randint(0, 256, (4, 3, 64, 64), generator=generator, dtype=torch.uint8)  # episode 2: noise
    frames[9] = 0  # one black frame in episode 3
    run = _replay(tmp_path, frames, episode_length=4)
    report = replay_frames.main([str(run), "--out", str(tmp_path / "r.json"), "--plot", str(tmp_path / "f.png")])
    assert report["transitions"] == 12 and report["episodes"] == 3
    row = report["keys"]["external_image"]
    assert row["flagged"] == 5 and row["first_flagged_transition"] == 4 and row["last_flagged_transition"] == 9
    assert row["episodes_mostly_flagged"] == [2]  # episode 3 has one flagged frame of four
    assert row["flagged_per_episode"] == [0.0, 1.0, 0.25]
    assert json.loads((tmp_path / "r.json").read_text())["keys"]["external_image"]["flagged"] == 5
    assert (tmp_path / "f.png").stat().st_size > 0


def test_a_folder_without_a_replay_is_named():
    with pytest.raises(FileNotFoundError, match="no replay storage"):
        replay_frames.storage_path("/nonexistent/run")
