"""The wandb (offline) and tensorboard loggers, for real: a short run from the command line writes their files,
and the files hold the run's grouped metrics; wandb follows its own environment variables, and the evaluation videos
reach each logger that can take them."""
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
    runs = list((tmp_path / "wandb").glob("offline-run-*/run-*.wandb"))  # under WANDB_DIR
    assert len(runs) == 1, list(tmp_path.rglob("*.wandb"))
    assert not (run_dir / "wandb").exists()
    data = runs[0].read_bytes()
    for tag in EXPECTED_TAGS:
        assert tag.encode() in data, tag
    assert b"model" in data and b"latent_dim" in data  # the run's config travels with it
    assert b"eval/video" in data and b"video-file" in data  # the evaluation video as wandb media
    assert list((run_dir / "videos").glob("eval_000002_0.mp4"))


# ---- wandb's own settings (issue 48): online where logged in, its environment variables respected -------------
WANDB_VARIABLES = ("WANDB_MODE", "WANDB_DIR", "WANDB_PROJECT", "WANDB_ENTITY", "WANDB_RUN_GROUP", "WANDB_NAME",
                   "WANDB_API_KEY", "WANDB_RUN_ID")


@pytest.fixture
def wandb_env(monkeypatch):
    """A clean wandb: none of its variables set, and its process-wide settings (read once) dropped before and after."""
    wandb = pytest.importorskip("wandb", reason="wandb is not installed (the wandb extra)")
    for name in WANDB_VARIABLES:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("WANDB_SILENT", "true")
    wandb.teardown()
    yield monkeypatch
    wandb.teardown()


def _wandb_run(run_dir: Path):
    from torchrl_mpail2.trainers.logs import make_torchrl_logger

    logger = make_torchrl_logger("wandb", run_dir, {"train": {"seed": 3}})
    logger.log_scalar("losses/loss_dynamics", 1.0, step=1)
    run = logger.experiment
    run.finish()
    return run


def test_wandb_takes_project_entity_group_name_mode_and_dir_from_its_variables(wandb_env, tmp_path):
    wandb_env.setenv("WANDB_MODE", "offline")
    for name, value in (("WANDB_DIR", str(tmp_path / "elsewhere")), ("WANDB_PROJECT", "lift"), ("WANDB_ENTITY", "lab"),
                        ("WANDB_RUN_GROUP", "sweep-3"), ("WANDB_NAME", "seed-3")):
        wandb_env.setenv(name, value)
    run = _wandb_run(tmp_path / "run")
    assert (run.project, run.entity, run.group, run.name, run.settings.mode) == ("lift", "lab", "sweep-3", "seed-3", "offline")
    assert list((tmp_path / "elsewhere" / "wandb").glob("offline-run-*/run-*.wandb"))
    assert not (tmp_path / "run").exists()
    import os

    assert os.environ["WANDB_MODE"] == "offline"  # TorchRL's offline flag would have rewritten it to "dryrun"


def test_wandb_defaults_to_the_package_project_and_the_run_folder(wandb_env, tmp_path):
    from torchrl_mpail2.trainers.logs import WANDB_PROJECT

    wandb_env.setenv("WANDB_MODE", "offline")
    run = _wandb_run(tmp_path / "run-7")
    assert (run.project, run.name) == (WANDB_PROJECT, "run-7")
    assert list((tmp_path / "run-7" / "wandb").glob("offline-run-*/run-*.wandb"))


def test_a_resumed_run_logs_into_the_same_wandb_run(wandb_env, tmp_path):
    """The run folder keeps its wandb id: a second launch (a resume) goes on in the first launch's wandb run; another
    run folder gets its own; ``WANDB_RUN_ID`` still wins."""
    from torchrl_mpail2.trainers.logs import WANDB_ID_FILE

    wandb_env.setenv("WANDB_MODE", "offline")
    (tmp_path / "run").mkdir()  # the trainer's run folder exists before its logger
    (tmp_path / "other").mkdir()
    first, again = _wandb_run(tmp_path / "run"), _wandb_run(tmp_path / "run")
    other = _wandb_run(tmp_path / "other")
    assert first.id == again.id == (tmp_path / "run" / WANDB_ID_FILE).read_text().strip()
    assert other.id != first.id
    wandb_env.setenv("WANDB_RUN_ID", "chosen01")
    assert _wandb_run(tmp_path / "run").id == "chosen01"


def test_wandb_mode_disabled_writes_nothing(wandb_env, tmp_path):
    wandb_env.setenv("WANDB_MODE", "disabled")
    run = _wandb_run(tmp_path / "run")
    assert run.settings.mode == "disabled" and not list(tmp_path.rglob("*.wandb"))


def test_wandb_without_a_mode_goes_online_and_asks_for_a_login_where_there_is_none(wandb_env, tmp_path):
    """Not forced offline: without ``WANDB_MODE`` and an API key wandb wants a login; the message says how to log
    offline instead. In a process of its own without a terminal, with a home folder holding no credentials."""
    env = {k: v for k, v in os.environ.items() if k not in WANDB_VARIABLES}
    env.update(HOME=str(tmp_path), PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1", WANDB_SILENT="true")
    code = ("from pathlib import Path; from torchrl_mpail2.trainers.logs import make_torchrl_logger; "
            f"make_torchrl_logger('wandb', Path({str(tmp_path / 'run')!r}), {{}})")
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, stdin=subprocess.DEVNULL,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode != 0, out.stdout
    assert "train.logger=wandb: No API key configured" in out.stderr and "WANDB_MODE=offline" in out.stderr, out.stderr
    assert not list(tmp_path.rglob("*.wandb"))


# ---- videos through TorchRL's loggers (issue 48) ---------------------------------------------------------------
def _frames(steps: int, value: int) -> "np.ndarray":
    import numpy as np

    frames = np.zeros((steps, 8, 8, 3), dtype=np.uint8)
    frames[..., 0] = value
    return frames


def test_tensorboard_takes_the_videos_where_moviepy_1_is_installed_and_says_so_elsewhere(tmp_path):
    pytest.importorskip("tensorboard")
    import importlib.util

    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    from torchrl_mpail2.trainers.logs import RunLogger

    try:
        moviepy_1 = importlib.util.find_spec("moviepy.editor") is not None
    except ImportError:
        moviepy_1 = False
    if moviepy_1:
        logger = RunLogger(tmp_path, "tensorboard", {}, video=True)
    else:
        with pytest.warns(RuntimeWarning, match=r"tensorboard gets no videos here: .*moviepy<2"):
            logger = RunLogger(tmp_path, "tensorboard", {}, video=True)
    logger.log_videos([_frames(4, 200), _frames(3, 100)], [], step=6)  # no crash without moviepy 1
    logger.logger.experiment.flush()
    accumulator = EventAccumulator(str(next((tmp_path / "tensorboard").rglob("events.out.tfevents.*"))))
    accumulator.Reload()
    if moviepy_1:
        assert [e.step for e in accumulator.Images("eval/video")] == [6]
    else:
        assert "eval/video" not in accumulator.Tags()["images"]
