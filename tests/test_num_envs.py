"""Collecting from several environments at once (train.num_envs)."""
import json

import pytest
import torch

from torchrl_mpail2.data import TRAJ_KEY, record_demos
from torchrl_mpail2.envs import make_env
from torchrl_mpail2.experts import PointMassExpert
from torchrl_mpail2.trainers import MPAIL2Trainer, apply_overrides, preset


def point_mass_run(tmp_path, **overrides):
    record_demos(make_env("point_mass", seed=5), PointMassExpert(), 2, out=tmp_path / "demos", progress=False)
    cfg = apply_overrides(preset("point_mass"), {
        "train.progress": False, "train.logger": "none", "train.figures": False, "train.warmup_episodes": 3,
        "train.utd": 0.02, "train.eval_episodes": 1, "train.num_demos": 2, "train.demos": str(tmp_path / "demos"),
        "planner.num_candidates": 32, "planner.num_elites": 4, **overrides})
    return MPAIL2Trainer(cfg, run_dir=tmp_path / "run")


def test_batches_of_episodes_keep_the_update_ratio_and_the_schedules(tmp_path):
    trainer = point_mass_run(tmp_path, **{"train.num_envs": 3, "train.total_episodes": 7, "train.eval_every": 4,
                                          "train.checkpoint_every": 4})
    summary = trainer.train()
    assert summary["episodes"] == 9  # three batches of three: the last steps past total_episodes
    ids = trainer.replay[:][TRAJ_KEY]
    assert len(ids.unique()) == 9 and len(ids) == 9 * 50  # nine whole, distinct episodes in the replay
    # updates after each batch from the end of the warm-up on (as after each episode with one env): 3 x 150 steps
    assert summary["updates"] == 3 * round(0.02 * 150)
    records = [json.loads(line) for line in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert [r["episode"] for r in records] == list(range(1, 10))
    evals = [json.loads(line)["episode"] for line in (tmp_path / "run" / "eval.jsonl").read_text().splitlines()]
    assert evals == [6, 9]  # due at 4 (stepped over by 6) and 8 (by 9); the end coincides with 9
    assert sorted(p.name for p in (tmp_path / "run" / "checkpoints").glob("episode_*")) == ["episode_000006",
                                                                                         "episode_000009"]


@pytest.mark.parametrize("parallel", [False, True])
def test_the_envs_are_seeded_apart_and_parallel_workers_collect_the_same(tmp_path, parallel):
    trainer = point_mass_run(tmp_path, **{"train.num_envs": 2, "train.total_episodes": 4, "train.eval_every": 0,
                                          "train.parallel_envs": parallel})
    trainer.train()
    data = trainer.replay[:]
    starts = data["observation"][data[TRAJ_KEY].diff(prepend=torch.tensor([-1])) != 0]
    assert starts.shape[0] == 4 and len({tuple(s.tolist()) for s in starts}) == 4
    # env i of the first batch is seeded seed + i: its first observation is that of a lone env seeded so
    for i in range(2):
        assert torch.equal(starts[i], make_env("point_mass", seed=i).reset()["observation"])


def _agent_and_env():
    from torchrl_mpail2.agents import MPAIL2Agent
    from torchrl_mpail2.config import ModelConfig, PlannerConfig

    env = make_env("point_mass", seed=0)
    torch.manual_seed(0)
    agent = MPAIL2Agent(env.observation_spec, env.action_spec,
                        ModelConfig(latent_dim=16, hidden_dims=(32,), coder_dim=32, vector_coder_hidden=32, horizon=4),
                        planner=PlannerConfig(num_candidates=32, num_elites=4, iterations=2))
    return agent, env


def _rollout(agent, env, steps, seed):
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    agent.planner.generator = torch.Generator().manual_seed(seed)
    agent.planner.reset()
    env.set_seed(seed)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        return env.rollout(steps, agent.planner, break_when_any_done=False)


def test_the_warm_start_carried_in_the_tensordict_plans_exactly_as_the_planners_own():
    agent, env = _agent_and_env()
    plain = _rollout(agent, env, 30, seed=3)
    carried = _rollout(agent, env.append_transform(agent.planner.make_tensordict_primer()), 30, seed=3)
    assert torch.equal(plain["action"], carried["action"])
    assert torch.equal(carried["planner_mean"][:-1, 1:], carried["next", "planner_mean"][:-1, 1:])
    assert "planner_mean" not in __import__("torchrl_mpail2.envs.keys", fromlist=["x"]).observation_keys_of(env)


def test_interleaved_callers_keep_each_envs_own_warm_start():
    """As an asynchronous collector would: two environments stepped in turn through one planner."""
    from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

    agent, _ = _agent_and_env()
    envs = [make_env("point_mass", seed=0).append_transform(agent.planner.make_tensordict_primer()) for _ in range(2)]
    alone = [_rollout(agent, env, 10, seed=s)["action"] for env, s in zip(envs, (3, 4))]
    tds = []
    for env, s in zip(envs, (3, 4)):
        env.set_seed(s)
        tds.append(env.reset())
    generators = [torch.Generator().manual_seed(s) for s in (3, 4)]
    actions = [[], []]
    agent.planner.reset()
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        for _ in range(10):
            for i, env in enumerate(envs):
                agent.planner.generator = generators[i]
                td = agent.planner(tds[i])
                actions[i].append(td["action"])
                tds[i] = step_mdp(env.step(td))
    for i in range(2):
        assert torch.equal(torch.stack(actions[i]), alone[i])
