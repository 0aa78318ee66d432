"""Training utilities: the per-stage updater (and the training loop)."""
from torchrl_mpail2.trainers.update import MPAIL2Updater

__all__ = ["MPAIL2Updater"]
