"""The replay keeps every stored episode a trajectory of its own, whatever ids its collector gave it."""
import torch

from conftest import QUIET_RUN
from torchrl_mpail2.data import TRAJ_KEY, record_demos
from torchrl_mpail2.envs import make_env
from torchrl_mpail2.experts import PointMassExpert
from torchrl_mpail2.planners.mppi import WARM_START_KEY
from torchrl_mpail2.trainers import MPAIL2Trainer, apply_overrides, preset
from torchrl_mpail2.trainers.collection import split_episodes
from torchrl_mpail2.trainers.replay import store_episodes


def test_episodes_of_restarted_collectors_stay_apart_in_the_replay(tmp_path):
    """A collector rebuilt after an env error (or at a resume) counts its episodes from 0 again: two neighbouring
    episodes stored under one id would be sampled as one trajectory, with windows across the seam."""
    record_demos(make_env("point_mass", seed=5), PointMassExpert(), 2, out=tmp_path / "demos", progress=False)
    cfg = apply_overrides(preset("point_mass"), [*QUIET_RUN, "train.num_demos=2", f"train.demos={tmp_path / 'demos'}",
                                                 "train.total_episodes=3", "train.warmup_episodes=2"])
    trainer = MPAIL2Trainer(cfg, run_dir=tmp_path / "run")
    trainer.agent.actor.random_actions = True
    for _ in range(2):  # a fresh collector each time, as after an env error
        collector = trainer._collector()
        episodes = split_episodes(next(iter(collector)), drop=(WARM_START_KEY,))
        collector.shutdown()
        assert episodes[0][TRAJ_KEY].unique().tolist() == [0]  # what the collector calls it
        store_episodes(episodes, trainer.counters["episodes"], trainer.replay)
        trainer.counters["episodes"] += 1
    for _ in range(5):  # 5 x 64 windows [B, H] sliced by trajectory id: about 13 start at the seam if it is unseen
        windows = trainer.sample_batch(trainer.replay)
        continuous = (windows["observation"][:, 1:] == windows["next", "observation"][:, :-1]).all(-1)
        assert continuous.all(), "a sampled window runs across the seam between two episodes"
    assert trainer.replay[:][TRAJ_KEY].tolist() == [0] * 50 + [1] * 50  # the run-wide episode index
