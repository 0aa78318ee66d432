"""MPAIL2's learned reward as a TorchRL transform, for envs and replay buffers, and SAC trained on it."""
import pytest
import torch
from tensordict import TensorDict
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.envs import TransformedEnv
from torchrl.envs.utils import check_env_specs

from conftest import QUIET_RUN
from torchrl_mpail2.agents import LearnedRewardTransform
from torchrl_mpail2.config import ModelConfig
from torchrl_mpail2.envs import make_env
from torchrl_mpail2.modules import make_mpail2_modules
from torchrl_mpail2.trainers import MPAIL2Trainer, apply_overrides, preset

TINY = ModelConfig(latent_dim=8, hidden_dims=(16,), coder_dim=16, vector_coder_hidden=16, horizon=3)


def _modules(seed=0):
    torch.manual_seed(seed)
    env = make_env("point_mass")
    m = make_mpail2_modules(env.observation_spec, env.action_spec, TINY)
    m.reward.module.reward_scale.fill_(2.5)  # a non-trivial running scale must be applied too
    return m


def _by_hand(m, td_now, td_next):
    with torch.no_grad():
        z, z_next = m.encoder.net(td_now["observation"]), m.encoder.net(td_next["observation"])
        return m.reward.module.critic(z, z_next) / 2.5


def test_in_an_env_each_step_is_scored_from_its_observations_and_the_next():
    m = _modules()
    env = TransformedEnv(make_env("point_mass", seed=3), LearnedRewardTransform(m.encoder, m.reward))
    check_env_specs(env)
    assert set(env.reward_keys) == {"learned_reward", "task_reward"}
    env.set_seed(7)  # check_env_specs played episodes of its own
    traj = env.rollout(12)
    expected = _by_hand(m, traj, traj["next"])
    torch.testing.assert_close(traj["next", "learned_reward"], expected)
    # the env's own reward is what the same actions earn without the transform
    actions = iter(traj["action"])
    plain_env = make_env("point_mass")
    plain_env.set_seed(7)
    plain = plain_env.rollout(12, policy=lambda td: td.set("action", next(actions)))
    torch.testing.assert_close(traj["next", "task_reward"], plain["next", "task_reward"])


def test_on_a_replay_buffer_sampled_transitions_are_scored():
    m = _modules()
    traj = make_env("point_mass", seed=4).rollout(20)
    rb = TensorDictReplayBuffer(storage=LazyTensorStorage(50), batch_size=8)
    rb.append_transform(LearnedRewardTransform(m.encoder, m.reward, out_key="reward"))
    rb.extend(traj)
    batch = rb.sample()
    torch.testing.assert_close(batch["next", "reward"], _by_hand(m, batch, batch["next"]))
    # called directly on any batch shape of transitions
    td = traj.reshape(4, 5).clone()
    out = LearnedRewardTransform(m.encoder, m.reward)(td)
    assert out["next", "learned_reward"].shape == (4, 5, 1)


def test_bad_inputs_name_what_is_missing():
    m = _modules()
    transform = LearnedRewardTransform(m.encoder, m.reward)
    with pytest.raises(KeyError, match="'next'"):
        transform(TensorDict({"observation": torch.zeros(3, 4)}, [3]))
    with pytest.raises(KeyError, match="next observation: missing key 'observation'"):
        transform(TensorDict({"observation": torch.zeros(3, 4), "next": {"state": torch.zeros(3, 4)}}, [3]))
    with pytest.raises(ValueError, match="'observation': expected shape"):
        transform(TensorDict({"observation": torch.zeros(3, 5), "next": {"observation": torch.zeros(3, 5)}}, [3]))
    with pytest.raises(TypeError, match="ObservationEncoder and a TransitionReward"):
        LearnedRewardTransform(m.reward, m.encoder)


def test_the_reward_networks_are_frozen_for_downstream_losses():
    m = _modules()
    transform = LearnedRewardTransform(m.encoder, m.reward)
    assert not any(p.requires_grad for p in transform.parameters())
    traj = make_env("point_mass").rollout(5)
    traj["action"].requires_grad_(True)
    assert not transform(traj)["next", "learned_reward"].requires_grad


def test_from_checkpoint_scores_with_the_runs_trained_reward(tmp_path):
    cfg = apply_overrides(preset("point_mass"), [*QUIET_RUN, "train.num_demos=3", "train.total_episodes=3",
                                                  "train.warmup_episodes=1", "train.utd=0.05",
                                                  "train.eval_every=0", "planner.num_candidates=32",
                                                  "planner.num_elites=4"])
    trainer = MPAIL2Trainer(cfg, run_dir=tmp_path / "run")
    trainer.train()
    transform = LearnedRewardTransform.from_checkpoint(tmp_path / "run" / "checkpoints" / "last")
    traj = make_env("point_mass", seed=1).rollout(10)
    m = trainer.agent.modules
    with torch.no_grad():
        expected = m.reward.module(m.encoder.encode(traj), m.encoder.encode(traj, ("next",)))
    torch.testing.assert_close(transform(traj)["next", "learned_reward"], expected)


@pytest.mark.slow
def test_torchrl_sac_learns_the_point_mass_from_the_learned_reward_alone(tmp_path):
    """MPAIL2 on the point mass, then TorchRL's SACLoss on its learned reward only (no task reward)."""
    import importlib

    bench = importlib.import_module("benchmarks.learning.learned_reward_sac")
    checkpoint = bench.train_mpail2(tmp_path / "mpail2", episodes=40)
    result = bench.run(checkpoint, seeds=[0], frames=5000, warmup=1000, episodes=20)
    assert result["sac_success_any_step_mean"] >= 0.6, result
    assert result["random_policy_success_any_step"] <= 0.2, result
