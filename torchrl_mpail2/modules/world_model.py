r"""Walking latents forward through the learned model: the imagined rollout under :math:`f_\psi` and the chain of
rewards :math:`r_\theta(z_k, z_{k+1})` along a latent path. One home for both: the value target and the actor's
imagined returns (:mod:`torchrl_mpail2.objectives.imagination`) and :class:`~torchrl_mpail2.modules.MPAIL2Modules`'
verbs (``imagine``, ``rewards``) call them."""
from __future__ import annotations

import torch
from torch import Tensor

from torchrl_mpail2.modules.dynamics import DynamicsNet
from torchrl_mpail2.modules.reward import RewardNet

__all__ = ["chain_rewards", "rollout_latents"]


def rollout_latents(dynamics: DynamicsNet, z0: Tensor, plan: Tensor) -> Tensor:
    """``z0 [M, Z]``, ``plan [M, H, A]`` -> ``[H+1, M, Z]`` (``z0`` first)."""
    latents = [z0]
    for k in range(plan.shape[-2]):
        latents.append(dynamics(latents[-1], plan[..., k, :]))
    return torch.stack(latents, 0)


def chain_rewards(reward: RewardNet, latents: Tensor) -> Tensor:
    """Rewards of consecutive latents ``[H+1, M, Z]`` -> ``[H, M]``, projecting each latent once."""
    h_now, h_next = reward.project(latents)
    return reward.from_projection(h_now[:-1], h_next[1:]).squeeze(-1)
