r"""Pure tensor math of MPAIL2: no modules, no configs.

Shape legend: ``B`` batch, ``T`` time, ``H`` horizon, ``N`` candidates, ``K`` elites,
``E`` ensemble, ``Z`` latent, ``A`` action.
"""
from __future__ import annotations

import math

import torch
from torch import Tensor

_LOG_SQRT_2PI = 0.5 * math.log(2 * math.pi)


def lambda_return(r: Tensor, q: Tensor, gamma: float, lmbda: float) -> Tensor:
    r"""Lambda-return of Eq. 6, computed backwards over the horizon.

    .. math::
        G_{t'} = \lambda \hat q_{t'} + (1 - \lambda)\,[\hat r_{t'} + \gamma G_{t'+1}],
        \qquad G_{t+H} = \hat q_{t+H}.

    Note that lambda weights the bootstrap ``q`` here (the paper's convention), the opposite
    of the usual TD(lambda) form; the recursion is implemented exactly as written.

    Args:
        r (Tensor): rewards ``[*B, H]`` for steps ``t .. t+H-1``.
        q (Tensor): values ``[*B, H+1]`` for steps ``t .. t+H``.
        gamma (float): discount.
        lmbda (float): return parameter.

    Returns:
        Tensor: ``G_t`` of shape ``[*B]``.

    Examples:
        >>> r = torch.tensor([1.0, 2.0])
        >>> q = torch.tensor([10.0, 20.0, 30.0])
        >>> # G_2 = 30; G_1 = 0.5*20 + 0.5*(2 + 30) = 26; G_0 = 0.5*10 + 0.5*(1 + 26) = 18.5
        >>> lambda_return(r, q, gamma=1.0, lmbda=0.5)
        tensor(18.5000)
    """
    horizon = r.shape[-1]
    if q.shape[-1] != horizon + 1:
        raise ValueError(f"q must have one more step than r: r {tuple(r.shape)}, q {tuple(q.shape)}")
    G = q[..., horizon]
    for k in range(horizon - 1, -1, -1):
        G = lmbda * q[..., k] + (1.0 - lmbda) * (r[..., k] + gamma * G)
    return G


def td_lambda_return(r: Tensor, q: Tensor, gamma: float, lmbda: float) -> Tensor:
    r"""The standard TD(lambda) return (Sutton and Barto; Dreamer, TD-MPC2), computed backwards.

    .. math::
        G_{k} = \hat r_{k} + \gamma\,[(1 - \lambda)\,\hat q_{k+1} + \lambda G_{k+1}],
        \qquad G_{H} = \hat q_{H}.

    Here lambda weights the longer returns: every step of the rollout reaches ``G_0`` with weight
    :math:`(\gamma\lambda)^k`, where in :func:`lambda_return` it is :math:`((1-\lambda)\gamma)^k`.

    Args:
        r (Tensor): rewards ``[*B, H]``. q (Tensor): values ``[*B, H+1]``. gamma, lmbda (float).

    Returns:
        Tensor: ``G_0`` of shape ``[*B]``.

    Examples:
        >>> r = torch.tensor([1.0, 2.0])
        >>> q = torch.tensor([10.0, 20.0, 30.0])
        >>> # G_2 = 30; G_1 = 2 + 0.5*30 + 0.5*30 = 32; G_0 = 1 + 0.5*20 + 0.5*32 = 27
        >>> td_lambda_return(r, q, gamma=1.0, lmbda=0.5)
        tensor(27.)
    """
    horizon = r.shape[-1]
    if q.shape[-1] != horizon + 1:
        raise ValueError(f"q must have one more step than r: r {tuple(r.shape)}, q {tuple(q.shape)}")
    G = q[..., horizon]
    for k in range(horizon - 1, -1, -1):
        G = r[..., k] + gamma * ((1.0 - lmbda) * q[..., k + 1] + lmbda * G)
    return G


#: The forms of the multi-step return an imagined rollout is scored with (see :func:`multi_step_return`).
RETURN_FORMS = ("paper", "authors", "td_lambda")


def multi_step_return(r: Tensor, q: Tensor, gamma: float, lmbda: float, form: str = "paper") -> Tensor:
    r"""Return of an imagined rollout in one of :data:`RETURN_FORMS`.

    * ``"paper"``: Eq. 6 as printed (:func:`lambda_return`), :math:`\approx \hat q_0` at lambda 0.95: the
      gradient reaching plan step ``k`` falls like :math:`(1-\lambda)^k`.
    * ``"authors"``: the authors' public implementation, :math:`\lambda \hat q_0 + (1-\lambda)\,G^{TD(\lambda)}_0`.
    * ``"td_lambda"``: the standard TD(lambda) return :math:`G^{TD(\lambda)}_0` (:func:`td_lambda_return`).

    Examples:
        >>> r, q = torch.tensor([1.0, 2.0]), torch.tensor([10.0, 20.0, 30.0])
        >>> [round(multi_step_return(r, q, 1.0, 0.8, f).item(), 2) for f in RETURN_FORMS]
        [12.68, 14.12, 30.6]
    """
    if form == "paper":
        return lambda_return(r, q, gamma, lmbda)
    if form not in RETURN_FORMS:
        raise ValueError(f"unknown return form {form!r}; choose from {RETURN_FORMS}")
    G = td_lambda_return(r, q, gamma, lmbda)
    return G if form == "td_lambda" else lmbda * q[..., 0] + (1.0 - lmbda) * G


#: Where an imagined path's return hands over to the value :math:`Q_\zeta` (see :func:`rewarded_steps`).
TERMINAL_VALUES = ("policy_action", "plan_last_action")


def rewarded_steps(horizon: int, terminal_value: str) -> int:
    r"""``K``, the rewards an ``H``-step imagined path earns before :math:`Q_\zeta` closes its return, by the
    terminal-value form (one of :data:`TERMINAL_VALUES`):

    * ``"policy_action"``: ``K = H``, :math:`Q_\zeta(\hat z_H, a_H)` with :math:`a_H` the policy's first action at
      :math:`\hat z_H` (Eq. 6, TD-MPC2);
    * ``"plan_last_action"``: ``K = H - 1``, :math:`Q_\zeta(\hat z_{H-1}, a_{H-1})` with the plan's own last action
      (the authors' planner).

    Examples:
        >>> rewarded_steps(5, "policy_action"), rewarded_steps(5, "plan_last_action")
        (5, 4)
    """
    if terminal_value not in TERMINAL_VALUES:
        raise ValueError(f"unknown terminal_value {terminal_value!r}; choose from {TERMINAL_VALUES}")
    return horizon - (terminal_value == "plan_last_action")


def n_step_return(r: Tensor, q_end: Tensor, gamma: float) -> tuple[Tensor, Tensor]:
    r"""The two terms of the ``K``-step return :math:`\sum_{k<K}\gamma^k r_k + \gamma^K q_K` (Algorithm 2's plan
    score; :func:`td_lambda_return` at :math:`\lambda = 1`): ``r [..., K]``, ``q_end [...]`` -> ``(reward sum,
    terminal value)``, each ``[...]``.

    Examples:
        >>> r, q = torch.tensor([1.0, 2.0]), torch.tensor([10.0, 20.0, 30.0])
        >>> rewards, terminal = n_step_return(r, q[-1], 0.5)
        >>> rewards.item(), terminal.item(), td_lambda_return(r, q, 0.5, 1.0).item()
        (2.0, 7.5, 9.5)
    """
    discounts = gamma ** torch.arange(r.shape[-1], dtype=r.dtype, device=r.device)
    return (r * discounts).sum(-1), gamma ** r.shape[-1] * q_end


def gradient_penalty(critic, x_expert: Tensor, x_agent: Tensor, generator: torch.Generator | None = None) -> Tensor:
    r"""WGAN-GP penalty of Appendix A.2 on per-sample uniform interpolations.

    .. math:: \mathrm{GP} = \mathbb{E}_{\tilde x}\big[(\lVert\nabla_{\tilde x} r(\tilde x)\rVert_2 - 1)^2\big],
              \quad \tilde x = \epsilon x_E + (1-\epsilon) x_B,\ \epsilon \sim U(0, 1).

    Args:
        critic (Callable): maps ``[N, D]`` to ``[N, 1]`` (or ``[N]``) scores.
        x_expert (Tensor): expert inputs ``[N, D]`` (for MPAIL2, concatenated ``(z, z')``).
        x_agent (Tensor): agent inputs ``[N, D]``.
        generator (torch.Generator, optional): source of the interpolation coefficients.

    Returns:
        Tensor: scalar penalty, differentiable w.r.t. the critic's parameters.

    Examples:
        >>> w = torch.tensor([3.0, 4.0])  # a linear critic with gradient norm 5 everywhere
        >>> gp = gradient_penalty(lambda x: x @ w, torch.zeros(8, 2), torch.ones(8, 2))
        >>> gp  # (5 - 1)^2
        tensor(16.)
    """
    if x_expert.shape != x_agent.shape:
        raise ValueError(f"expert and agent inputs must match: {tuple(x_expert.shape)} vs {tuple(x_agent.shape)}")
    eps_shape = (x_expert.shape[0],) + (1,) * (x_expert.dim() - 1)
    eps = torch.rand(eps_shape, device=x_expert.device, dtype=x_expert.dtype, generator=generator)
    x = (eps * x_expert.detach() + (1.0 - eps) * x_agent.detach()).requires_grad_(True)
    with torch.enable_grad():
        score = critic(x)
        (grad,) = torch.autograd.grad(score.sum(), x, create_graph=True)
    norm = grad.flatten(1).norm(dim=-1)
    return (norm - 1.0).pow(2).mean()


def mppi_weights(returns: Tensor, num_elites: int, temperature: float) -> tuple[Tensor, Tensor]:
    r"""Softmax weights of the ``K`` best plans (Algorithm 2), max-subtracted so they never overflow.

    .. math:: w_k \propto \exp\big((\mathcal R_k - \max_j \mathcal R_j) / \eta\big)\ \text{for the K elites, } 0 \text{ otherwise}.

    Algorithm 2 writes "set non-elite returns to 0" before the softmax, which would still give them
    weight; the text's intent (non-elites do not contribute) is what is implemented.

    Args:
        returns (Tensor): plan returns ``[*B, N]``.
        num_elites (int): ``K``.
        temperature (float): ``eta``.

    Returns:
        tuple: ``(weights [*B, K], elite_index [*B, K])``; weights sum to one over ``K``.

    Examples:
        >>> w, idx = mppi_weights(torch.tensor([0.0, 2.0, 1e4, 1e4 - 2.0]), num_elites=2, temperature=2.0)
        >>> idx.tolist(), [round(v, 4) for v in w.tolist()]
        ([2, 3], [0.7311, 0.2689])
    """
    elite_returns, elite_index = returns.topk(num_elites, dim=-1)
    logits = (elite_returns - elite_returns[..., :1]) / temperature
    return torch.softmax(logits, dim=-1), elite_index


def squashed_gaussian_sample(
    mean: Tensor, log_std: Tensor, deterministic: bool = False, generator: torch.Generator | None = None
) -> tuple[Tensor, Tensor]:
    r"""Reparameterised sample of :math:`\tanh(\mathcal N(\mu, \sigma^2))` and its log-density.

    The density is summed over the last dimension (one action step), with the exact
    change-of-variables correction :math:`\log(1 - \tanh^2 u) = 2(\log 2 - u - \mathrm{softplus}(-2u))`.

    Returns:
        tuple: ``(action, log_prob)`` with ``log_prob`` of shape ``mean.shape[:-1]``.
    """
    if deterministic:
        u = mean
    else:
        noise = torch.randn(mean.shape, device=mean.device, dtype=mean.dtype, generator=generator)
        u = mean + log_std.exp() * noise
    gauss = -0.5 * ((u - mean) / log_std.exp()).pow(2) - log_std - _LOG_SQRT_2PI
    log_det = 2.0 * (math.log(2.0) - u - torch.nn.functional.softplus(-2.0 * u))
    return torch.tanh(u), (gauss - log_det).sum(-1)
