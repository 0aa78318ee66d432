r"""Multi-step actor loss (Eq. 5) with SAC-style entropy temperature."""
from __future__ import annotations

import math

import torch
from tensordict import TensorDict, TensorDictBase
from torch import nn

from torchrl_mpail2.modules.dynamics import LatentDynamics
from torchrl_mpail2.modules.encoder import ObservationEncoder
from torchrl_mpail2.modules.policy import MultiStepPolicy
from torchrl_mpail2.modules.reward import TransitionReward
from torchrl_mpail2.modules.value import QEnsemble
from torchrl_mpail2.objectives.base import MPAIL2LossBase
from torchrl_mpail2.objectives.imagination import (checked_return_form, ensemble_estimate, frozen,
                                                   imagined_lambda_return)


class MultiStepActorLoss(MPAIL2LossBase):
    r"""Maximises the imagined lambda-return of policy plans minus an entropy cost (Eq. 5).

    .. math::
        \mathcal L_\pi(\phi) = \mathbb E_{z,\ \hat{\mathbf a}\sim\pi_\phi(\cdot|z)}
        \big[\alpha \tfrac{1}{H}\log\pi_\phi(\hat{\mathbf a}\mid z) - G^\lambda(\hat{\boldsymbol\tau}^\pi)\big],\qquad
        \mathcal L_\alpha = -\log\alpha\,\big(\tfrac{1}{H}\log\pi + \bar{\mathcal H}\big).

    The log-probability is taken per action step (divided by ``H``) so that the target entropy
    :math:`\bar{\mathcal H} = -|\mathcal A|` applies per step (Table 4). Dynamics, reward and Q are
    evaluated with frozen parameters: gradients reach only the policy (and ``log_alpha`` through
    ``loss_alpha``). ``G`` uses the online Q, mean (or ``q_reduce="min"``) of two random heads.

    Keyword Args:
        gamma, lmbda (float): as in Eq. 6. return_form (str): form of the imagined return, one of ``RETURN_FORMS``.
        q_reduce (str): ``mean`` (default) or ``min`` of the two Q heads in ``G``. init_alpha (float): initial temperature.
        target_entropy_per_step (float, optional): default ``-A``.

    Returns: ``loss_actor``, ``loss_alpha`` and detached ``alpha``, ``entropy`` (per step, ``-log pi / H``),
    ``target_entropy`` (per step) and ``imagined_return``.
    """

    policy_network: MultiStepPolicy
    dynamics_network: LatentDynamics
    reward_network: TransitionReward
    qvalue_network: QEnsemble

    def __init__(self, encoder_network: ObservationEncoder, dynamics_network: LatentDynamics,
                 reward_network: TransitionReward, qvalue_network: QEnsemble, policy_network: MultiStepPolicy, *,
                 gamma: float = 0.99, lmbda: float = 0.95, return_form: str = "paper", q_reduce: str = "mean",
                 init_alpha: float = 1e-3,
                 target_entropy_per_step: float | None = None, reduction: str = "mean"):
        super().__init__(encoder_network, reduction)
        self.policy_network = policy_network
        self.__dict__["dynamics_network"] = dynamics_network  # evaluated frozen, never trained here
        self.__dict__["reward_network"] = reward_network
        self.__dict__["qvalue_network"] = qvalue_network
        self.log_alpha = nn.Parameter(torch.tensor(math.log(init_alpha)))
        action_dim = policy_network.net.action_dim
        self.target_entropy = float(-action_dim if target_entropy_per_step is None else target_entropy_per_step)
        self.gamma, self.lmbda = gamma, lmbda
        self.return_form = checked_return_form(return_form)
        self.q_reduce = q_reduce

    def forward(self, tensordict: TensorDictBase, latents=None) -> TensorDictBase:
        z = latents[0] if latents is not None else self.replay_latents(tensordict)[0]
        z = z.reshape(-1, z.shape[-1])
        policy = self.policy_network.net
        plan, log_prob = policy(z)
        log_prob_step = log_prob / policy.horizon
        qnet = self.qvalue_network.net
        with frozen(self.dynamics_network, self.reward_network, self.qvalue_network):
            G = imagined_lambda_return(z, plan, self.dynamics_network.module, self.reward_network.module,
                                       ensemble_estimate(qnet, self.q_reduce), policy, self.gamma, self.lmbda,
                                       self.return_form)
        alpha = self.log_alpha.exp().detach()
        loss_actor = self.reduce(alpha * log_prob_step - G)
        loss_alpha = self.reduce(-self.log_alpha * (log_prob_step.detach() + self.target_entropy))
        return TensorDict({"loss_actor": loss_actor, "loss_alpha": loss_alpha, "alpha": alpha,
                           "entropy": -log_prob_step.detach().mean(),
                           "target_entropy": self.log_alpha.new_tensor(self.target_entropy),
                           "imagined_return": G.detach().mean()}, [])
