r"""Lambda-return value loss :math:`\mathcal L_Q(\zeta)` (Eq. 4) with a Polyak target ensemble."""
from __future__ import annotations

from contextlib import nullcontext

import torch
from tensordict import TensorDict, TensorDictBase, TensorDictParams

from torchrl_mpail2.modules.dynamics import LatentDynamics
from torchrl_mpail2.modules.encoder import ObservationEncoder
from torchrl_mpail2.modules.policy import MultiStepPolicy
from torchrl_mpail2.modules.reward import TransitionReward
from torchrl_mpail2.modules.value import QEnsemble
from torchrl_mpail2.modules.world_model import rollout_latents
from torchrl_mpail2.objectives.base import MPAIL2LossBase
from torchrl_mpail2.objectives.imagination import checked_return_form, ensemble_estimate, imagined_lambda_return


class LambdaReturnValueLoss(MPAIL2LossBase):
    r"""Every ensemble member regresses onto a model-based lambda-return target (Eq. 4).

    .. math::
        \mathcal L_Q = \sum_{e=1}^{E}\mathbb E_{(z,a,z')}\big[(Q^e_\zeta(z,a) - y)^2\big],\quad
        y = r_\theta(z, z') + \gamma\,(1 - d)\,\bar G^\lambda(z'),

    where :math:`\bar G^\lambda(z')` is the lambda-return (Eq. 6) of an imagined H-step policy plan
    from :math:`z'` scored with the slow target :math:`\bar Q_\zeta` (min over two random heads), and
    :math:`d` the termination flag when ``mask_terminal`` is set. Eq. 4 calls the target
    entropy-regularised, but Eq. 6 has no entropy term; Eq. 6 is followed.

    Args:
        encoder_network, dynamics_network, reward_network, qvalue_network, policy_network: the MPAIL2 modules.

    Keyword Args:
        gamma (float): discount (0.99). lmbda (float): return parameter (0.95).
        return_form (str): form of the imagined return, one of ``RETURN_FORMS`` (``"paper"``: Eq. 6 as printed).
        mask_terminal (bool): no bootstrap after terminal transitions (False: the robot tasks never terminate).
        head_reduce (str): ``"sum"`` (Eq. 4) or ``"mean"`` over the ensemble heads.
        encoder_grad (bool): regress :math:`Q^e_\zeta(e_\omega(o), a)` with the gradient reaching the encoder
            (``LossConfig.value_trains_encoder``; not in the paper). The target is computed from stop-gradient latents
            either way.
        branch_fraction (float): imagined branches beside the replayed transitions, as a share of them (0: none, as in
            the paper; ``LossConfig.value_branch_fraction``). See :meth:`imagined_branches`.
        branch_noise (float): std of the Gaussian noise added to the policy's plan along a branch.

    With ``bf16_stop_gradient`` set (the updater's bf16 mode) the target's imagined rollout runs under bfloat16
    autocast; the return itself is float32.

    Parameters: ``qvalue_network_params`` and ``target_qvalue_network_params`` (update the latter with
    ``torchrl.objectives.SoftUpdate(loss, tau=0.01)``).

    Returns: ``loss_value`` and detached ``q_mean``, ``q_target_mean``, ``learned_reward_mean``.
    """

    qvalue_network: QEnsemble
    qvalue_network_params: TensorDictParams
    target_qvalue_network_params: TensorDictParams
    dynamics_network: LatentDynamics
    reward_network: TransitionReward
    policy_network: MultiStepPolicy

    def __init__(self, encoder_network: ObservationEncoder, dynamics_network: LatentDynamics,
                 reward_network: TransitionReward, qvalue_network: QEnsemble, policy_network: MultiStepPolicy, *,
                 gamma: float = 0.99, lmbda: float = 0.95, return_form: str = "paper", mask_terminal: bool = False,
                 head_reduce: str = "sum", encoder_grad: bool = False, branch_fraction: float = 0.0,
                 branch_noise: float = 0.3, reduction: str = "mean"):
        super().__init__(encoder_network, reduction)
        self.__dict__["dynamics_network"] = dynamics_network  # read only: kept out of this loss's parameters
        self.__dict__["reward_network"] = reward_network
        self.__dict__["policy_network"] = policy_network
        self.convert_to_functional(qvalue_network, "qvalue_network", create_target_params=True)
        if head_reduce not in ("sum", "mean"):
            raise ValueError(f"head_reduce must be 'sum' or 'mean', got {head_reduce!r}")
        self.gamma, self.lmbda, self.mask_terminal, self.head_reduce = gamma, lmbda, mask_terminal, head_reduce
        self.encoder_grad = encoder_grad
        if branch_fraction < 0 or branch_noise < 0:
            raise ValueError(f"branch_fraction and branch_noise must be >= 0, got {branch_fraction} and {branch_noise}")
        self.branch_fraction, self.branch_noise = branch_fraction, branch_noise
        self.return_form = checked_return_form(return_form)

    @torch.no_grad()
    def target(self, z, z_next, terminated=None):
        """``y = r(z, z') + gamma (1 - d) G_bar(z')`` for flat ``[M, Z]`` latents -> ``([M], r [M])``."""
        policy = self.policy_network.net
        plan, _ = policy(z_next)
        with self.target_qvalue_network_params.data.to_module(self.qvalue_network):
            G = imagined_lambda_return(z_next, plan, self.dynamics_network.module, self.reward_network.module,
                                       ensemble_estimate(self.qvalue_network.net, "min"), policy, self.gamma, self.lmbda,
                                       self.return_form, torch.bfloat16 if self.bf16_stop_gradient else None)
        r = self.reward_network.module(z, z_next).squeeze(-1)
        if terminated is not None and self.mask_terminal:
            G = G * (~terminated.reshape(G.shape)).to(G.dtype)
        return r + self.gamma * G, r

    @torch.no_grad()
    def imagined_branches(self, z):
        r"""Transitions the replay lacks, imagined from its latents: ``z [M, Z]`` -> ``(z_b [m, Z], a_b [m, A],
        z_b' [m, Z])`` with ``m = round(branch_fraction * M)``.

        From ``m`` latents drawn from ``z``, a plan :math:`\tilde a = \mathrm{clip}(a^\pi + \sigma\epsilon, -1, 1)`
        (the policy's sample, :math:`\epsilon \sim \mathcal N(0, I)`, :math:`\sigma` = ``branch_noise``) is rolled
        through :math:`f_\psi`, and one step :math:`k \sim U\{0..H-1\}` of each path is kept:
        :math:`(\hat z_k, \tilde a_k, \hat z_{k+1})`. The planner scores its candidates by Q at such imagined
        latents, which the replay never holds; regressed onto the same target (Eq. 4 at imagined points, not in the
        paper) the value is held to the reward and its own bootstrap there instead of extrapolating.
        """
        m = round(self.branch_fraction * z.shape[0])
        if m == 0:
            return None
        start = z[torch.randint(z.shape[0], (m,), device=z.device)]
        plan, _ = self.policy_network.net(start)
        plan = (plan.float() + self.branch_noise * torch.randn_like(plan, dtype=torch.float32)).clamp(-1.0, 1.0)
        low_precision = (torch.autocast(z.device.type, dtype=torch.bfloat16) if self.bf16_stop_gradient
                         else nullcontext())  # as the target's rollout
        with low_precision:
            path = rollout_latents(self.dynamics_network.module, start, plan)  # [H+1, m, Z]
        k = torch.randint(plan.shape[-2], (m,), device=z.device)
        rows = torch.arange(m, device=z.device)
        return path[k, rows].float(), plan[rows, k], path[k + 1, rows].float()

    def forward(self, tensordict: TensorDictBase, latents=None) -> TensorDictBase:
        z, z_next = latents if latents is not None else self.replay_latents(tensordict)
        z, z_next = z.reshape(-1, z.shape[-1]), z_next.reshape(-1, z_next.shape[-1])
        action = self.require(tensordict, self.tensor_keys.action)
        action = action.reshape(-1, action.shape[-1])
        terminated = self.require(tensordict, self.tensor_keys.terminated) if self.mask_terminal else None
        z_fit = self.encode(tensordict).reshape(-1, z.shape[-1]) if self.encoder_grad else z  # Q's input
        branches = self.imagined_branches(z)
        if branches is not None:
            z_b, a_b, z_b_next = branches
            z, z_fit, z_next = torch.cat([z, z_b]), torch.cat([z_fit, z_b]), torch.cat([z_next, z_b_next])
            action = torch.cat([action, a_b.to(action.dtype)])
            if terminated is not None:  # imagined steps never terminate
                terminated = torch.cat([terminated.reshape(-1), terminated.new_zeros(z_b.shape[0])])
        y, r = self.target(z, z_next, terminated)
        q = self.qvalue_network.net(z_fit, action).squeeze(-1)  # [E, M]
        errors = (q - y).pow(2)  # [E, M]: each head regresses independently
        loss = self.reduce(errors.sum(0) if self.head_reduce == "sum" else errors.mean(0))
        return TensorDict({"loss_value": loss, "q_mean": q.detach().mean(), "q_target_mean": y.mean(),
                           "learned_reward_mean": r.mean()}, [])
