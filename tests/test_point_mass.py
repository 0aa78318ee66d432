import sys

import pytest
import torch
from torchrl.envs.utils import check_env_specs

from torchrl_mpail2.envs import PointMassEnv, make_env
from torchrl_mpail2.envs.point_mass import SUCCESS_RADIUS
from torchrl_mpail2.experts import PointMassExpert, get_expert

NUM_EPISODES = 200
HORIZON = 50


@pytest.mark.parametrize("batch_size", [[], [4], [2, 3]])
def test_specs(batch_size):
    env = PointMassEnv(batch_size=batch_size, seed=0)
    check_env_specs(env)
    assert env.action_spec.shape == (*batch_size, 2)
    assert torch.equal(env.action_spec.space.low, -torch.ones(*batch_size, 2))
    assert env.reward_keys == ["task_reward"]
    assert env.observation_spec["observation"].dtype == torch.float32


@pytest.mark.parametrize("num_envs", [None, 4])
def test_factory_specs_and_keys(num_envs):
    env = make_env("point_mass", seed=0, num_envs=num_envs)
    check_env_specs(env)
    rollout = env.rollout(3)
    for key in ("observation", "success", "step_count", "is_init", "episode_task_return"):
        assert key in rollout.keys()
    assert ("next", "task_reward") in rollout.keys(True)
    assert "reward" not in rollout["next"].keys()
    assert rollout["next", "success"].shape == (*env.batch_size, 3, 1)


def _last_step_success_rate(policy):
    env = PointMassEnv(batch_size=[NUM_EPISODES], seed=123)
    rollout = env.rollout(HORIZON + 10, policy=policy)  # the truncation must stop it at HORIZON
    assert rollout.shape == (NUM_EPISODES, HORIZON)
    return rollout["next", "success"][:, -1].float().mean().item()


def test_expert_succeeds():
    assert _last_step_success_rate(PointMassExpert()) >= 0.95


def test_random_policy_fails():
    assert _last_step_success_rate(None) < 0.2


def test_success_matches_distance():
    env = PointMassEnv(batch_size=[16], seed=1)
    rollout = env.rollout(HORIZON, policy=PointMassExpert())
    distance = rollout["next", "observation"][..., :2].norm(dim=-1, keepdim=True)
    assert torch.equal(rollout["next", "success"], distance < SUCCESS_RADIUS)
    assert torch.allclose(rollout["next", "task_reward"], -distance)
    # Starts on the 0.8-1.0 ring, at rest.
    start_radius = rollout["observation"][:, 0, :2].norm(dim=-1)
    assert ((start_radius >= 0.8 - 1e-6) & (start_radius <= 1.0 + 1e-6)).all()
    assert (rollout["observation"][:, 0, 2:] == 0).all()


def test_truncation_never_termination():
    env = make_env("point_mass", seed=0)
    rollout = env.rollout(200, break_when_any_done=False)
    truncated = rollout["next", "truncated"].squeeze(-1)
    assert not rollout["next", "terminated"].any()
    # Truncated exactly every 50 steps, and the step counter restarts after the auto-reset.
    assert truncated.nonzero().squeeze(-1).tolist() == [49, 99, 149, 199]
    assert rollout["next", "step_count"][49].item() == 50
    assert rollout["step_count"][50].item() == 0


def test_dynamics():
    env = PointMassEnv(seed=0)
    td = env.reset()
    position = td["observation"][:2].clone()
    td["action"] = torch.tensor([1.0, -1.0])
    next_td = env.step(td)["next"]
    expected_velocity = 0.5 * torch.tensor([1.0, -1.0])
    assert torch.allclose(next_td["observation"][2:], expected_velocity)
    assert torch.allclose(next_td["observation"][:2], position + 0.1 * expected_velocity)


def test_partial_reset():
    env = PointMassEnv(batch_size=[3], seed=0)
    td = env.reset()
    td["action"] = torch.ones(3, 2)
    stepped = env.step(td)["next"]
    reset_mask = torch.tensor([[True], [False], [False]])
    after = env.reset(stepped.clone().set("_reset", reset_mask))
    assert torch.equal(after["observation"][1:], stepped["observation"][1:])
    assert not torch.equal(after["observation"][0], stepped["observation"][0])
    assert (after["observation"][0, 2:] == 0).all()


def test_seeded_resets_are_reproducible():
    first = [make_env("point_mass", seed=7).reset()["observation"] for _ in range(2)]
    other = make_env("point_mass", seed=8).reset()["observation"]
    assert torch.equal(first[0], first[1])
    assert not torch.equal(first[0], other)
    env = PointMassEnv(batch_size=[5], seed=0)
    a = env.reset()["observation"]
    env.set_seed(0)
    assert torch.equal(env.reset()["observation"], a)


def test_get_expert(tmp_path, monkeypatch):
    import torchrl_mpail2.experts.gym as gym_experts

    env = make_env("point_mass")
    assert isinstance(get_expert("point_mass", env), PointMassExpert)
    monkeypatch.setattr(gym_experts, "ASSET_DIR", tmp_path)  # no weights there
    with pytest.raises(FileNotFoundError, match="python -m torchrl_mpail2.experts.ppo --env Hopper-v5"):
        get_expert("gym/Hopper-v5", env)


def test_factory_rejects_bad_arguments():
    with pytest.raises(ValueError, match="gym/Humanoid-v5"):
        make_env("point_mas")
    with pytest.raises(ValueError, match="'gym/Hopper-v5' has no observation mode 'pixels'; its modes: state."):
        make_env("gym/Hopper-v5", obs="pixels")


def test_factory_routes_robosuite_names(monkeypatch):
    # robosuite_env.py is written elsewhere; a stand-in module checks the wiring only.
    import types

    calls = []

    def fake_make_robosuite_env(task, obs="state", seed=0, horizon=None, device="cpu"):
        calls.append((task, obs, seed))
        return PointMassEnv(seed=seed, device=device)

    fake_module = types.ModuleType("torchrl_mpail2.envs.robosuite_env")
    fake_module.make_robosuite_env = fake_make_robosuite_env
    monkeypatch.setitem(sys.modules, "torchrl_mpail2.envs.robosuite_env", fake_module)
    env = make_env("robosuite/PushMirrored", obs="pixels", seed=3)
    assert calls == [("PushMirrored", "pixels", 3)]
    assert "episode_task_return" in env.observation_spec.keys()
    batched = make_env("robosuite/Lift", seed=0, num_envs=2)
    assert batched.batch_size == (2,)
    assert {call[0] for call in calls[1:]} == {"Lift"}  # SerialEnv also builds one probe env
