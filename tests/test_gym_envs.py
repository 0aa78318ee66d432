import pytest
import torch
from torchrl.envs.utils import check_env_specs

pytest.importorskip("gymnasium")
pytest.importorskip("mujoco")

from torchrl_mpail2.envs import make_env, make_gym_env  # noqa: E402

GYM_NAMES = ["gym/Hopper-v5", "gym/Ant-v5", "gym/Humanoid-v5"]


@pytest.mark.parametrize("name", GYM_NAMES)
def test_specs_and_conventions(name):
    env = make_env(name, seed=0)
    check_env_specs(env)
    assert torch.all(env.action_spec.space.low == -1) and torch.all(env.action_spec.space.high == 1)
    assert env.action_spec.dtype == torch.float32
    assert env.observation_spec["observation"].dtype == torch.float32
    assert env.reward_keys == ["task_reward"]
    rollout = env.rollout(5)
    assert "reward" not in rollout["next"].keys()
    assert not rollout["next", "success"].any()  # these tasks have no success criterion
    assert torch.allclose(rollout["next", "episode_task_return"][-1], rollout["next", "task_reward"].sum(0))


def test_humanoid_actions_are_rescaled_to_native_bounds():
    env = make_gym_env("Humanoid-v5")
    assert torch.allclose(env.base_env.action_spec.space.high, torch.full((17,), 0.4))
    td = env.reset()
    td["action"] = torch.ones(17)
    # The inverse transforms map the policy's [-1, 1] action onto what gymnasium receives.
    native = env.transform.inv(td.clone())["action"]
    assert torch.allclose(native, torch.full((17,), 0.4))


def test_hopper_terminations_are_kept():
    env = make_env("gym/Hopper-v5", seed=0)
    torch.manual_seed(0)
    rollout = env.rollout(1000, break_when_any_done=True)  # random actions make the hopper fall fast
    assert rollout.shape[0] < 1000
    assert rollout["next", "terminated"][-1].item()
    assert not rollout["next", "truncated"][-1].item()
    assert rollout["next", "done"][-1].item()


def test_seeding_is_reproducible():
    first = make_env("gym/Hopper-v5", seed=3).reset()["observation"]
    again = make_env("gym/Hopper-v5", seed=3).reset()["observation"]
    other = make_env("gym/Hopper-v5", seed=4).reset()["observation"]
    assert torch.equal(first, again) and not torch.equal(first, other)


def test_batched_gym_env():
    env = make_env("gym/Hopper-v5", seed=0, num_envs=2)
    assert env.batch_size == (2,)
    observation = env.reset()["observation"]
    assert not torch.equal(observation[0], observation[1])  # sub-envs get different seeds
