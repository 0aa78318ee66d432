import os

import pytest
import torch
from tensordict import TensorDict

from torchrl_mpail2.config import ModelConfig
from torchrl_mpail2.modules import MPAIL2Modules

TINY = dict(latent_dim=16, hidden_dims=(32, 32), coder_dim=32, vector_coder_hidden=32, cnn_channels=8, horizon=3)
BATCH_SHAPES = [(), (4,), (2, 3)]


def pytest_configure(config):
    """Under pytest-xdist the cores are shared out between the workers (and the processes the tests start), so that
    torch's intra-op threads do not oversubscribe them: on 2 cores, two workers at one thread each."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "0"))
    if workers:
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
        threads = max(1, cores // workers)
        torch.set_num_threads(threads)
        os.environ.setdefault("OMP_NUM_THREADS", str(threads))


@pytest.fixture(autouse=True)
def _own_working_directory(tmp_path, monkeypatch):
    """Each test runs in its own folder: what a run writes relative to the working directory (the scripted-demo cache
    ``demos/``, default run folders) lands there, never in the checkout, and no two tests share it."""
    monkeypatch.chdir(tmp_path)


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
