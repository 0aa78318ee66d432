"""Training: the loop, with the run configs and presets re-exported from :mod:`torchrl_mpail2.config` (the agent and
its updaters are in :mod:`torchrl_mpail2.agents`)."""
from torchrl_mpail2.config import ABLATIONS, PRESETS, ExperimentConfig, TrainConfig, apply_overrides, preset

__all__ = ["ABLATIONS", "ExperimentConfig", "TrainConfig", "apply_overrides", "PRESETS", "preset", "MPAIL2Trainer"]


def __getattr__(name):
    # the loop imports the env and data stacks: load it on first use only
    if name == "MPAIL2Trainer":
        from torchrl_mpail2.trainers.trainer import MPAIL2Trainer
        return MPAIL2Trainer
    raise AttributeError(name)
