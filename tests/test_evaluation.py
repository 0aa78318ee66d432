"""Evaluation that can decide between configurations: fixed initial states, seeded planner noise."""
import pytest
import torch

from conftest import QUIET_RUN
from torchrl_mpail2.config import ConfigError
from torchrl_mpail2.envs import make_env
from torchrl_mpail2.trainers import MPAIL2Trainer, apply_overrides, preset
from torchrl_mpail2.trainers.evaluation import evaluate_episodes, evaluate_episodes_lockstep, summarize_outcomes


def _trainer(tmp_path, *overrides):
    cfg = apply_overrides(preset("point_mass"), [*QUIET_RUN, "train.eval_episodes=3", "planner.num_candidates=32",
                                                 "planner.num_elites=4", *overrides])
    return MPAIL2Trainer(cfg, run_dir=tmp_path / "run")


def _first_observations(trainer):
    env = trainer.env_fn(seed=0)
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


def _steps_equal(a, b):
    return a.batch_size == b.batch_size and all(torch.equal(a.get(k), b.get(k)) for k in
                                                ("action", ("next", "observation"), ("next", "success")))


def test_lockstep_evaluation_with_one_env_is_the_sequential_one_step_for_step(tmp_path):
    trainer = _trainer(tmp_path)
    seeds, planner = trainer.evaluation_seeds(), trainer.agent.planner
    env = trainer.env_fn(seed=0)
    one, stepped = [], []
    sequential = evaluate_episodes(env, trainer.agent.policy, seeds, planner, rollouts=one)
    lockstep = evaluate_episodes_lockstep([env], trainer.agent.policy, seeds, planner, rollouts=stepped)
    assert sequential == lockstep
    assert len(one) == len(stepped) == 3 and all(_steps_equal(a, b) for a, b in zip(one, stepped))
    assert planner.generator is None


def test_lockstep_evaluation_plays_each_seeds_episode_to_its_own_end(tmp_path):
    trainer = _trainer(tmp_path)
    seeds, policy, planner = trainer.evaluation_seeds(), trainer.agent.policy, trainer.agent.planner
    # two envs whose episodes end at different steps; three seeds, so the second batch holds one episode
    envs = [make_env("point_mass", seed=0, horizon=5), make_env("point_mass", seed=0, horizon=8)]
    rollouts, again, videos = [], [], []
    outcomes = evaluate_episodes_lockstep(envs, policy, seeds, planner, rollouts=rollouts, videos=videos,
                                          video_episodes=2)
    assert evaluate_episodes_lockstep(envs, policy, seeds, planner, rollouts=again) == outcomes  # deterministic
    assert [r.shape[0] for r in rollouts] == [5, 8, 5]
    assert [v.shape[0] for v in videos] == [6, 9]  # the first two episodes filmed: the reset and every step
    assert all(bool(r["next", "done"][-1]) and not r["next", "done"][:-1].any() for r in rollouts)
    assert torch.equal(torch.stack([r["observation"][0] for r in rollouts]), _first_observations(trainer))
    assert summarize_outcomes(outcomes)["episodes"] == 3


def test_the_trainer_evaluates_eval_envs_episodes_at_once(tmp_path):
    trainer = _trainer(tmp_path, "train.eval_envs=2")
    first = trainer.evaluate()
    assert first == trainer.evaluate() and first["episodes"] == 3
    assert len(trainer.eval_env_batch) == 2
    with pytest.raises(ConfigError, match="eval_envs"):
        _trainer(tmp_path / "bad", "train.eval_envs=0")


def test_random_acting_samples_around_the_plan_from_the_seeded_generator(tmp_path):
    trainer = _trainer(tmp_path)
    seeds, planner, policy = trainer.evaluation_seeds()[:2], trainer.agent.planner, trainer.agent.policy
    env = trainer.env_fn(seed=0)
    mean, first, second = [], [], []
    evaluate_episodes(env, policy, seeds, planner, rollouts=mean)
    torch.manual_seed(3)
    evaluate_episodes(env, policy, seeds, planner, rollouts=first, acting="random")
    torch.manual_seed(4)
    evaluate_episodes(env, policy, seeds, planner, rollouts=second, acting="random")
    assert all(_steps_equal(a, b) for a, b in zip(first, second))  # the noise is the evaluation's, not global
    assert not torch.equal(mean[0]["action"][0], first[0]["action"][0])
    assert planner.generator is None
    with pytest.raises(ValueError, match="acting must be one of"):
        evaluate_episodes(env, policy, seeds, planner, acting="greedy")


def test_random_acting_without_a_planner_plays_the_same_episodes_and_leaves_the_global_stream(tmp_path):
    from torchrl_mpail2.planners.policy_actor import PolicyActor

    trainer = _trainer(tmp_path)
    actor, seeds, env = PolicyActor(trainer.agent.modules), trainer.evaluation_seeds()[:2], trainer.env_fn(seed=0)
    first, second = [], []
    torch.manual_seed(3)
    evaluate_episodes(env, actor, seeds, rollouts=first, acting="random")
    after = torch.rand(1)
    torch.manual_seed(4)
    evaluate_episodes(env, actor, seeds, rollouts=second, acting="random")
    assert all(_steps_equal(a, b) for a, b in zip(first, second))  # the policy's own sampling is seeded per episode
    torch.manual_seed(3)
    assert torch.equal(torch.rand(1), after)  # the global stream continues as if no evaluation had run


def test_the_trainer_evaluates_with_the_configured_acting(tmp_path):
    deterministic = _trainer(tmp_path / "mean").evaluate()
    sampled = _trainer(tmp_path / "sampled", "train.eval_acting=random")
    assert sampled.evaluate() == sampled.evaluate()  # still the same episodes each time
    assert sampled.evaluate()["episodes"] == deterministic["episodes"] == 3
    assert sampled.evaluate()["return"] != deterministic["return"]  # same weights (same seed), other actions
    with pytest.raises(ConfigError, match="eval_acting"):
        _trainer(tmp_path / "bad", "train.eval_acting=greedy")


def test_the_rebuilt_evaluation_env_is_built_like_the_trainers_with_its_cube():
    """Lift draws its cube size when the env is built: tools that re-evaluate a checkpoint rebuild the evaluation env
    with the run's ``eval_seed`` (as the trainer does), not with a default seed, else they play another cube."""
    pytest.importorskip("robosuite")
    from torchrl_mpail2.envs.robosuite_env import robosuite_base
    from torchrl_mpail2.trainers.evaluation import evaluation_env

    def proprio_and_cube(env):
        out = env.observation_spec["proprio"].shape, robosuite_base(env).privileged_state()["cube_half_size"].copy()
        env.close()
        return out

    train = {"env": "robosuite/Lift", "obs": "state", "env_kwargs": {"observe_gripper_command": True},
             "eval_seed": 2_000_000}
    proprio, cube = proprio_and_cube(evaluation_env(train))
    trainers_proprio, trainers_cube = proprio_and_cube(
        make_env("robosuite/Lift", obs="state", seed=2_000_000, observe_gripper_command=True))
    assert proprio == trainers_proprio and (cube == trainers_cube).all()
    default_proprio, default_cube = proprio_and_cube(make_env("robosuite/Lift", obs="state", seed=0))
    assert proprio[-1] == default_proprio[-1] + 1  # the gripper command of the run's env_kwargs
    assert not (cube == default_cube).all()  # a default-seeded env holds another cube
    _, old_run_cube = proprio_and_cube(evaluation_env({k: v for k, v in train.items() if k != "eval_seed"}))
    assert (old_run_cube == trainers_cube).all()  # a train section without eval_seed: the default


def test_a_transfer_schedule_evaluates_the_starting_weights_then_periodically_until_a_point(tmp_path):
    """The paper's transfer curves: an evaluation of the starting weights (episode 0), then every ``eval_every`` up to
    ``eval_until``, then none but the one where the run ends; a resumed run does not play episode 0 again."""
    import json

    from torchrl_mpail2.trainers.plots import EVAL_FILE, read_jsonl

    trainer = _trainer(tmp_path, "train.total_episodes=4", "train.warmup_episodes=1", "train.utd=0.05",
                       "train.eval_at_start=true", "train.eval_every=1", "train.eval_until=2", "train.eval_episodes=1")
    trainer.train()
    run = trainer.run_dir
    assert [r["episode"] for r in read_jsonl(run / EVAL_FILE)] == [0, 1, 2, 4]
    resumed = MPAIL2Trainer.resume(run, ["train.total_episodes=5"])
    resumed.train()
    assert [r["episode"] for r in read_jsonl(run / EVAL_FILE)] == [0, 1, 2, 4, 5]
    assert json.loads((run / "config.json").read_text())["train"]["eval_until"] == 2
    with pytest.raises(ConfigError, match="eval_until"):
        apply_overrides(preset("point_mass"), ["train.eval_until=0"])
