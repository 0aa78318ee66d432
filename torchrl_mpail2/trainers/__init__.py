"""Training: the loop, run configs and presets (the agent and its updaters are in :mod:`torchrl_mpail2.agents`)."""
from torchrl_mpail2.trainers.config import ABLATIONS, ExperimentConfig, TrainConfig, apply_overrides
from torchrl_mpail2.trainers.presets import PRESETS, preset

__all__ = ["ABLATIONS", "ExperimentConfig", "TrainConfig", "apply_overrides", "PRESETS", "preset", "MPAIL2Trainer"]


def __getattr__(name):
    # the loop imports the env and data stacks: load it on first use only
    if name == "MPAIL2Trainer":
        from torchrl_mpail2.trainers.trainer import MPAIL2Trainer
        return MPAIL2Trainer
    raise AttributeError(name)
