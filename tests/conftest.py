import os

import pytest
import torch
from tensordict import TensorDict

from torchrl_mpail2.config import ModelConfig
from torchrl_mpail2.modules import MPAIL2Modules

TINY = dict(latent_dim=16, hidden_dims=(32, 32), coder_dim=32, vector_coder_hidden=32, cnn_channels=8, horizon=3)
BATCH_SHAPES = [(), (4,), (2, 3)]
#: Overrides of a short test run that leaves out what only a person watches: the progress bar, the logger, the figures.
QUIET_RUN = ["train.progress=false", "train.logger=none", "train.figures=false"]


@pytest.fixture(autouse=True)
def _own_working_directory(tmp_path, monkeypatch):
    """Each test runs in its own folder: what a run writes relative to the working directory (the scripted-demo cache
    ``demos/``, default run folders) lands there, never in the checkout, and no two tests share it."""
    monkeypatch.chdir(tmp_path)


def pytest_configure(config):
    """Under pytest-xdist each test process takes its share of the cores for torch's threads, so that the processes
    do not oversubscribe them."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "0"))
    if workers > 1:
        torch.set_num_threads(max(1, (os.cpu_count() or 1) // workers))


@pytest.fixture(autouse=True)
def _seed():
    torch.manual_seed(0)


def tiny_modules(obs_dim: int = 3, action_dim: int = 2, **overrides) -> MPAIL2Modules:
    return MPAIL2Modules({"observation": [obs_dim]}, action_dim, ModelConfig(**{**TINY, **overrides}))


def replay_batch(batch: int = 4, steps: int = 3, obs_dim: int = 3, action_dim: int = 2) -> TensorDict:
    def obs():
        return torch.randn(batch, steps, obs_dim)
    return TensorDict({
        "observation": obs(), "action": torch.rand(batch, steps, action_dim) * 2 - 1,
        ("next", "observation"): obs(), ("next", "terminated"): torch.zeros(batch, steps, 1, dtype=torch.bool),
        ("expert", "observation"): obs(), ("expert", "next", "observation"): obs(),
    }, [batch, steps])


@pytest.fixture(scope="module")
def demo_dir(tmp_path_factory):
    """Four scripted point-mass demonstrations in a folder (one recording per test module)."""
    from torchrl_mpail2.data import record_demos
    from torchrl_mpail2.envs import make_env
    from torchrl_mpail2.experts import PointMassExpert

    path = tmp_path_factory.mktemp("demos") / "pm"
    record_demos(make_env("point_mass", seed=1), PointMassExpert(), episodes=4, out=path, progress=False)
    return path


def short_run_cfg(demo_dir, *overrides):
    """A two-episode point-mass run on ``demo_dir``'s demos: the quickest run that checkpoints and resumes."""
    from torchrl_mpail2.trainers import apply_overrides, preset

    return apply_overrides(preset("point_mass"), [
        *QUIET_RUN, f"train.demos={demo_dir}", "train.total_episodes=2", "train.warmup_episodes=1", "train.utd=0.02",
        "train.batch_size=8", "train.eval_every=0", "train.checkpoint_every=0", "planner.num_candidates=32",
        "planner.num_elites=4", *overrides])


def train_short_run(demo_dir, run, *overrides):
    """Trains :func:`short_run_cfg` into the folder ``run``; returns it."""
    from torchrl_mpail2.trainers import MPAIL2Trainer

    MPAIL2Trainer(short_run_cfg(demo_dir, *overrides), run_dir=run).train()
    return run


def flip_a_byte(path) -> None:
    """Corrupts a file the way a bad disk does: one byte in its middle inverted."""
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))
