import math

import pytest
import torch

from torchrl_mpail2.functional import gradient_penalty, lambda_return, mppi_weights, squashed_gaussian_sample


def test_lambda_return_three_steps_by_hand():
    r = torch.tensor([1.0, 2.0, 3.0])
    q = torch.tensor([10.0, 20.0, 30.0, 40.0])
    gamma, lmbda = 0.9, 0.8
    g3 = 40.0
    g2 = 0.8 * 30 + 0.2 * (3 + 0.9 * g3)   # 24 + 0.2 * 39 = 31.8
    g1 = 0.8 * 20 + 0.2 * (2 + 0.9 * g2)   # 16 + 0.2 * 30.62 = 22.124
    g0 = 0.8 * 10 + 0.2 * (1 + 0.9 * g1)   # 8 + 0.2 * 20.9116 = 12.18232
    assert g0 == pytest.approx(12.18232)
    assert lambda_return(r, q, gamma, lmbda).item() == pytest.approx(g0, rel=1e-6)


def test_lambda_return_batched_and_limits():
    r, q = torch.rand(5, 4, 3), torch.rand(5, 4, 4)
    assert lambda_return(r, q, 0.99, 0.95).shape == (5, 4)
    # lambda = 1 is pure bootstrap: G = q_t; lambda = 0 is the discounted reward sum plus gamma^H q_H
    assert torch.allclose(lambda_return(r, q, 0.9, 1.0), q[..., 0])
    mc = r[..., 0] + 0.9 * r[..., 1] + 0.81 * r[..., 2] + 0.729 * q[..., 3]
    assert torch.allclose(lambda_return(r, q, 0.9, 0.0), mc, atol=1e-6)
    with pytest.raises(ValueError, match="one more step"):
        lambda_return(r, r, 0.9, 0.5)


def test_gradient_penalty_linear_critic():
    w = torch.tensor([0.6, 0.8, 2.0])  # norm sqrt(0.36 + 0.64 + 4) = sqrt(5)
    gp = gradient_penalty(lambda x: (x @ w).unsqueeze(-1), torch.randn(16, 3), torch.randn(16, 3))
    assert gp.item() == pytest.approx((math.sqrt(5.0) - 1.0) ** 2, rel=1e-5)
    unit = torch.tensor([0.6, 0.8, 0.0])
    assert gradient_penalty(lambda x: x @ unit, torch.randn(8, 3), torch.randn(8, 3)).item() == pytest.approx(0.0, abs=1e-10)


def test_gradient_penalty_backpropagates_to_critic_parameters():
    critic = torch.nn.Linear(4, 1, bias=False)
    gp = gradient_penalty(critic, torch.randn(8, 4), torch.randn(8, 4))
    gp.backward()
    # d/dw (||w|| - 1)^2 = 2 (||w|| - 1) w / ||w||
    w = critic.weight.detach()
    expected = 2 * (w.norm() - 1) * w / w.norm()
    assert torch.allclose(critic.weight.grad, expected, atol=1e-5)


def test_mppi_weights_by_hand_and_elite_selection():
    returns = torch.tensor([[1.0, 5.0, 3.0, -2.0]])
    w, idx = mppi_weights(returns, num_elites=2, temperature=2.0)
    assert idx.tolist() == [[1, 2]]
    e = math.exp((3.0 - 5.0) / 2.0)
    assert w[0].tolist() == pytest.approx([1 / (1 + e), e / (1 + e)], rel=1e-6)


@pytest.mark.parametrize("scale", [1e4, 1e6, -1e6])
def test_mppi_weights_finite_for_large_returns(scale):
    returns = torch.randn(3, 512) * 10 + scale
    w, _ = mppi_weights(returns, 64, 2.0)
    assert torch.isfinite(w).all()
    assert torch.allclose(w.sum(-1), torch.ones(3))


def test_squashed_gaussian_log_prob_matches_torch_distributions():
    mean, log_std = torch.randn(6, 2), torch.randn(6, 2) * 0.3
    torch.manual_seed(1)
    a, lp = squashed_gaussian_sample(mean, log_std)
    base = torch.distributions.Normal(mean, log_std.exp())
    dist = torch.distributions.TransformedDistribution(base, [torch.distributions.TanhTransform(cache_size=1)])
    assert torch.allclose(lp, dist.log_prob(a).sum(-1), atol=1e-4)
    assert a.abs().max() < 1
    det, _ = squashed_gaussian_sample(mean, log_std, deterministic=True)
    assert torch.allclose(det, torch.tanh(mean))


@pytest.mark.parametrize("form", ["paper", "authors", "td_lambda"])
def test_multi_step_return_forms_weight_the_rollout_steps_as_documented(form):
    from torchrl_mpail2.functional import multi_step_return

    gamma, lmbda, horizon = 0.99, 0.95, 7
    r = torch.randn(horizon, requires_grad=True)
    q = torch.randn(horizon + 1)
    multi_step_return(r, q, gamma, lmbda, form).backward()
    k = torch.arange(horizon, dtype=torch.float32)
    expected = {"paper": (1 - lmbda) * ((1 - lmbda) * gamma) ** k,
                "td_lambda": (gamma * lmbda) ** k,
                "authors": (1 - lmbda) * (gamma * lmbda) ** k}[form]
    torch.testing.assert_close(r.grad, expected)


def test_td_lambda_return_is_the_n_step_mixture():
    """At lambda 0 it is the one-step TD target, at lambda 1 the H-step Monte Carlo return plus bootstrap."""
    from torchrl_mpail2.functional import td_lambda_return

    r, q = torch.tensor([1.0, 2.0, 3.0]), torch.tensor([5.0, 6.0, 7.0, 8.0])
    assert td_lambda_return(r, q, 0.5, 0.0).item() == pytest.approx(1 + 0.5 * 6)
    assert td_lambda_return(r, q, 0.5, 1.0).item() == pytest.approx(1 + 0.5 * 2 + 0.25 * 3 + 0.125 * 8)
