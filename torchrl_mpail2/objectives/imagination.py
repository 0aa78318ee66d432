r"""Imagined policy rollouts and their lambda-return :math:`G^\lambda_t(\hat{\boldsymbol\tau}^\pi_t)` (Eq. 6).

Shared by the value target (slow target Q, no gradient) and the actor objective (online Q,
frozen parameters, gradient through the actions).
"""
from __future__ import annotations

from collections.abc import Callable
from contextlib import contextmanager, nullcontext

import torch
from torch import Tensor, nn

from torchrl_mpail2.functional import RETURN_FORMS, multi_step_return, rewarded_steps
from torchrl_mpail2.modules.dynamics import DynamicsNet
from torchrl_mpail2.modules.policy import PlanPolicyNet
from torchrl_mpail2.modules.reward import RewardNet
from torchrl_mpail2.modules.value import QEnsembleNet, draw_heads
from torchrl_mpail2.modules.world_model import chain_rewards, rollout_latents


def checked_return_form(form: str) -> str:
    """``form`` if it is one of :data:`~torchrl_mpail2.functional.RETURN_FORMS`; a ValueError naming them otherwise."""
    if form not in RETURN_FORMS:
        raise ValueError(f"unknown return_form {form!r}; choose from {RETURN_FORMS}")
    return form


def ensemble_estimate(qnet: QEnsembleNet, reduce: str) -> Callable[[Tensor, Tensor], Tensor]:
    """``(z, a) -> [*B]``: min (targets) or mean (objectives) over two random heads."""
    if reduce not in ("min", "mean"):
        raise ValueError(f"reduce must be 'min' or 'mean', got {reduce!r}")

    def estimate(z: Tensor, a: Tensor) -> Tensor:
        q = qnet(z, a, heads=draw_heads(qnet.num_q, z.device)).squeeze(-1)
        return q.min(0).values if reduce == "min" else q.mean(0)

    return estimate


def imagined_lambda_return(
    z0: Tensor, plan: Tensor, dynamics: DynamicsNet, reward: RewardNet, q_estimate: Callable[[Tensor, Tensor], Tensor],
    policy: PlanPolicyNet, gamma: float, lmbda: float, return_form: str = "paper",
    stop_gradient_dtype: torch.dtype | None = None, terminal_value: str = "policy_action",
) -> Tensor:
    r"""Lambda-return of a plan rolled out through the latent model.

    ``q`` at step ``t+H`` needs an action beyond the H-step plan; as in TD-MPC2 it is the first
    step of a policy sample at :math:`\hat z_{t+H}` (``terminal_value="policy_action"``). With
    ``"plan_last_action"`` the path stops a step short and ends on the plan's own last action, as the planner's
    score of that form (:func:`~torchrl_mpail2.functional.rewarded_steps`).

    Args:
        z0 (Tensor): start latents ``[M, Z]``.
        plan (Tensor): actions ``[M, H, A]``.
        q_estimate (Callable): ``(z [H+1, M, Z], a [H+1, M, A]) -> [H+1, M]``.
        return_form (str): one of :data:`~torchrl_mpail2.functional.RETURN_FORMS`.
        stop_gradient_dtype (torch.dtype, optional): autocast dtype of the rollout when gradients are disabled
            (the value target); ignored where gradients are enabled (the actor's return). None: float32.

    Returns:
        Tensor: ``G`` of shape ``[M]``, float32 in either case.
    """
    dtype = None if torch.is_grad_enabled() else stop_gradient_dtype
    low_precision = torch.autocast(z0.device.type, dtype=dtype) if dtype is not None else nullcontext()
    rewarded = rewarded_steps(plan.shape[-2], terminal_value)
    with low_precision:
        latents = rollout_latents(dynamics, z0, plan[..., :rewarded, :])
        r = chain_rewards(reward, latents)
    if rewarded < plan.shape[-2]:
        last_action = plan[..., rewarded, :]
    else:  # sampled in float32 in any case, so that both precisions draw the same random numbers
        last_action = policy(latents[-1].float())[0][..., 0, :]
    with low_precision:
        actions = torch.cat([plan[..., :rewarded, :].transpose(0, 1), last_action.unsqueeze(0)], 0)
        q = q_estimate(latents, actions)
    return multi_step_return(r.transpose(0, 1).float(), q.transpose(0, 1).float(), gamma, lmbda, return_form)


@contextmanager
def frozen(*modules: nn.Module):
    """Runs the modules with their parameters marked as not requiring gradients, so no gradient
    reaches them while gradients still flow through their inputs.

    Autograd then records no weight edges, so the backward pass computes only the input gradients
    (about half the work of a full backward through these networks). The flags are restored on exit;
    the recorded graph stays valid after the context.
    """
    params = [p for m in modules for p in m.parameters() if p.requires_grad]
    try:
        for p in params:
            p.requires_grad_(False)
        yield
    finally:
        for p in params:
            p.requires_grad_(True)
