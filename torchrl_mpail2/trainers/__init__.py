"""Training: the per-stage updater, the training loop, configs and presets."""
from torchrl_mpail2.trainers.config import ABLATIONS, ExperimentConfig, TrainConfig, apply_overrides
from torchrl_mpail2.trainers.presets import PRESETS, preset
from torchrl_mpail2.trainers.update import MPAIL2Updater

__all__ = ["ABLATIONS", "ExperimentConfig", "TrainConfig", "apply_overrides", "PRESETS", "preset", "MPAIL2Updater",
           "MPAIL2Trainer"]


def __getattr__(name):
    # the loop imports the env and data stacks: load it on first use only
    if name == "MPAIL2Trainer":
        from torchrl_mpail2.trainers.trainer import MPAIL2Trainer
        return MPAIL2Trainer
    raise AttributeError(name)
