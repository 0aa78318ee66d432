import json

import pytest
import torch

from torchrl_mpail2.data.checkpoint import CheckpointError, read_checkpoint
from torchrl_mpail2.envs import make_env
from torchrl_mpail2.experts.gym import GymExpert
from torchrl_mpail2.experts.ppo import PPO_SETTINGS, PPORun, RunningMeanStd, make_batched_env, train_ppo

SMALL = {**PPO_SETTINGS, "hidden": [32, 32], "frames_per_batch": 512, "num_envs": 2, "epochs": 2, "minibatch_size": 128}


def test_running_mean_std_matches_the_statistics_of_everything_seen():
    torch.manual_seed(0)
    chunks = [torch.randn(n, 3) * torch.tensor([1.0, 5.0, 0.1]) + 2.0 for n in (7, 50, 1, 20)]
    stats = RunningMeanStd(3)
    for chunk in chunks:
        stats.update(chunk)
    seen = torch.cat(chunks).double()
    # the prior count of 1e-4 at mean 0, variance 1 shifts the figures by about 1e-6
    assert torch.allclose(stats.mean, seen.mean(0), atol=1e-5)
    assert torch.allclose(stats.var, seen.var(0, unbiased=False), rtol=1e-5, atol=1e-5)
    assert stats.count.item() == pytest.approx(78, abs=1e-3)


def test_rewards_are_scaled_by_the_spread_of_discounted_returns_that_restart_at_episode_ends():
    run = PPORun(make_batched_env("Hopper-v5", 0, 2), 10_000, settings=SMALL)
    gamma = SMALL["gamma"]
    reward = torch.tensor([[1.0, 2.0, 3.0], [0.5, 0.5, 0.5]]).unsqueeze(-1)
    done = torch.tensor([[False, True, False], [False, False, False]]).unsqueeze(-1)
    scaled = run.scale_rewards(reward, done)
    returns = torch.tensor([1.0, 1.0 * gamma + 2.0, 3.0, 0.5, 0.5 * gamma + 0.5, (0.5 * gamma + 0.5) * gamma + 0.5],
                           dtype=torch.float64)
    assert torch.allclose(run.returns_stats.mean, returns.mean().reshape(1), atol=1e-4)
    std = torch.sqrt(run.returns_stats.var + 1e-8).float()
    assert torch.allclose(scaled, reward / std)
    # the first env's episode ended at step 2 and restarted; the second's goes on into the next batch
    assert run.discounted_return.tolist() == pytest.approx([3.0, returns[-1].item()])


def test_ppo_expert_trains_saves_loads_and_resumes(tmp_path):
    out, run_dir = tmp_path / "Hopper-v5.pt", tmp_path / "run"
    kwargs = dict(settings=SMALL, eval_episodes=1, progress=False, save_every=512, run_dir=run_dir)
    first = train_ppo("Hopper-v5", 1024, out, **kwargs)
    assert first["kind"] == "ppo" and first["frames"] == 1024 and first["finished"]
    assert json.loads(out.with_suffix(".json").read_text()) == json.loads(json.dumps(first))
    saved = read_checkpoint(run_dir / "checkpoints" / "last")
    assert saved["counters"]["frames"] == 1024 and len(saved["optim"]["state"]) > 0
    # the observation statistics took in both batches' 1024 observations and travel with the policy
    assert saved["policy"]["module.0.module.stats.count"].item() == pytest.approx(1024, abs=1e-3)

    env = make_env("gym/Hopper-v5", seed=3)
    expert = GymExpert(out, env.action_spec)  # rebuilt with the run's network sizes, not the defaults
    assert expert.kind == "ppo" and expert.settings["hidden"] == [32, 32]
    td = env.reset()
    a1, a2 = expert(td.clone())["action"], expert(td.clone())["action"]
    assert torch.equal(a1, a2) and a1.shape == (3,) and a1.abs().max() <= 1
    loaded_stats = expert.actor[0].module.stats
    assert torch.equal(loaded_stats.mean, saved["policy"]["module.0.module.stats.mean"])

    second = train_ppo("Hopper-v5", 1536, out, **kwargs)
    assert second["frames"] == 1536 and second["launches"] == 2
    resumed = read_checkpoint(run_dir / "checkpoints" / "last")
    assert resumed["episode_returns"][:len(saved["episode_returns"])] == saved["episode_returns"]
    assert not torch.equal(resumed["policy"]["module.0.module.stats.mean"], saved["policy"]["module.0.module.stats.mean"])
    with pytest.raises(CheckpointError, match="minibatch_size"):
        train_ppo("Hopper-v5", 2048, out, **{**kwargs, "settings": {**SMALL, "minibatch_size": 64}})


@pytest.mark.slow
def test_ppo_expert_learns_to_hop(tmp_path):
    """40k frames (about a minute and a half on one thread): random actions score 5-54 on Hopper."""
    summary = train_ppo("Hopper-v5", 40_960, tmp_path / "Hopper-v5.pt", eval_episodes=3, progress=False,
                        save_every=0)
    assert summary["eval_mean_return"] > 200
