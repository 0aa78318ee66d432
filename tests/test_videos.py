"""Evaluation videos: frames from env.render(), written as mp4, without changing what is evaluated."""
import imageio
import numpy as np
import pytest
import torch

from conftest import QUIET_RUN
from torchrl_mpail2.envs import make_env
from torchrl_mpail2.trainers import MPAIL2Trainer, apply_overrides, preset
from torchrl_mpail2.trainers.videos import video_tensor


def _cfg(*overrides):
    return apply_overrides(preset("point_mass"), [*QUIET_RUN, "train.num_demos=2", "train.total_episodes=2",
                                                  "train.warmup_episodes=1",
                                                  "train.utd=0.05", "train.eval_every=2", "train.eval_episodes=3",
                                                  "planner.num_candidates=32", "planner.num_elites=4", *overrides])


def test_point_mass_frames_show_the_point_where_it_is():
    env = make_env("point_mass", seed=0)
    td = env.reset()
    frame = env.render()
    assert frame.shape == (128, 128, 3) and frame.dtype == np.uint8
    x, y = td["observation"][:2].tolist()
    blue = np.argwhere((frame == (40, 60, 220)).all(-1)).mean(0)  # row, column of the point
    assert abs(blue[1] - (x + 1.5) / 3 * 128) < 2 and abs(blue[0] - (1.5 - y) / 3 * 128) < 2


def test_train_video_writes_the_evaluation_episodes_and_evaluates_the_same(tmp_path):
    filmed = MPAIL2Trainer(_cfg("train.video=true", "train.video_episodes=2", "train.logger=csv"),
                           run_dir=tmp_path / "filmed")
    filmed.train()
    videos = sorted((tmp_path / "filmed" / "videos").glob("*.mp4"))
    assert [p.name for p in videos] == ["eval_000002_0.mp4", "eval_000002_1.mp4"]
    reader = imageio.get_reader(videos[0])
    assert reader.count_frames() == 51  # the reset and 50 steps
    assert reader.get_meta_data()["size"] == (128, 128)
    # TorchRL's CSV logger has them too (issue 48): mp4 where torchcodec is installed, its uint8 tensor elsewhere
    logged = list((tmp_path / "filmed" / "logs" / "videos" / "eval").glob("video_2.*"))
    assert len(logged) == 1, list((tmp_path / "filmed" / "logs").rglob("*"))
    if logged[0].suffix == ".pt":
        tensor = torch.load(logged[0])
        assert tensor.dtype == torch.uint8 and tensor.shape == (2, 51, 3, 128, 128)
        first = np.asarray(reader.get_data(0), dtype=np.int16)  # the mp4 is lossy: close, not equal
        assert np.abs(tensor[0, 0].permute(1, 2, 0).numpy().astype(np.int16) - first).mean() < 8
    # the same weights scored with and without filming: filming changes nothing of the episodes
    with_video = filmed.evaluate()
    filmed.cfg.train.video = False
    without = filmed.evaluate()
    assert {k: v for k, v in with_video.items() if k != "videos"} == without


def test_video_tensor_stacks_episodes_as_torchrls_loggers_take_them():
    short, long = np.zeros((2, 4, 6, 3), np.uint8), np.zeros((3, 4, 6, 3), np.uint8)
    short[1, 0, 5] = (10, 20, 30)  # the short episode's last frame: one coloured pixel at row 0, column 5
    long[2] = 7
    video = video_tensor([short, long])
    assert video.dtype == torch.uint8 and video.shape == (2, 3, 3, 4, 6)  # [B, T, C, H, W]
    assert video[0, 1, :, 0, 5].tolist() == [10, 20, 30] and int(video[0, 1].sum()) == 60
    assert torch.equal(video[0, 2], video[0, 1])  # the shorter episode holds its last frame
    assert int(video[1, 2].min()) == 7 and int(video[1, :2].max()) == 0


def test_train_video_on_an_env_without_render_is_refused_by_name(tmp_path):
    env = make_env("point_mass")

    class NoRender:
        def __getattr__(self, name):
            if name == "render":
                raise AttributeError(name)
            return getattr(env, name)

    with pytest.raises(ValueError, match="train.video=true needs an env with render"):
        MPAIL2Trainer(_cfg("train.video=true"), run_dir=tmp_path / "run", env_fn=lambda seed=0: NoRender())
    assert not (tmp_path / "run").exists()
