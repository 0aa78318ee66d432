"""Planner correctness on a known latent model: z' = z + a, reward peaked at a goal."""
import pytest
import torch
from tensordict import TensorDict
from torch import nn
from torchrl.data import Bounded
from torchrl.envs.utils import ExplorationType, set_exploration_type

from conftest import tiny_modules
from torchrl_mpail2 import ConfigError, LatentMPPIPlanner, LossConfig, PlannerConfig
from torchrl_mpail2.modules.reward import RewardNet

GOAL = torch.tensor([0.5, -0.3])


class Identity(nn.Module):
    def forward(self, x):
        return x


class AddDynamics(nn.Module):
    def forward(self, z, a):
        return z + a


class PeakReward(RewardNet):
    """r(z, z') = -scale * ||z' - goal||^2, written in the planner's projected form."""

    def __init__(self, scale=1.0):
        super().__init__(2, [4])
        self.scale = scale

    def project(self, z):
        return torch.zeros_like(z), z

    def from_projection(self, h_now, h_next):
        return -self.scale * (h_next - GOAL).pow(2).sum(-1, keepdim=True)


class ZeroQ(nn.Module):
    num_q = 5

    def forward(self, z, a, heads=None):
        return torch.zeros(2 if heads is not None else 5, *z.shape[:-1], 1)


class FixedPolicy(nn.Module):
    """Proposes the same plan every time and records how many plans it was asked for."""

    def __init__(self, plan):
        super().__init__()
        self.plan, self.calls, self.horizon, self.action_dim = plan, [], plan.shape[0], plan.shape[1]

    def forward(self, z, deterministic=False, generator=None):
        self.calls.append(tuple(z.shape[:-1]))
        return self.plan.expand(*z.shape[:-1], *self.plan.shape), torch.zeros(z.shape[:-1])


def known_planner(policy_plan=None, reward_scale=1.0, gamma=0.99, **cfg):
    m = tiny_modules(obs_dim=2, action_dim=2, latent_dim=2, horizon=3)
    m.encoder.net.forward = lambda obs: obs  # the latent is the observation itself
    m.dynamics.module = AddDynamics()
    m.reward.module = PeakReward(reward_scale)
    m.value.module.net = ZeroQ()
    policy = FixedPolicy(torch.zeros(3, 2) if policy_plan is None else policy_plan)
    m.policy.net = policy
    defaults = dict(num_candidates=256, num_elites=32, iterations=6, temperature=0.5)
    planner = LatentMPPIPlanner(m, Bounded(-1, 1, (2,)), PlannerConfig(**{**defaults, **cfg}), gamma=gamma,
                                generator=torch.Generator().manual_seed(0))
    return planner, policy


def obs(*rows):
    return TensorDict({"observation": torch.tensor(rows, dtype=torch.float32)}, [len(rows)])


def test_first_action_points_at_the_optimum():
    planner, _ = known_planner()
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        td = planner(obs([0.0, 0.0], [0.5, -0.3], [0.2, 0.4]))
    # one step reaches the goal; the best first action is goal - z for each environment
    expected = GOAL - torch.tensor([[0.0, 0.0], [0.5, -0.3], [0.2, 0.4]])
    assert torch.allclose(td["action"], expected, atol=0.08), td["action"]


def test_stochastic_mode_samples_around_the_mean():
    planner, _ = known_planner(std_min=0.3)
    a = torch.stack([planner(obs([0.0, 0.0]))["action"] for _ in range(20)])
    assert a.std(0).min() > 0.05  # sampled, not the mean
    assert torch.allclose(a.mean(0), GOAL.unsqueeze(0), atol=0.3)


def test_warm_start_shifts_the_previous_mean_and_resets_new_episodes():
    planner, _ = known_planner()
    prev = torch.arange(2 * 3 * 2, dtype=torch.float32).view(2, 3, 2) / 10
    planner._prev_mean = prev.clone()
    td = obs([0.0, 0.0], [0.0, 0.0])
    mean = planner._initial_mean(td, 2, torch.zeros(1))
    assert torch.equal(mean[:, :2], prev[:, 1:]) and torch.equal(mean[:, 2], torch.zeros(2, 2))
    td["is_init"] = torch.tensor([[True], [False]])
    mean = planner._initial_mean(td, 2, torch.zeros(1))
    assert torch.equal(mean[0], torch.zeros(3, 2)) and torch.equal(mean[1, :2], prev[1, 1:])
    # after a call the stored mean is the optimised plan; a different batch size starts fresh
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        out = planner(obs([0.0, 0.0], [0.0, 0.0]))
    assert torch.equal(planner._prev_mean, out["plan"])
    assert torch.equal(planner._initial_mean(obs([0.0, 0.0]), 1, torch.zeros(1)), torch.zeros(1, 3, 2))
    state = planner.state_dict()
    planner.reset()
    assert planner._prev_mean is None
    planner.load_state_dict(state)
    assert torch.equal(planner._prev_mean, out["plan"])


def test_warm_start_is_used_in_the_next_plan():
    # with a single iteration and a tiny std, the plan must stay near the shifted previous mean
    planner, _ = known_planner(iterations=1, std_max=0.05, policy_fraction=0.0)
    planner._prev_mean = torch.full((1, 3, 2), 0.7)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        plan = planner(obs([0.0, 0.0]))["plan"]
    assert torch.allclose(plan[0, :2], torch.full((2, 2), 0.7), atol=0.1)
    assert torch.allclose(plan[0, 2], torch.zeros(2), atol=0.1)


def test_policy_sample_fraction_is_respected():
    planner, policy = known_planner(num_candidates=200, policy_fraction=0.05)
    planner(obs([0.0, 0.0], [0.1, 0.1], [0.2, 0.2]))
    sampling_calls = [c for c in policy.calls if len(c) == 2]
    assert sampling_calls == [(3, 10)]  # M = 0.05 * 200 plans per environment, drawn once per call


def test_policy_that_proposes_the_optimum_raises_policy_influence():
    optimum = torch.stack([GOAL, torch.zeros(2), torch.zeros(2)])
    good, _ = known_planner(policy_plan=optimum, iterations=1, reward_scale=50.0)
    bad, _ = known_planner(policy_plan=-optimum, iterations=1, reward_scale=50.0)
    influence_good = good(obs([0.0, 0.0]))["policy_influence"].item()
    influence_bad = bad(obs([0.0, 0.0]))["policy_influence"].item()
    assert influence_good > 0.5 and influence_bad < 0.05
    assert 0.0 <= influence_bad <= influence_good <= 1.0 + 1e-6


def test_returns_of_1e4_and_more_stay_finite():
    planner, _ = known_planner(reward_scale=1e6)
    td = planner(obs([0.0, 0.0], [-1.0, 1.0]))
    assert torch.isfinite(td["action"]).all() and torch.isfinite(td["plan"]).all()
    assert td["action"].abs().max() <= 1.0


@pytest.mark.parametrize("batch", [(), (4,), (2, 3)])
def test_any_batch_shape(batch):
    m = tiny_modules()
    planner = LatentMPPIPlanner(m, Bounded(-1, 1, (2,)), PlannerConfig(num_candidates=32, num_elites=4, iterations=2),
                                gamma=LossConfig.gamma)
    td = planner(TensorDict({"observation": torch.randn(*batch, 3)}, batch))
    assert td["action"].shape == (*batch, 2) and td["plan"].shape == (*batch, 3, 2)
    assert td["policy_influence"].shape == (*batch, 1)


def test_bad_observations_and_impossible_configs_are_rejected():
    from torchrl_mpail2.config import ConfigError
    m = tiny_modules()
    planner = LatentMPPIPlanner(m, Bounded(-1, 1, (2,)), PlannerConfig(num_candidates=32, num_elites=4, iterations=2),
                                gamma=LossConfig.gamma)
    with pytest.raises(ValueError, match="'observation': expected shape \\[\\*B, 3\\]"):
        planner(TensorDict({"observation": torch.randn(2, 4)}, [2]))
    with pytest.raises(ValueError, match="NaN"):
        planner(TensorDict({"observation": torch.full((2, 3), float("inf"))}, [2]))
    with pytest.raises(ConfigError, match="num_elites"):
        PlannerConfig(num_candidates=32, num_elites=64)


def test_warmup_switch_reports_the_planners_statistics_per_episode():
    from torchrl_mpail2.planners.policy_actor import WarmupSwitch

    planner, _ = known_planner()
    actor = WarmupSwitch(planner, Bounded(-1, 1, (2,)), random_actions=True)
    actor(obs([0.0, 0.0], [0.1, 0.1], [0.2, 0.2]))
    assert actor.pop_stats() == {}  # random warm-up steps neither plan nor count
    actor.random_actions = False
    elite_returns = []
    for start in ([0.0, 0.0], [-3.0, 3.0]):
        actor(obs(start, start, start))
        elite_returns.append(planner.last_stats["elite_return"].item())
    stats = actor.pop_stats()
    assert stats["elite_return"] == pytest.approx(sum(elite_returns) / 2, rel=1e-5)
    assert elite_returns[1] < elite_returns[0] <= 0.0  # the far start cannot reach the goal's reward
    assert planner.cfg.std_min <= stats["plan_std"] <= planner.cfg.std_max
    assert stats["actions_per_s"] > 0
    assert actor.pop_stats() == {}  # reset after reading


class LinearQ(nn.Module):
    """Q(z, a) = sum(z) + 10 sum(a): tells which latent and which action closed the return."""

    num_q = 5

    def forward(self, z, a, heads=None):
        q = (z.sum(-1, keepdim=True) + 10 * a.sum(-1, keepdim=True)).unsqueeze(0)
        return q.expand(2 if heads is not None else 5, *q.shape[1:])


@pytest.mark.parametrize("terminal_value", ["policy_action", "plan_last_action"])
def test_terminal_value_forms_score_by_hand(terminal_value):
    planner, _ = known_planner(terminal_value=terminal_value, gamma=0.5)
    planner.components.value.module.net = LinearQ()
    z = torch.zeros(1, 2)
    plan = torch.tensor([[[0.1, 0.0], [0.0, 0.2], [0.3, 0.3]]])  # [B=1, H=3, A=2]; one candidate
    returns = planner.score(z, plan.unsqueeze(1), torch.tensor([0, 1]))
    latents = torch.cumsum(plan[0], 0)  # z_1, z_2, z_3 under z' = z + a
    r = -(latents - GOAL).pow(2).sum(-1)
    if terminal_value == "policy_action":  # H rewards, Q at z_H with the policy's first action (zeros here)
        expected = r[0] + 0.5 * r[1] + 0.25 * r[2] + 0.125 * latents[2].sum()
    else:  # H - 1 rewards, Q at z_{H-1} with the plan's own last action
        expected = r[0] + 0.5 * r[1] + 0.25 * (latents[1].sum() + 10 * plan[0, 2].sum())
    assert returns.shape == (1, 1)
    assert returns.item() == pytest.approx(expected.item(), rel=1e-5)
    rewards, terminal = planner.score_parts(z, plan.unsqueeze(1), torch.tensor([0, 1]))
    rewarded = r[0] + 0.5 * r[1] + (0.25 * r[2] if terminal_value == "policy_action" else 0.0)
    assert rewards.item() == pytest.approx(rewarded.item(), rel=1e-5)
    assert terminal.item() == pytest.approx((expected - rewarded).item(), rel=1e-5, abs=1e-6)
    # the same return read off the latent path itself
    path = torch.cat([z, latents]).unsqueeze(0)  # [B=1, H + 1, Z]
    on_path = planner.path_return_parts(path, plan, torch.tensor([0, 1]))
    assert [p.item() for p in on_path] == pytest.approx([rewards.item(), terminal.item()], rel=1e-5, abs=1e-6)


def test_effective_number_of_elites_is_logged_between_one_and_k():
    planner, _ = known_planner()
    planner(obs([0.0, 0.0]))
    ess = planner.last_stats["elite_ess"].item()
    assert 1.0 <= ess <= planner.cfg.num_elites


def _twin_planners(**cfg):
    modules = tiny_modules(obs_dim=3, action_dim=2, horizon=3)
    settings = dict(num_candidates=32, num_elites=8, iterations=2, **cfg)
    return [LatentMPPIPlanner(modules, Bounded(-1, 1, (2,)), PlannerConfig(**settings, compile=compiled),
                              gamma=LossConfig.gamma, generator=torch.Generator().manual_seed(0)) for compiled in (False, True)]


def test_a_compiling_planner_copies_and_pickles_before_and_without_its_graphs():
    import copy
    import pickle

    _, compiled = _twin_planners()
    assert compiled._scorer() is not compiled.score  # wrapped lazily, on first use
    for clone in (copy.deepcopy(compiled), pickle.loads(pickle.dumps(compiled))):
        assert "_compiled_score" not in clone.__dict__ and clone.cfg.compile


def test_an_unknown_compile_mode_is_refused_by_name():
    with pytest.raises(ConfigError, match="compile_mode 'fast'"):
        PlannerConfig(compile=True, compile_mode="fast")


@pytest.mark.slow
@pytest.mark.parametrize("compile_mode", ["default", "reduce-overhead"])
def test_the_compiled_planner_plans_as_the_eager_one_in_training_and_evaluation(compile_mode):
    eager, compiled = _twin_planners(compile_mode=compile_mode)
    observations = TensorDict({"observation": torch.randn(2, 3)}, [2])
    for mode in (ExplorationType.RANDOM, ExplorationType.DETERMINISTIC, ExplorationType.RANDOM):
        with set_exploration_type(mode):
            actions = [planner(observations.clone())["action"] for planner in (eager, compiled)]
        torch.testing.assert_close(actions[1], actions[0], atol=1e-5, rtol=1e-5)
    # the graphs read the weights as they are now (an optimiser step between calls), and planners built later on
    # other networks of the same sizes reuse them with their own weights
    with torch.no_grad():
        for param in compiled.components.parameters():
            param.add_(0.3 * torch.randn_like(param))
    for eager, compiled in ((eager, compiled), _twin_planners(compile_mode=compile_mode)):
        actions = [planner(observations.clone())["action"] for planner in (eager, compiled)]
        torch.testing.assert_close(actions[1], actions[0], atol=1e-5, rtol=1e-5)


def test_a_planner_whose_compilation_fails_warns_once_and_plans_eagerly(monkeypatch, caplog):
    import torchrl_mpail2.planners.mppi as mppi

    calls = []

    def failing_compile(fn, **kwargs):
        def compiled(*args):
            calls.append(1)
            raise torch._dynamo.exc.BackendCompilerFailed(fn, RuntimeError("InvalidCxxCompiler: no C++ compiler"), None)
        return compiled

    monkeypatch.setattr(mppi.torch, "compile", failing_compile)
    eager, compiled = _twin_planners()
    observations = TensorDict({"observation": torch.randn(2, 3)}, [2])
    with caplog.at_level("WARNING", logger="torchrl_mpail2.planners.mppi"):
        for _ in range(2):
            actions = [planner(observations.clone())["action"] for planner in (eager, compiled)]
            torch.testing.assert_close(actions[1], actions[0])
    assert len(calls) == 1  # tried once, then eager for good
    warnings = [r.getMessage() for r in caplog.records if "compiling the plan scoring failed" in r.getMessage()]
    assert len(warnings) == 1 and "InvalidCxxCompiler" in warnings[0]


@pytest.mark.parametrize("terminal_value", ["policy_action", "plan_last_action"])
def test_the_plan_score_is_the_losses_imagined_return_at_lambda_one(terminal_value):
    """One imagined return: Algorithm 2's plan score is the value target's and actor's return (Eq. 6's path, its
    terminal value in the same form) in the TD(lambda) form at lambda = 1, with Q the mean of the planner's heads and
    the policy's mean acting at the end."""
    from torchrl_mpail2.objectives.imagination import imagined_lambda_return

    torch.manual_seed(0)
    m = tiny_modules(obs_dim=3, action_dim=2, horizon=4)
    planner = LatentMPPIPlanner(m, Bounded(-1, 1, (2,)), PlannerConfig(terminal_value=terminal_value), gamma=0.9)
    z, plans, heads = torch.randn(2, m.cfg.latent_dim), torch.rand(2, 5, 4, 2) * 2 - 1, torch.tensor([0, 1])
    scores = planner.score(z, plans, heads)
    G = imagined_lambda_return(
        z.repeat_interleave(5, 0), plans.reshape(10, 4, 2), m.dynamics.module, m.reward.module,
        lambda zk, a: m.q(zk, a, heads).mean(0), lambda zk: m.pi(zk, deterministic=True), gamma=0.9, lmbda=1.0,
        return_form="td_lambda", terminal_value=terminal_value)
    torch.testing.assert_close(scores, G.view(2, 5), rtol=1e-5, atol=1e-5)
