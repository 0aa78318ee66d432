"""Planners acting in the learned latent space."""
from torchrl_mpail2.planners.latent_env import LatentWorldModelEnv
from torchrl_mpail2.planners.mppi import LatentMPPIPlanner

__all__ = ["LatentMPPIPlanner", "LatentWorldModelEnv"]
