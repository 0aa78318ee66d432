"""Ray collection: a worker's copy of the actor acts with its own copy of the networks, receives the learner's
weights and warm-up switch, keeps its trajectories apart from the other workers', and the trainer collects
through it (``train.collector=ray``)."""
from __future__ import annotations

import functools
import json
import pickle
import sys

import pytest
import torch
from tensordict import TensorDict
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.data.replay_buffers import SliceSampler
from torchrl.envs.utils import ExplorationType, set_exploration_type

from conftest import QUIET_RUN
from torchrl_mpail2.agents import MPAIL2Agent
from torchrl_mpail2.config import ConfigError, ModelConfig, PlannerConfig
from torchrl_mpail2.data import TRAJ_KEY
from torchrl_mpail2.envs import make_env
from torchrl_mpail2.trainers import MPAIL2Trainer, apply_overrides, preset
from torchrl_mpail2.trainers.collection import split_episodes
from torchrl_mpail2.trainers.ray_collection import (NetworkOwningActor, RayEpisodeCollector, make_ray_collector,
                                                    worker_unique_traj_ids)

TINY_MODEL = ModelConfig(latent_dim=8, hidden_dims=(16,), coder_dim=16, vector_coder_hidden=16, horizon=3)
TINY_PLANNER = PlannerConfig(num_candidates=16, num_elites=4, iterations=2)


#: Ray workers unpickle the env builder: it must live in an importable module, not in this test file.
point_mass = functools.partial(make_env, "point_mass")
#: Hopper falls after a seed-dependent number of random steps: episodes of different lengths.
hopper = functools.partial(make_env, "gym/Hopper-v5")


def _agent(env_fn=point_mass):
    env = env_fn()
    return MPAIL2Agent(env.observation_spec, env.action_spec, TINY_MODEL, planner=TINY_PLANNER), env


def _act(actor, td, seed=0):
    actor.actor.generator = torch.Generator().manual_seed(seed)
    actor.actor.reset()
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        return actor(td.clone())["action"]


def test_a_pickled_actor_plans_with_its_own_copy_of_the_networks():
    agent, env = _agent()
    owning = NetworkOwningActor(agent.policy, agent.modules)
    weights = TensorDict.from_module(owning)
    shared = {p.data_ptr() for p in weights.values(True, True)}
    assert all(p.data_ptr() in shared for p in agent.modules.parameters()), "every network parameter is sent"

    copy = pickle.loads(pickle.dumps(owning))
    assert copy.actor.components is copy.networks  # the copy's planner uses the copy's networks
    td = env.reset()
    assert torch.equal(_act(owning, td), _act(copy, td))
    with torch.no_grad():
        for p in copy.networks.parameters():
            p.mul_(3.0)
    assert not torch.equal(_act(owning, td), _act(copy, td)), "the copy acts with its own weights"
    TensorDict.from_module(owning).data.to_module(copy)  # what a worker does with received weights
    assert torch.equal(_act(owning, td), _act(copy, td))


def test_the_warmup_switch_travels_with_the_weights():
    agent, env = _agent()
    owning = NetworkOwningActor(agent.actor, agent.modules)
    copy = pickle.loads(pickle.dumps(owning))
    agent.actor.random_actions = True
    assert copy.actor.random_actions is False
    TensorDict.from_module(owning).data.to_module(copy)
    assert copy.actor.random_actions is True
    assert not copy.actor(env.reset())["plan"].any(), "random steps write no plan"
    assert "_random_actions" not in agent.actor.state_dict()  # checkpoints stay as they were


def test_worker_ids_are_relabelled_apart():
    ids = torch.tensor([[[0, 0], [1, 1]], [[0, 0], [1, 2]], [[0, -1], [0, 0]]])  # [W=3, 2, 2]
    out = worker_unique_traj_ids(TensorDict({TRAJ_KEY: ids.clone()}, [3, 2, 2]))[TRAJ_KEY]
    assert torch.equal(out, torch.tensor([[[0, 0], [3, 3]], [[1, 1], [4, 7]], [[2, -1], [2, 2]]]))
    per_worker = [set(out[w][out[w] >= 0].tolist()) for w in range(3)]
    assert all(not per_worker[a] & per_worker[b] for a in range(3) for b in range(a + 1, 3))


def _run_cfg(tmp_path, *overrides):
    from torchrl_mpail2.data import record_demos
    from torchrl_mpail2.experts import PointMassExpert

    record_demos(make_env("point_mass", seed=5), PointMassExpert(), 2, out=tmp_path / "demos", progress=False)
    return apply_overrides(preset("point_mass"), [
        *QUIET_RUN, "train.utd=0.02", "train.eval_episodes=1", "train.num_demos=2", f"train.demos={tmp_path / 'demos'}",
        "planner.num_candidates=32", "planner.num_elites=4", *overrides])


def test_ray_settings_are_checked_by_name():
    cfg = preset("point_mass")
    with pytest.raises(ConfigError, match="unknown TrainConfig.collector 'dask'"):
        apply_overrides(cfg, ["train.collector=dask"])
    with pytest.raises(ConfigError, match="TrainConfig.ray_workers"):
        apply_overrides(cfg, ["train.collector=ray", "train.ray_workers=0"])
    with pytest.raises(ConfigError, match="parallel_envs applies to collector='local'"):
        apply_overrides(cfg, ["train.collector=ray", "train.parallel_envs=true"])
    with pytest.raises(ConfigError, match="ray_address='auto' applies to collector='ray'"):
        apply_overrides(cfg, ["train.ray_address=auto"])
    with pytest.raises(ConfigError, match=r"ray_workers \* num_envs=4 \* 2 is more than total_episodes=5"):
        apply_overrides(cfg, ["train.collector=ray", "train.ray_workers=4", "train.num_envs=2",
                              "train.total_episodes=5"])
    ray_cfg = apply_overrides(cfg, ["train.collector=ray", "train.ray_workers=3", "train.num_envs=2"]).train
    assert ray_cfg.episodes_per_batch == 6 and cfg.train.episodes_per_batch == 1


def test_a_missing_ray_is_named_with_its_extra(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` now fails as if it were not installed
    cfg = _run_cfg(tmp_path, "train.collector=ray", "train.total_episodes=4")
    with pytest.raises(ImportError, match=r"train.collector='ray' needs ray: pip install 'torchrl-mpail2\[ray\]'"):
        MPAIL2Trainer(cfg, run_dir=tmp_path / "run")
    assert not (tmp_path / "run").exists()  # a failed start leaves nothing behind


# ---- with Ray running: one local Ray of 2 CPUs for the tests below ----------------------------------------------
@pytest.fixture(scope="module")
def ray_session():
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


def _remote_policy_state(collector, worker):
    import ray

    return ray.get(collector.remote_collectors[worker].state_dict.remote())["policy_state_dict"]


def test_ray_workers_keep_their_trajectories_apart_and_follow_the_learner(ray_session):
    """Two workers, 20 steps each per batch: both are inside their first episode, which each counts as 0."""
    agent, _ = _agent()
    agent.actor.random_actions = True
    collector = make_ray_collector(point_mass, agent.actor, agent.modules, frames_per_batch=40)
    owning_state = NetworkOwningActor(agent.actor, agent.modules).state_dict
    try:
        batches = iter(collector)
        batch = next(batches)
        assert batch.shape == (2, 20) and not batch["plan"].any(), "warm-up: random actions on both workers"
        ids = batch[TRAJ_KEY]
        assert not set(ids[0].tolist()) & set(ids[1].tolist()), "the two workers' episodes share an id"

        # flattened into a replay sampled by trajectory, no window spans both workers' episodes
        replay = TensorDictReplayBuffer(storage=LazyTensorStorage(100), batch_size=5 * 400,
                                        sampler=SliceSampler(slice_len=5, traj_key=TRAJ_KEY, strict_length=True))
        worker = torch.arange(2).unsqueeze(1).expand(2, 20)
        replay.extend(batch.set("worker", worker).reshape(-1))
        windows = replay.sample().reshape(400, 5)["worker"]
        assert (windows == windows[:, :1]).all(), "a sampled window spans two workers' episodes"

        # after an update the workers hold the learner's weights and warm-up switch
        with torch.no_grad():
            for p in agent.modules.parameters():
                p.add_(0.5)  # stands in for an update
        agent.actor.random_actions = False
        collector.update_policy_weights_()
        for w in range(2):
            remote, local = _remote_policy_state(collector, w), owning_state()
            assert all(torch.equal(remote[k], v) for k, v in local.items() if isinstance(v, torch.Tensor))
        assert next(batches)["plan"].abs().sum() > 0, "the workers still take random actions"
    finally:
        collector.shutdown()


def test_ray_episode_batches_hold_whole_episodes_of_different_lengths(ray_session):
    pytest.importorskip("gymnasium")
    agent, _ = _agent(hopper)
    agent.actor.random_actions = True  # Hopper falls after a few random steps
    collector = RayEpisodeCollector(hopper, agent.actor, agent.modules, first_seed=3, workers=2)
    try:
        batch = next(iter(collector))
    finally:
        collector.shutdown()
    lengths = batch[("collector", "mask")].sum(1).tolist()
    assert batch.shape == (2, max(lengths)) and lengths[0] != lengths[1], lengths
    episodes = split_episodes(batch)
    assert [e.shape[0] for e in episodes] == lengths
    for w, episode in enumerate(episodes):
        assert episode["next", "done"][-1].all() and not episode["next", "done"][:-1].any()
        assert episode[TRAJ_KEY].unique().numel() == 1
        # worker w's env is seeded first_seed + w
        assert torch.equal(episode["observation"][0], hopper(seed=3 + w).reset()["observation"])
    assert episodes[0][TRAJ_KEY][0] != episodes[1][TRAJ_KEY][0]
    # each worker draws its own random actions (its torch generator is seeded from its first env seed)
    assert not torch.equal(episodes[0]["action"][:5], episodes[1]["action"][:5])


def test_the_trainer_collects_through_ray_workers(ray_session, tmp_path):
    cfg = _run_cfg(tmp_path, "train.collector=ray", "train.ray_workers=2", "train.total_episodes=4",
                   "train.warmup_episodes=2", "train.eval_every=4")
    trainer = MPAIL2Trainer(cfg, run_dir=tmp_path / "run")
    summary = trainer.train()
    assert summary["episodes"] == 4 and summary["updates"] == 2 * round(0.02 * 100)
    data = trainer.replay[:]
    assert data[TRAJ_KEY].unique().tolist() == [0, 1, 2, 3] and len(data) == 4 * 50
    starts = data["observation"][data[TRAJ_KEY].diff(prepend=torch.tensor([-1])) != 0]
    for i in range(2):  # the first batch: worker i's env seeded seed + i
        assert torch.equal(starts[i], make_env("point_mass", seed=i).reset()["observation"])
    records = [json.loads(line) for line in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert [r["random_actions"] for r in records] == [True, True, False, False]
    assert all("policy_influence" in r for r in records[2:])  # the workers planned
    assert "collect" in summary["time_split_s"] and summary["last_eval"]["episode"] == 4


@pytest.mark.slow
def test_mpail2_learns_the_point_mass_through_ray_workers(ray_session, tmp_path):
    """The criterion of ``test_training.py``'s single-env run (>= 80% deterministic evaluation success on 10
    episodes after 35 episodes), here after 36 episodes in 18 batches from 2 Ray workers."""
    cfg = apply_overrides(preset("point_mass"), [*QUIET_RUN, "train.collector=ray", "train.ray_workers=2",
                                                 "train.total_episodes=36", "train.eval_every=36",
                                                 "train.eval_episodes=10"])
    summary = MPAIL2Trainer(cfg, run_dir=tmp_path / "run").train()
    assert summary["episodes"] == 36 and summary["last_eval"]["success_rate"] >= 0.8, summary
