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
