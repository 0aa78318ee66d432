"""Looking inside a trained agent: a latent probe and pictures of the planner's elite plans."""
from torchrl_mpail2.diagnostics.latent_probe import LatentProbe, fit_latent_probe
from torchrl_mpail2.diagnostics.plan_pictures import PLANE_POSITIONS, draw_plan_pictures

__all__ = ["PLANE_POSITIONS", "LatentProbe", "draw_plan_pictures", "fit_latent_probe"]
