"""Evaluation that can decide between configurations: fixed initial states, seeded planner noise."""
import torch

from conftest import QUIET_RUN
from torchrl_mpail2.trainers import MPAIL2Trainer, apply_overrides, preset


def _trainer(tmp_path, *overrides):
    cfg = apply_overrides(preset("point_mass"), [*QUIET_RUN, "train.eval_episodes=3", "planner.num_candidates=32",
                                                 "planner.num_elites=4", *overrides])
    return MPAIL2Trainer(cfg, run_dir=tmp_path / "run")


def _first_observations(trainer):
    env = trainer.eval_env
    firsts = []
    for seed in trainer.evaluation_seeds():
        env.set_seed(seed)
        firsts.append(env.reset()["observation"].clone())
    return torch.stack(firsts)


def test_evaluation_plays_the_same_episodes_whatever_the_global_rng(tmp_path):
    trainer = _trainer(tmp_path)
    torch.manual_seed(1)
    first = trainer.evaluate()
    torch.manual_seed(2)
    torch.rand(1000)  # a different global stream must not change a single planned action
    second = trainer.evaluate()
    assert first == second
    assert first["episodes"] == 3 and len(first["success_any_step_per_episode"]) == 3
    assert first["success_rate"] <= first["success_rate_any_step"]
    # the planner's own state is what it was before the evaluation
    assert trainer.agent.planner.generator is None


def test_evaluation_episodes_do_not_depend_on_the_training_seed(tmp_path):
    a = _trainer(tmp_path / "a", "train.seed=0")
    b = _trainer(tmp_path / "b", "train.seed=7")
    a.evaluate(1), b.evaluate(1)
    starts_a, starts_b = _first_observations(a), _first_observations(b)
    assert torch.equal(starts_a, starts_b)
    assert not torch.equal(starts_a[0], starts_a[1])  # and the episodes differ from each other


def test_best_checkpoint_is_chosen_by_any_step_success(tmp_path):
    trainer = _trainer(tmp_path)
    results = iter([{"success_rate_any_step": 0.5, "success_rate": 0.5},
                    {"success_rate_any_step": 0.7, "success_rate": 0.1},
                    {"success_rate_any_step": 0.7, "success_rate": 0.0}])
    trainer.evaluate = lambda: dict(next(results))
    saved = []
    trainer.save = lambda tag, with_replay=False: saved.append(tag)
    for _ in range(3):
        trainer._evaluate_and_checkpoint()
    assert saved.count("best") == 2 and trainer.best_eval == (0.7, 0.1)
