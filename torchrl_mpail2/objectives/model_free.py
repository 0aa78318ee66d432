r"""Model-free value and actor losses for the paper's [-PM] (DAC) and [-PMO] (AIRL) ablations.

No planner and no dynamics model: a single-step policy and a soft Q-ensemble trained by one-step
TD on the learned reward :math:`r_\theta(z, z')`. As in the paper's DAC baseline, the encoder is
trained through the value loss (at the encoder learning rate).
"""
from __future__ import annotations

import math

import torch
from tensordict import TensorDict, TensorDictBase, TensorDictParams
from torch import nn

from torchrl_mpail2.modules.encoder import ObservationEncoder
from torchrl_mpail2.modules.policy import MultiStepPolicy
from torchrl_mpail2.modules.reward import TransitionReward
from torchrl_mpail2.modules.value import QEnsemble
from torchrl_mpail2.config import LossConfig
from torchrl_mpail2.objectives.base import MPAIL2LossBase
from torchrl_mpail2.objectives.imagination import ensemble_estimate, frozen
from torchrl_mpail2.objectives.composite import StagedLoss
from torchrl_mpail2.objectives.reward import AdversarialRewardLoss


class ModelFreeActorLoss(MPAIL2LossBase):
    r"""SAC actor on latents: :math:`\mathcal L_\pi = \mathbb E[\alpha \log\pi(a|z) - Q_\zeta(z, a)]` with a single-step policy.

    The policy is a :class:`MultiStepPolicy` with horizon 1. ``alpha`` is tuned towards ``-|A|``.
    Returns ``loss_actor``, ``loss_alpha`` and detached ``alpha``, ``entropy``.
    """

    policy_network: MultiStepPolicy
    qvalue_network: QEnsemble

    def __init__(self, encoder_network: ObservationEncoder, qvalue_network: QEnsemble, policy_network: MultiStepPolicy,
                 *, init_alpha: float = 1e-3, target_entropy: float | None = None, reduction: str = "mean"):
        super().__init__(encoder_network, reduction)
        if policy_network.net.horizon != 1:
            raise ValueError(f"the model-free ablations use a single-step policy (horizon 1), got {policy_network.net.horizon}")
        self.policy_network = policy_network
        self.__dict__["qvalue_network"] = qvalue_network
        self.log_alpha = nn.Parameter(torch.tensor(math.log(init_alpha)))
        self.target_entropy = float(-policy_network.net.action_dim if target_entropy is None else target_entropy)

    def forward(self, tensordict: TensorDictBase, latents=None) -> TensorDictBase:
        z = latents[0] if latents is not None else self.replay_latents(tensordict)[0]
        z = z.reshape(-1, z.shape[-1])
        plan, log_prob = self.policy_network.net(z)
        with frozen(self.qvalue_network):
            q = ensemble_estimate(self.qvalue_network.net, "mean")(z, plan[:, 0])
        alpha = self.log_alpha.exp().detach()
        return TensorDict({
            "loss_actor": self.reduce(alpha * log_prob - q),
            "loss_alpha": self.reduce(-self.log_alpha * (log_prob.detach() + self.target_entropy)),
            "alpha": alpha, "entropy": -log_prob.detach().mean(),
            "target_entropy": self.log_alpha.new_tensor(self.target_entropy),
        }, [])


class ModelFreeValueLoss(MPAIL2LossBase):
    r"""Soft one-step TD on the learned reward; trains the Q-ensemble and the encoder.

    .. math::
        y = r_\theta(\bar z, \bar z') + \gamma (1 - d)\big(\min_{2\ \mathrm{heads}} \bar Q(\bar z', a') - \alpha\log\pi(a'|\bar z')\big),
        \quad a' \sim \pi(\cdot|\bar z'),\quad \mathcal L = \sum_e \mathbb E[(Q^e(e_\omega(o), a) - y)^2]

    (bars: stop-gradient latents / slow target). ``alpha`` is read from the actor loss.
    Returns ``loss_value`` and detached ``q_mean``, ``q_target_mean``, ``learned_reward_mean``.
    """

    qvalue_network: QEnsemble
    qvalue_network_params: TensorDictParams
    target_qvalue_network_params: TensorDictParams

    def __init__(self, encoder_network: ObservationEncoder, reward_network: TransitionReward, qvalue_network: QEnsemble,
                 policy_network: MultiStepPolicy, actor_loss: ModelFreeActorLoss, *, gamma: float = 0.99,
                 mask_terminal: bool = False, reduction: str = "mean"):
        super().__init__(encoder_network, reduction)
        self.__dict__["reward_network"] = reward_network
        self.__dict__["policy_network"] = policy_network
        self.__dict__["actor_loss"] = actor_loss
        self.convert_to_functional(qvalue_network, "qvalue_network", create_target_params=True)
        self.gamma, self.mask_terminal = gamma, mask_terminal

    def forward(self, tensordict: TensorDictBase, latents=None) -> TensorDictBase:
        z_sg, z_next = latents if latents is not None else self.replay_latents(tensordict)
        z_sg, z_next = z_sg.reshape(-1, z_sg.shape[-1]), z_next.reshape(-1, z_next.shape[-1])
        z = self.encode(tensordict).reshape(-1, z_sg.shape[-1])  # with gradient: the encoder learns here
        action = self.require(tensordict, self.tensor_keys.action)
        action = action.reshape(-1, action.shape[-1])
        with torch.no_grad():
            r = self.reward_network.module(z_sg, z_next).squeeze(-1)
            plan, log_prob = self.policy_network.net(z_next)
            with self.target_qvalue_network_params.data.to_module(self.qvalue_network):
                q_next = ensemble_estimate(self.qvalue_network.net, "min")(z_next, plan[:, 0])
            bootstrap = q_next - self.actor_loss.log_alpha.exp() * log_prob
            if self.mask_terminal:
                terminated = self.require(tensordict, self.tensor_keys.terminated).reshape(-1)
                bootstrap = bootstrap * (~terminated).to(bootstrap.dtype)
            y = r + self.gamma * bootstrap
        q = self.qvalue_network.net(z, action).squeeze(-1)
        loss = self.reduce((q - y).pow(2).sum(0))
        return TensorDict({"loss_value": loss, "q_mean": q.detach().mean(), "q_target_mean": y.mean(),
                           "learned_reward_mean": r.mean()}, [])


class DACLoss(StagedLoss):
    r"""Composite of the [-PM] (DAC) ablation: adversarial reward, model-free value (with encoder) and actor.

    Same reward as MPAIL2 (:class:`AdversarialRewardLoss`); no dynamics loss, no planner. The
    policy of ``modules`` must have horizon 1. :meth:`param_groups` mirrors :meth:`MPAIL2Loss.param_groups`
    with the encoder moved into the value stage. The actor stage reads the latents encoded before the value
    stage changed the encoder.
    """

    stages = ("reward", "value", "actor")

    def __init__(self, modules, cfg: LossConfig | None = None):
        cfg = cfg or LossConfig()
        super().__init__(modules.encoder)
        self.cfg = cfg
        self.__dict__["components"] = modules
        m = modules
        self.reward_loss = AdversarialRewardLoss(m.encoder, m.reward, gp_coef=cfg.gp_coef,
                                                 scale_momentum=cfg.reward_scale_momentum)
        self.actor_loss = ModelFreeActorLoss(m.encoder, m.value, m.policy, init_alpha=cfg.init_alpha,
                                             target_entropy=cfg.target_entropy_per_step)
        self.value_loss = ModelFreeValueLoss(m.encoder, m.reward, m.value, m.policy, self.actor_loss, gamma=cfg.gamma,
                                             mask_terminal=cfg.mask_terminal)
        self.set_image_shift(cfg.image_shift)

    @property
    def log_alpha(self) -> nn.Parameter:
        return self.actor_loss.log_alpha

    def param_groups(self) -> dict[str, list[dict]]:
        m, c = self.components, self.cfg
        return {
            "reward": [dict(params=list(m.reward.parameters()), lr=c.lr, max_grad_norm=None)],
            "value": [dict(params=list(m.encoder.parameters()), lr=c.encoder_lr, max_grad_norm=c.value_grad_clip),
                      dict(params=list(m.value.parameters()), lr=c.lr, max_grad_norm=c.value_grad_clip)],
            "actor": [dict(params=list(m.policy.parameters()), lr=c.lr, max_grad_norm=c.policy_grad_clip)],
            "alpha": [dict(params=[self.actor_loss.log_alpha], lr=c.alpha_lr, max_grad_norm=None)],
        }
