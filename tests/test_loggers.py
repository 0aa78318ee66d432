"""The wandb (offline) and tensorboard loggers, for real: a short run from the command line writes their files,
and the files hold the run's grouped metrics."""
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHORT_RUN = ["--preset", "point_mass", "train.progress=false", "train.figures=false", "train.num_demos=2",
             "train.total_episodes=2", "train.warmup_episodes=1", "train.utd=0.05", "train.eval_every=2",
             "train.eval_episodes=1",
             "planner.num_candidates=32", "planner.num_elites=4"]
#: Tags every run logs: a loss, a planner statistic and the headline evaluation figure.
EXPECTED_TAGS = ("losses/loss_dynamics", "planner/elite_ess", "eval/environment/success_rate_any_step")


def _train(tmp_path: Path, logger: str, *extra: str) -> Path:
    run_dir = tmp_path / f"run_{logger}"
    env = {**os.environ, "OMP_NUM_THREADS": "1", "WANDB_MODE": "offline", "WANDB_SILENT": "true",
           "WANDB_DIR": str(tmp_path), "PYTHONPATH": str(ROOT)}
    subprocess.run([sys.executable, "-m", "torchrl_mpail2.train", *SHORT_RUN, f"train.logger={logger}",
                    f"train.run_dir={run_dir}", *extra], cwd=tmp_path, env=env, check=True, capture_output=True, timeout=300)
    return run_dir


def test_tensorboard_logger_writes_the_grouped_scalars(tmp_path):
    pytest.importorskip("tensorboard")
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    run_dir = _train(tmp_path, "tensorboard")
    events = list((run_dir / "tensorboard").rglob("events.out.tfevents.*"))
    assert len(events) == 1, events
    accumulator = EventAccumulator(str(events[0]))
    accumulator.Reload()
    tags = set(accumulator.Tags()["scalars"])
    assert set(EXPECTED_TAGS) <= tags, sorted(tags)
    assert [e.step for e in accumulator.Scalars("losses/loss_dynamics")] == [1, 2]  # warm-up episode 1 updates too
    assert [e.step for e in accumulator.Scalars("eval/environment/success_rate_any_step")] == [2]


def test_wandb_offline_logger_writes_a_run_file_with_the_metrics(tmp_path):
    pytest.importorskip("wandb")
    run_dir = _train(tmp_path, "wandb", "train.video=true")
    runs = list((run_dir / "wandb").glob("offline-run-*/run-*.wandb"))
    assert len(runs) == 1, list((run_dir / "wandb").rglob("*"))
    data = runs[0].read_bytes()
    for tag in EXPECTED_TAGS:
        assert tag.encode() in data, tag
    assert b"model" in data and b"latent_dim" in data  # the run's config travels with it
    assert b"eval/video" in data  # the evaluation video as wandb media
    assert list((run_dir / "videos").glob("eval_000002_0.mp4"))
