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
        "train.progress": False, "train.logger": "none", "train.warmup_episodes": 3, "train.utd": 0.02,
        "train.eval_episodes": 1, "train.num_demos": 2, "train.demos": str(tmp_path / "demos"),
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
