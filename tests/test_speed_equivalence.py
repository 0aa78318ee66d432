"""The fast paths compute what the straightforward code computes.

* the planner against Algorithm 2 written out with plain loops (one candidate, one step at a time),
  drawing the same random numbers from the same ``torch.Generator`` seed;
* the bf16 planning mode really runs the networks in bf16 and leaves the learner's parameters alone;
* the Q-ensemble's stacked layers against a per-head loop;
* one ``MPAIL2Updater.update`` (window encoding, frozen networks, malloc setting) against per-loss calls
  on plainly encoded latents with hand-written optimiser steps.
"""
import contextlib
import copy
import math
from unittest import mock

import pytest
import torch
import torch.nn.functional as F
from tensordict import TensorDict
from torchrl.data import Bounded
from torchrl.envs.utils import ExplorationType, set_exploration_type

from conftest import tiny_modules
from torchrl_mpail2 import LatentMPPIPlanner, LossConfig, MPAIL2Loss, MPAIL2Updater, PlannerConfig
from torchrl_mpail2.config import ModelConfig
from torchrl_mpail2.modules import MPAIL2Modules
from torchrl_mpail2.objectives import actor as actor_module
from torchrl_mpail2.modules.value import HEADS_PER_ESTIMATE

PLANNER = dict(num_candidates=64, num_elites=8, iterations=3, temperature=0.5, policy_fraction=0.1)


@pytest.fixture(autouse=True)
def _one_thread():
    """Tiny tensors: one thread is fastest, and stays fast when other jobs load the machine."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


# ---- planner --------------------------------------------------------------------------------------
def reference_plan(m, cfg: PlannerConfig, obs, generator, prev_mean=None, deterministic=True, temperature=None):
    """Algorithm 2 with loops; returns ``(action [B, A], plan [B, H, A])``."""
    temperature = cfg.temperature if temperature is None else temperature
    H, A, gamma = m.cfg.horizon, m.action_dim, LossConfig.gamma
    num_pi = cfg.num_policy_samples
    num_gauss = cfg.num_candidates - num_pi
    with torch.no_grad():
        z = m.encoder.net(obs)
        B = z.shape[0]
        heads = torch.randperm(m.value.net.num_q, generator=generator)[:HEADS_PER_ESTIMATE]
        pi_plans = m.policy.net(z.unsqueeze(1).expand(B, num_pi, z.shape[-1]), generator=generator)[0]

        def plan_return(b, plan):
            zk, total = z[b], 0.0
            for k in range(H):
                z_next = m.dynamics.module(zk, plan[k])
                total = total + gamma ** k * m.reward.module(zk, z_next).squeeze()
                zk = z_next
            a_last = m.policy.net(zk, deterministic=True)[0][0]
            q = m.value.net(zk, a_last, heads=heads).mean()
            return total + gamma ** H * q

        mean = torch.zeros(B, H, A)
        if prev_mean is not None:
            mean[:, :-1] = prev_mean[:, 1:]
        std = torch.full((B, H, A), cfg.std_max)
        for _ in range(cfg.iterations):
            noise = torch.randn(B, num_gauss, H, A, generator=generator)
            for b in range(B):
                candidates = [(mean[b] + std[b] * noise[b, i]).clamp(-1, 1) for i in range(num_gauss)]
                candidates += [pi_plans[b, i] for i in range(num_pi)]
                returns = [float(plan_return(b, c)) for c in candidates]
                elites = sorted(range(len(candidates)), key=lambda i: -returns[i])[: cfg.num_elites]
                best = returns[elites[0]]
                w = [math.exp((returns[i] - best) / temperature) for i in elites]
                w = [x / sum(w) for x in w]
                new_mean = sum(wi * candidates[i] for wi, i in zip(w, elites))
                var = sum(wi * (candidates[i] - new_mean) ** 2 for wi, i in zip(w, elites))
                mean[b], std[b] = new_mean, var.sqrt().clamp(cfg.std_min, cfg.std_max)
        plan = mean if deterministic else (mean + std * torch.randn(mean.shape, generator=generator)).clamp(-1, 1)
    return plan[:, 0], plan, mean


def _planner_case():
    m = tiny_modules(obs_dim=3, action_dim=2, horizon=3)
    cfg = PlannerConfig(**PLANNER)
    obs = torch.randn(2, 3)
    return m, cfg, obs


@pytest.mark.parametrize("deterministic", [True, False])
def test_planner_matches_loop_reference_with_the_same_random_numbers(deterministic):
    m, cfg, obs = _planner_case()
    planner = LatentMPPIPlanner(m, Bounded(-1, 1, (2,)), cfg, gamma=LossConfig.gamma, generator=torch.Generator().manual_seed(7))
    gen = torch.Generator().manual_seed(7)
    mode = ExplorationType.DETERMINISTIC if deterministic else ExplorationType.RANDOM
    prev = None
    for _ in range(2):  # the second call starts from the shifted first plan (warm start)
        with set_exploration_type(mode):
            td = planner(TensorDict({"observation": obs}, [2]))
        action, plan, prev = reference_plan(m, cfg, obs, gen, prev_mean=prev, deterministic=deterministic)
        torch.testing.assert_close(td["plan"], plan, atol=1e-4, rtol=1e-4)
        torch.testing.assert_close(td["action"], action, atol=1e-4, rtol=1e-4)
    # the comparison discriminates: a reference with another temperature picks another plan
    _, other, _ = reference_plan(m, cfg, obs, torch.Generator().manual_seed(7), deterministic=True, temperature=5.0)
    first = LatentMPPIPlanner(m, Bounded(-1, 1, (2,)), cfg, gamma=LossConfig.gamma, generator=torch.Generator().manual_seed(7))
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        assert (first(TensorDict({"observation": obs}, [2]))["plan"] - other).abs().max() > 1e-3


def test_bf16_planning_runs_the_networks_in_bf16_and_restores_the_parameters():
    m, cfg, obs = _planner_case()
    params_before = {k: (v, v.clone()) for k, v in m.named_parameters()}
    seen = []
    hooks = [net.register_forward_hook(lambda mod, inp, out: seen.append((type(mod).__name__, out.dtype)))
             for net in (m.dynamics.module.net[0], m.reward.module.net[2], m.policy.net.net[0])]
    planner = LatentMPPIPlanner(m, Bounded(-1, 1, (2,)), PlannerConfig(**PLANNER, bf16=True), gamma=LossConfig.gamma,
                                generator=torch.Generator().manual_seed(0))
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        td = planner(TensorDict({"observation": obs}, [2]))
    for h in hooks:
        h.remove()
    assert seen and all(dtype == torch.bfloat16 for _, dtype in seen), seen
    assert td["action"].dtype == torch.float32 and torch.isfinite(td["action"]).all()
    for name, p in m.named_parameters():
        original, value = params_before[name]
        assert p is original and p.dtype == torch.float32 and torch.equal(p, value), name
    # bf16 returns track the fp32 returns of the same plans
    z = m.encoder.net(obs)
    plans = torch.rand(2, 16, 3, 2) * 2 - 1
    heads = torch.tensor([0, 3])
    with torch.no_grad():
        fp32 = planner.score(z, plans, heads)
        with planner._low_precision() as dtype:
            bf16 = planner.score(z.to(dtype), plans, heads)
    assert bf16.dtype == torch.float32
    assert (bf16 - fp32).abs().max() < 0.05 * fp32.abs().max()


# ---- Q ensemble -------------------------------------------------------------------------------------
@pytest.mark.parametrize("heads", [None, torch.tensor([3, 1])])
def test_stacked_q_layers_match_a_per_head_loop(heads):
    q = tiny_modules().value.net
    with torch.no_grad():
        for p in q.parameters():
            p.add_(torch.randn_like(p) * 0.1)  # non-trivial LayerNorm affine parameters
    z, a = torch.randn(5, 16), torch.randn(5, 2)
    out = q(z, a, heads=heads)
    chosen = range(q.num_q) if heads is None else heads.tolist()
    expected = []
    for e in chosen:
        x = torch.cat([z, a], -1)
        for linear, norm in zip(q.linears, q.norms):
            x = F.silu(F.layer_norm(x @ linear.weight[e] + linear.bias[e], (linear.weight.shape[-1],),
                                    norm.weight[e], norm.bias[e]))
        expected.append(x @ q.head.weight[e] + q.head.bias[e])
    torch.testing.assert_close(out, torch.stack(expected), atol=1e-5, rtol=1e-5)


# ---- update ---------------------------------------------------------------------------------------------
def _update_case(contiguous: bool, images: bool):
    shapes = {"observation": [3]}
    if images:
        shapes["camera"] = [3, 64, 64]
    cfg = ModelConfig(latent_dim=16, hidden_dims=(32, 32), coder_dim=32, vector_coder_hidden=32, cnn_channels=8, horizon=3)
    m = MPAIL2Modules(shapes, 2, cfg)
    B, T = 4, 3

    def observations():
        out = {}
        for key, shape in shapes.items():
            if len(shape) == 3:
                out[key] = torch.randint(0, 256, (B, T + 1, *shape), dtype=torch.uint8)
            else:
                out[key] = torch.randn(B, T + 1, *shape)
        return out

    data = {"action": torch.rand(B, T, 2) * 2 - 1, ("next", "terminated"): torch.zeros(B, T, 1, dtype=torch.bool)}
    agent, expert, other = observations(), observations(), observations()
    for key in shapes:
        data[key] = agent[key][:, :-1]
        data[("next", key)] = agent[key][:, 1:] if contiguous else other[key][:, 1:]
        data[("expert", key)], data[("expert", "next", key)] = expert[key][:, :-1], expert[key][:, 1:]
    return m, TensorDict(data, [B, T])


def _reference_update(loss: MPAIL2Loss, opt: MPAIL2Updater, td: TensorDict) -> tuple[dict, dict]:
    """The update as separate per-loss calls on plainly encoded latents; returns (metrics, grads per stage)."""
    m, grads, metrics = loss.components, {}, {}

    def step(stage, value, modules):
        optimizer = opt.optimizers[stage]
        optimizer.zero_grad(set_to_none=True)
        value.backward()
        if opt.max_grad_norm[stage] is not None:
            torch.nn.utils.clip_grad_norm_([p for g in optimizer.param_groups for p in g["params"]], opt.max_grad_norm[stage])
        for prefix, module in modules.items():
            for name, p in module.named_parameters():
                grads[f"{prefix}.{name}"] = None if p.grad is None else p.grad.clone()
        optimizer.step()

    # Eq. 2 by hand: gradient through the first latent only, stop-gradient targets
    z = m.encoder.encode(td[:, 0])
    with torch.no_grad():
        targets = m.encoder.encode(td, ("next",))
    total = 0.0
    for k in range(td.shape[1]):
        z = m.dynamics.module(z, td["action"][:, k])
        total = total + loss.cfg.rho ** (k + 1) * (z - targets[:, k]).pow(2).sum(-1)
    metrics["loss_dynamics"] = total.mean()
    step("dynamics", metrics["loss_dynamics"], {"encoder": m.encoder, "dynamics": m.dynamics})
    with torch.no_grad():  # encoded after the dynamics step, each key and prefix separately
        latents = m.encoder.encode(td), m.encoder.encode(td, ("next",))
        expert = m.encoder.encode(td, ("expert",)), m.encoder.encode(td, ("expert", "next"))
    out = loss.reward_loss(td, latents=latents, expert_latents=expert)
    metrics.update(out.items())
    step("reward", out["loss_reward"], {"reward": m.reward})
    out = loss.value_loss(td, latents=latents)
    metrics.update(out.items())
    step("value", out["loss_value"], {"value": m.value})
    opt.target_updater.step()
    with mock.patch.object(actor_module, "frozen", lambda *modules: contextlib.nullcontext()):
        out = loss.actor_loss(td, latents=latents)  # no freezing: only the policy's optimiser steps
    metrics.update(out.items())
    step("actor", out["loss_actor"], {"policy": m.policy})
    step("alpha", out["loss_alpha"], {})
    return {k: v.detach() for k, v in metrics.items()}, grads


@pytest.mark.parametrize("contiguous,images", [(True, False), (False, False), (True, True)])
def test_update_matches_per_loss_calls(contiguous, images):
    m, td = _update_case(contiguous, images)
    m_ref = copy.deepcopy(m)
    loss, loss_ref = MPAIL2Loss(m, LossConfig(init_alpha=0.1)), MPAIL2Loss(m_ref, LossConfig(init_alpha=0.1))
    updater, reference = MPAIL2Updater(loss), MPAIL2Updater(loss_ref, retain_memory=False)
    torch.manual_seed(11)
    metrics = updater.update(td)
    torch.manual_seed(11)
    ref_metrics, ref_grads = _reference_update(loss_ref, reference, td)
    for key in ("loss_dynamics", "loss_reward", "loss_value", "loss_actor", "loss_alpha", "grad_penalty", "q_target_mean"):
        torch.testing.assert_close(metrics[key], ref_metrics[key], atol=1e-5, rtol=1e-4, msg=key)
    modules = {"encoder": m.encoder, "dynamics": m.dynamics, "reward": m.reward, "value": m.value, "policy": m.policy}
    for prefix, module in modules.items():
        for name, p in module.named_parameters():
            key, expected = f"{prefix}.{name}", ref_grads[f"{prefix}.{name}"]
            # only the stage that trains a network leaves a gradient on it (frozen ones get none from the actor)
            assert (p.grad is None) == (expected is None), key
            if expected is not None:
                # float32 sums in another order: errors scale with the largest gradient entry (about 1e-6 of it
                # for the image encoder's layers, whose gradients reach 10-30)
                atol = max(1e-5, 4e-6 * expected.abs().max().item())
                torch.testing.assert_close(p.grad, expected, atol=atol, rtol=1e-4, msg=key)
    for (name, p), p_ref in zip(m.named_parameters(), m_ref.parameters()):
        torch.testing.assert_close(p, p_ref, atol=1e-6, rtol=1e-5, msg=name)
    for a, b in zip(loss.value_loss.target_qvalue_network_params.values(True, True),
                    loss_ref.value_loss.target_qvalue_network_params.values(True, True)):
        torch.testing.assert_close(a, b, atol=1e-6, rtol=1e-5)


def test_bf16_updates_encode_stop_gradient_latents_close_and_return_them_in_float32():
    m, td = _update_case(contiguous=True, images=False)
    loss = MPAIL2Loss(m)
    z32 = loss.replay_latents(td)[0]
    MPAIL2Updater(loss, retain_memory=False)
    assert not loss.reward_loss.bf16_stop_gradient  # default: float32 latents, unchanged results
    MPAIL2Updater(loss, retain_memory=False, bf16=True)
    assert all(sub.bf16_stop_gradient for sub in (loss, loss.dynamics_loss, loss.value_loss, loss.actor_loss))
    z16 = loss.replay_latents(td)[0]
    assert z16.dtype == torch.float32 and not torch.equal(z16, z32)
    assert (z16 - z32).abs().max() < 0.1
    with torch.enable_grad():  # latents that carry gradients are never computed in bf16
        torch.testing.assert_close(loss.encode(td), m.encoder.encode(td), atol=1e-6, rtol=1e-5)


def test_bf16_value_target_is_close_and_gradient_paths_stay_fp32():
    m, td = _update_case(contiguous=True, images=False)
    loss = MPAIL2Loss(m)
    z, z_next = (x.reshape(-1, 16) for x in loss.replay_latents(td))
    torch.manual_seed(3)
    y32, _ = loss.value_loss.target(z, z_next)
    torch.manual_seed(4)
    actor32 = loss.actor_loss(td, latents=(z, z_next))["loss_actor"]
    loss.value_loss.bf16_stop_gradient = loss.actor_loss.bf16_stop_gradient = True
    torch.manual_seed(3)
    y16, _ = loss.value_loss.target(z, z_next)
    torch.manual_seed(4)
    actor16 = loss.actor_loss(td, latents=(z, z_next))["loss_actor"]
    assert y16.dtype == torch.float32 and not torch.equal(y16, y32)
    assert (y16 - y32).abs().max() < 0.05 * y32.abs().max()
    assert torch.equal(actor16, actor32)  # returns with gradients stay float32


def _flat_grads(module) -> torch.Tensor:
    return torch.cat([p.grad.flatten() for p in module.parameters() if p.grad is not None])


@pytest.mark.parametrize("images", [False, True])
def test_bf16_update_is_mixed_precision_and_close_to_fp32(images):
    m, td = _update_case(contiguous=True, images=images)
    m32 = copy.deepcopy(m)
    loss, loss32 = MPAIL2Loss(m, LossConfig(init_alpha=0.1)), MPAIL2Loss(m32, LossConfig(init_alpha=0.1))
    updater = MPAIL2Updater(loss, retain_memory=False, bf16=True)
    assert all(sub.bf16_stop_gradient for sub in (loss.dynamics_loss, loss.value_loss, loss.actor_loss))
    reference = MPAIL2Updater(loss32, retain_memory=False)
    autocast_at_step = []
    step = updater._step

    def spy(stage, value):  # autocast must be off when a stage steps, or its cached bf16 weights go stale
        autocast_at_step.append(torch.is_autocast_enabled("cpu"))
        step(stage, value)

    updater._step = spy
    torch.manual_seed(11)
    metrics = updater.update(td)
    torch.manual_seed(11)
    expected = reference.update(td)
    assert autocast_at_step == [False] * 5  # dynamics, reward, value, actor, alpha
    for key in ("loss_dynamics", "loss_reward", "loss_value", "loss_actor", "grad_penalty", "q_target_mean"):
        assert metrics[key].dtype == torch.float32, key
        assert not torch.equal(metrics[key], expected[key]), f"{key}: bf16 mode left the computation in fp32"
        assert (metrics[key] - expected[key]).abs() <= 0.05 * expected[key].abs() + 1e-3, key
    # master weights, their gradients and the Polyak targets stay fp32; gradients point the same way
    for name in ("encoder", "dynamics", "reward", "value", "policy"):
        module, module32 = getattr(m, name), getattr(m32, name)
        assert all(p.dtype == torch.float32 for p in module.parameters()), name
        g, g32 = _flat_grads(module), _flat_grads(module32)
        assert g.dtype == torch.float32
        assert F.cosine_similarity(g, g32, dim=0) > 0.95, name
    assert all(t.dtype == torch.float32 for t in loss.value_loss.target_qvalue_network_params.values(True, True))
