r"""Composite :class:`MPAIL2Loss`: the four MPAIL2 objectives and their optimiser groups."""
from __future__ import annotations

import torch
from tensordict import TensorDict

from torchrl_mpail2.config import LossConfig
from torchrl_mpail2.modules.factory import MPAIL2Modules
from torchrl_mpail2.objectives.actor import MultiStepActorLoss
from torchrl_mpail2.objectives.composite import StagedLoss
from torchrl_mpail2.objectives.dynamics import JEPDynamicsLoss
from torchrl_mpail2.objectives.reward import AdversarialRewardLoss
from torchrl_mpail2.objectives.value import LambdaReturnValueLoss


class MPAIL2Loss(StagedLoss):
    r"""All MPAIL2 objectives in one TorchRL ``LossModule``.

    ``forward`` returns every term (``loss_dynamics``, ``loss_reward``, ``loss_value``, ``loss_actor``,
    ``loss_alpha``) plus detached diagnostics, all computed from the same parameters. The paper updates
    the components one after the other (dynamics -> reward -> value -> policy), each with its own
    optimiser: ``stages`` is that order, :meth:`param_groups` gives the groups (encoder LR 3e-5, the rest 3e-4,
    gradient clip 5 for the value and 1 for the policy) and :class:`torchrl_mpail2.agents.MPAIL2Updater` runs
    them in one call. The sub-losses are available as ``loss.dynamics_loss``, ``loss.reward_loss``,
    ``loss.value_loss`` and ``loss.actor_loss``.

    Args:
        modules (MPAIL2Modules): encoder, dynamics, reward, value and policy.
        cfg (LossConfig, optional): coefficients (Table 4 defaults).

    Examples:
        >>> from torchrl_mpail2.config import ModelConfig
        >>> from torchrl_mpail2.modules import MPAIL2Modules
        >>> modules = MPAIL2Modules({"observation": [3]}, action_dim=2,
        ...                         cfg=ModelConfig(latent_dim=8, hidden_dims=(16,), coder_dim=16, vector_coder_hidden=16, horizon=3))
        >>> loss = MPAIL2Loss(modules)
        >>> obs = lambda *s: torch.randn(*s, 3)
        >>> td = TensorDict({"observation": obs(4, 3), "action": torch.rand(4, 3, 2) * 2 - 1,
        ...                  ("next", "observation"): obs(4, 3), ("next", "terminated"): torch.zeros(4, 3, 1, dtype=torch.bool),
        ...                  ("expert", "observation"): obs(4, 3), ("expert", "next", "observation"): obs(4, 3)}, [4, 3])
        >>> out = loss(td)
        >>> sorted(k for k in out.keys() if k.startswith("loss_"))
        ['loss_actor', 'loss_alpha', 'loss_dynamics', 'loss_reward', 'loss_value']
    """

    #: The paper's update order (Algorithm 1).
    stages = ("dynamics", "reward", "value", "actor")

    def __init__(self, modules: MPAIL2Modules, cfg: LossConfig | None = None):
        cfg = cfg or LossConfig()
        super().__init__(modules.encoder)
        self.cfg = cfg
        self.__dict__["components"] = modules
        m = modules
        self.dynamics_loss = JEPDynamicsLoss(m.encoder, m.dynamics, rho=cfg.rho)
        self.reward_loss = AdversarialRewardLoss(m.encoder, m.reward, gp_coef=cfg.gp_coef,
                                                 scale_momentum=cfg.reward_scale_momentum)
        self.value_loss = LambdaReturnValueLoss(m.encoder, m.dynamics, m.reward, m.value, m.policy, gamma=cfg.gamma,
                                                lmbda=cfg.lmbda, return_form=cfg.return_form,
                                                mask_terminal=cfg.mask_terminal, head_reduce=cfg.value_head_reduce,
                                                encoder_grad=cfg.value_trains_encoder,
                                                branch_fraction=cfg.value_branch_fraction,
                                                branch_noise=cfg.value_branch_noise)
        self.actor_loss = MultiStepActorLoss(m.encoder, m.dynamics, m.reward, m.value, m.policy, gamma=cfg.gamma,
                                             lmbda=cfg.lmbda, return_form=cfg.return_form, q_reduce=cfg.actor_q_reduce,
                                             init_alpha=cfg.init_alpha,
                                             target_entropy_per_step=cfg.target_entropy_per_step)
        self.set_image_shift(cfg.image_shift)

    @property
    def log_alpha(self) -> torch.nn.Parameter:
        return self.actor_loss.log_alpha

    def param_groups(self) -> dict[str, list[dict]]:
        """Per-optimiser parameter groups of the paper (Table 4), keyed by update stage.

        Each value is a list of ``torch.optim`` parameter-group dicts; ``"max_grad_norm"`` (or None) is
        the clip applied before that optimiser's step. Stages: ``dynamics`` (encoder at ``encoder_lr``,
        dynamics at ``lr``), ``reward``, ``value`` (and the encoder at ``encoder_lr`` with
        ``cfg.value_trains_encoder``), ``actor`` (policy), ``alpha`` (``log_alpha``).
        """
        m, c = self.components, self.cfg
        return {
            "dynamics": [dict(params=list(m.encoder.parameters()), lr=c.encoder_lr, max_grad_norm=None),
                         dict(params=list(m.dynamics.parameters()), lr=c.lr, max_grad_norm=None)],
            "reward": [dict(params=list(m.reward.parameters()), lr=c.lr, max_grad_norm=None)],
            "value": [dict(params=list(m.value.parameters()), lr=c.lr, max_grad_norm=c.value_grad_clip)]
            + ([dict(params=list(m.encoder.parameters()), lr=c.encoder_lr, max_grad_norm=c.value_grad_clip)]
               if c.value_trains_encoder else []),
            "actor": [dict(params=list(m.policy.parameters()), lr=c.lr, max_grad_norm=c.policy_grad_clip)],
            "alpha": [dict(params=[self.actor_loss.log_alpha], lr=c.alpha_lr, max_grad_norm=None)],
        }
