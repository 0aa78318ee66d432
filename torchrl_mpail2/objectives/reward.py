r"""Adversarial (WGAN-GP) reward loss :math:`\mathcal L_r(\theta)` (Eq. 3, Algorithm 1)."""
from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase

from torchrl_mpail2.functional import gradient_penalty
from torchrl_mpail2.modules.encoder import ObservationEncoder
from torchrl_mpail2.modules.reward import TransitionReward
from torchrl_mpail2.objectives.base import MPAIL2LossBase


class AdversarialRewardLoss(MPAIL2LossBase):
    r"""Off-policy WGAN-GP critic on latent transitions (Eq. 3).

    .. math::
        \mathcal L_r(\theta) = \mathbb E_{(z,z')\sim e_\omega(\mathcal B)}[r_\theta]
        - \mathbb E_{(z,z')\sim e_\omega(\mathcal D)}[r_\theta] + \beta\,\mathrm{GP}(r_\theta, \mathcal B, \mathcal D)

    Latents are stop-gradient: the encoder is trained only by the dynamics loss. The
    penalty interpolates the concatenated ``(z, z')`` pairs per sample (Appendix A.2); when
    the two sets differ in size, the first ``min(n_agent, n_expert)`` pairs of each are used.

    Args:
        encoder_network (ObservationEncoder): :math:`e_\omega` (read only).
        reward_network (TransitionReward): :math:`r_\theta`.

    Keyword Args:
        gp_coef (float): :math:`\beta` (Table 4: 0.1).
        scale_momentum (float, optional): when set, each call also updates the reward network's
            ``reward_scale`` (a running standard deviation of the critic over the batch's expert and replayed
            transitions, see :meth:`RewardNet.track_scale`), so that the value, the actor and the planner see
            rewards of about unit scale whatever the critic's. ``None`` (the paper) leaves the scale at 1.

    Returns: ``loss_reward`` and detached diagnostics ``reward_expert``, ``reward_agent``, ``reward_gap``
    (expert minus agent, raw critic), ``grad_penalty``, ``expert_accuracy`` (share of paired samples where the
    expert transition scores higher) and ``reward_scale``.
    """

    reward_network: TransitionReward

    def __init__(self, encoder_network: ObservationEncoder, reward_network: TransitionReward, *, gp_coef: float = 0.1,
                 scale_momentum: float | None = None, reduction: str = "mean", generator: torch.Generator | None = None):
        super().__init__(encoder_network, reduction)
        if scale_momentum is not None and not 0.0 <= scale_momentum < 1.0:
            raise ValueError(f"scale_momentum must be in [0, 1) or None, got {scale_momentum}")
        self.reward_network = reward_network
        self.gp_coef = gp_coef
        self.scale_momentum = scale_momentum
        self.generator = generator

    def forward(self, tensordict: TensorDictBase, latents=None, expert_latents=None) -> TensorDictBase:
        """Args:
            tensordict: replay batch with an ``"expert"`` sub-tensordict.
            latents, expert_latents (tuple, optional): precomputed stop-gradient ``(z, z')`` (the composite
                loss passes them to avoid encoding twice).
        """
        z, z_next = latents if latents is not None else self.replay_latents(tensordict)
        ze, ze_next = expert_latents if expert_latents is not None else self.expert_latents(tensordict)
        net = self.reward_network.module
        r_agent = net.critic(z, z_next).flatten()
        r_expert = net.critic(ze, ze_next).flatten()
        x_agent = torch.cat([net._select(z), net._select(z_next)], -1).flatten(0, -2)
        x_expert = torch.cat([net._select(ze), net._select(ze_next)], -1).flatten(0, -2)
        n = min(x_agent.shape[0], x_expert.shape[0])
        gp = gradient_penalty(net.score_pairs, x_expert[:n], x_agent[:n], generator=self.generator)
        loss = self.reduce(r_agent) - self.reduce(r_expert) + self.gp_coef * gp
        with torch.no_grad():
            if self.scale_momentum is not None and self.training:
                net.track_scale(torch.cat([r_agent, r_expert]), self.scale_momentum)
            accuracy = (r_expert[:n] > r_agent[:n]).float().mean()
            return_td = TensorDict({
                "reward_expert": r_expert.mean(), "reward_agent": r_agent.mean(),
                "reward_gap": r_expert.mean() - r_agent.mean(), "grad_penalty": gp.detach(),
                "expert_accuracy": accuracy, "reward_scale": net.reward_scale.clone(),
            }, [])
        return_td.set("loss_reward", loss)
        return return_td
