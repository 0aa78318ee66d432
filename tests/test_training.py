"""End-to-end: MPAIL2 learns the point mass from observation-only demonstrations; runs resume after a kill."""
import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type

from conftest import QUIET_RUN
from torchrl_mpail2.config import ConfigError
from torchrl_mpail2.envs import make_env
from torchrl_mpail2.trainers import ExperimentConfig, MPAIL2Trainer, apply_overrides, preset
from torchrl_mpail2.data.checkpoint import read_checkpoint

ROOT = Path(__file__).resolve().parents[1]


def _cfg(*overrides):
    return apply_overrides(preset("point_mass"), [*QUIET_RUN, *overrides])


def test_mpail2_learns_the_point_mass_and_beats_random(tmp_path):
    """About two minutes on 2 CPU cores: >= 80% deterministic evaluation success after 35 episodes."""
    trainer = MPAIL2Trainer(_cfg("train.total_episodes=35", "train.eval_every=35", "train.eval_episodes=10",
                                 "train.figures=true"),
                            run_dir=tmp_path / "run")
    summary = trainer.train()
    assert summary["last_eval"]["success_rate"] >= 0.8, summary
    # a uniform random policy on the same evaluation environment stays far below
    env = make_env("point_mass", seed=123)
    successes = []
    with set_exploration_type(ExplorationType.RANDOM):
        for _ in range(20):
            traj = env.rollout(100, break_when_any_done=True)
            successes.append(float(traj["next", "success"][-1]))
    assert sum(successes) / len(successes) < 0.2
    # the run folder holds what a user looks at
    for name in ("metrics.jsonl", "eval.jsonl", "curves.png", "learner.png", "summary.json", "config.json"):
        assert (tmp_path / "run" / name).exists(), name
    records = [json.loads(line) for line in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert [r["episode"] for r in records] == list(range(1, 36))
    assert any("policy_influence" in r for r in records)
    # an episode that ends in success succeeded at some step; the paper's any-step rate is logged beside it
    assert all(r["success"] <= r["success_any_step"] for r in records)
    planned = [r for r in records if not r["random_actions"]]
    assert planned and all(r["actions_per_s"] > 0 and "elite_return" in r and "plan_std" in r for r in planned)
    assert all("actions_per_s" not in r for r in records if r["random_actions"])
    assert all(r["normalized_return"] == pytest.approx(r["task_return"] / trainer.demos.mean_return) for r in records)
    assert summary["last_eval"]["success_rate"] <= summary["last_eval"]["success_rate_any_step"]


def test_policy_only_ablation_runs(tmp_path):
    trainer = MPAIL2Trainer(_cfg("train.ablation=P", "train.total_episodes=3", "train.warmup_episodes=1",
                                 "train.eval_every=3", "train.eval_episodes=1", "train.utd=0.1"), run_dir=tmp_path / "r")
    summary = trainer.train()
    assert summary["episodes"] == 3 and summary["updates"] > 0
    records = [json.loads(line) for line in (tmp_path / "r" / "metrics.jsonl").read_text().splitlines()]
    assert all("policy_influence" not in r and "elite_return" not in r for r in records)  # no planner
    assert not (tmp_path / "r" / "curves.png").exists()  # train.figures=false
    assert all(r["actions_per_s"] > 0 for r in records if not r["random_actions"])


def test_latest_episode_ablation_trains_on_the_last_episode(tmp_path):
    trainer = MPAIL2Trainer(_cfg("train.ablation=O", "train.total_episodes=3", "train.warmup_episodes=1",
                                 "train.eval_every=0", "train.utd=0.1"), run_dir=tmp_path / "r")
    trainer.train()
    assert len(trainer.latest) == 50 and len(trainer.replay) == 150


@pytest.mark.parametrize("ablation", ["PM", "PMO"])
def test_model_free_ablations_run(tmp_path, ablation):
    trainer = MPAIL2Trainer(_cfg(f"train.ablation={ablation}", "train.total_episodes=3", "train.warmup_episodes=1",
                                 "train.eval_every=3", "train.eval_episodes=1", "train.utd=0.1"), run_dir=tmp_path / "r")
    before = {k: v.clone() for k, v in trainer.agent.modules.encoder.state_dict().items()}
    summary = trainer.train()
    assert summary["episodes"] == 3 and summary["updates"] > 0 and trainer.agent.planner is None
    assert trainer.agent.modules.policy.net.horizon == 1
    # DAC's encoder learns through the value loss
    assert any(not torch.equal(v, trainer.agent.modules.encoder.state_dict()[k]) for k, v in before.items())
    assert (trainer.latest is not None) == (ablation == "PMO")


def test_a_run_shorter_than_eval_every_ends_without_an_evaluation(tmp_path):
    """A smoke run follows its own ``eval_every`` (issue 48): two episodes with evaluations every three play none
    (they played ``eval_episodes`` at the end before), and still draw their figures; a run that reaches
    ``eval_every`` evaluates there and where it ends."""
    small = ["train.num_demos=2", "train.warmup_episodes=1", "train.utd=0.05", "train.eval_episodes=2",
             "planner.num_candidates=32", "planner.num_elites=4"]
    summary = MPAIL2Trainer(_cfg(*small, "train.total_episodes=2", "train.eval_every=3", "train.figures=true"),
                            run_dir=tmp_path / "short").train()
    assert summary["last_eval"] is None and "evaluate" not in summary["time_split_s"]
    assert not (tmp_path / "short" / "eval.jsonl").exists() and (tmp_path / "short" / "curves.png").exists()
    MPAIL2Trainer(_cfg(*small, "train.total_episodes=3", "train.eval_every=2", "train.eval_episodes=1"),
                  run_dir=tmp_path / "long").train()
    evaluations = [json.loads(line) for line in (tmp_path / "long" / "eval.jsonl").read_text().splitlines()]
    assert [(e["episode"], e["episodes"]) for e in evaluations] == [(2, 1), (3, 1)]


def test_bad_configs_fail_before_training():
    with pytest.raises(ConfigError, match="num_elites"):
        _cfg("planner.num_elites=1000")
    with pytest.raises(ConfigError, match="unknown field train.episodes"):
        _cfg("train.episodes=3")
    with pytest.raises(ConfigError, match="unknown ablation"):
        _cfg("train.ablation=XYZ")
    with pytest.raises(ConfigError, match="unknown update_precision"):
        _cfg("train.update_precision=fp16")
    with pytest.raises(ConfigError, match="model-based updater only"):
        _cfg("train.ablation=PM", "train.update_precision=bf16")


def test_the_policy_horizon_is_derived_saved_and_checked():
    from torchrl_mpail2.agents import MPAIL2Agent
    from torchrl_mpail2.config import resolve_for_run

    cfg = preset("point_mass")
    assert cfg.model.policy_horizon is None
    assert resolve_for_run(cfg, "run").model.policy_horizon == cfg.model.horizon
    model_free = resolve_for_run(apply_overrides(cfg, ["train.ablation=PM"]), "run")
    assert (model_free.model.horizon, model_free.model.policy_horizon) == (cfg.model.horizon, 1)  # windows keep H
    saved = ExperimentConfig.from_dict(json.loads(model_free.to_json()))
    assert saved.model.policy_horizon == 1
    with pytest.raises(ValueError, match="model.policy_horizon=1 contradicts model.horizon=5"):
        resolve_for_run(apply_overrides(cfg, ["model.policy_horizon=1"]), "run")
    env = make_env("point_mass")
    agent = MPAIL2Agent(env.observation_spec, env.action_spec, saved.model, saved.loss, saved.planner, ablation="PM")
    assert agent.modules.policy.net.horizon == 1
    with pytest.raises(ValueError, match="model.policy_horizon=3 contradicts"):
        MPAIL2Agent(env.observation_spec, env.action_spec, dataclasses.replace(saved.model, policy_horizon=3),
                    ablation="PM")


@pytest.mark.parametrize("native", [False, True])
def test_auto_update_precision_is_resolved_for_the_machine_and_saved(native, monkeypatch):
    from torchrl_mpail2.config import ablations
    from torchrl_mpail2.config import resolve_for_run

    monkeypatch.setattr(ablations, "runs_bf16_natively", lambda device="cpu": native)
    cfg = preset("lift_state")
    assert cfg.train.update_precision == "auto"
    assert resolve_for_run(cfg, "run").train.update_precision == ("bf16" if native else "float32")
    model_free = apply_overrides(preset("lift_state"), ["train.ablation=PM"])
    assert resolve_for_run(model_free, "run").train.update_precision == "float32"  # no bf16 updater there
    explicit = apply_overrides(preset("lift_state"), ["train.update_precision=bf16"])
    assert resolve_for_run(explicit, "run").train.update_precision == "bf16"  # asked for: kept
    for camera in ("push_pixels", "lift_pixels", "push_video_only"):  # images stay float32: bf16 rounds the cube away
        assert preset(camera).train.update_precision == "auto"
        assert resolve_for_run(preset(camera), "run").train.update_precision == "float32"
    assert ablations.resolve_update_precision("auto", images=True) == "float32"
    assert ablations.resolve_update_precision("auto") == ("bf16" if native else "float32")
    if native:
        assert ablations.resolve_update_precision("bf16") == "bf16"
    else:  # the agent's builder warns
        with pytest.warns(RuntimeWarning, match="no native bfloat16"):
            assert ablations.resolve_update_precision("bf16") == "bf16"


def test_an_agent_that_sees_images_resolves_auto_to_float32(monkeypatch):
    from torchrl_mpail2.agents import MPAIL2Agent
    from torchrl_mpail2.config import ModelConfig, ablations

    monkeypatch.setattr(ablations, "runs_bf16_natively", lambda device="cpu": True)
    small = ModelConfig(latent_dim=8, hidden_dims=(16,), coder_dim=16, vector_coder_hidden=16, horizon=3)
    for obs, bf16 in (("state", True), ("pixels", False)):
        env = make_env("point_mass", obs=obs)
        agent = MPAIL2Agent(env.observation_spec, env.action_spec, small, update_precision="auto")
        assert agent.updater.bf16 is bf16, obs


def _wait_for(predicate, timeout, proc):
    deadline = time.time() + timeout
    while time.time() < deadline:
        if predicate():
            return True
        if proc.poll() is not None:
            raise AssertionError(f"training exited early: {proc.stdout.read() if proc.stdout else ''}")
        time.sleep(0.5)
    return False


def test_killed_run_resumes_with_counters_buffer_and_weights(tmp_path):
    run = tmp_path / "run"
    args = [sys.executable, "-m", "torchrl_mpail2.train", "--preset", "point_mass", "train.progress=false",
            "train.logger=csv", "train.figures=false", "train.num_demos=2", "planner.num_candidates=32",
            "planner.num_elites=4", "train.total_episodes=10", "train.warmup_episodes=1", "train.utd=0.1",
            "train.eval_every=2", "train.eval_episodes=1", "train.checkpoint_every=0", f"train.run_dir={run}"]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(args, cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    last = run / "checkpoints" / "last" / "state.pt"

    def checkpointed_past_four():
        try:
            return last.exists() and read_checkpoint(last)["counters"]["episodes"] >= 4
        except Exception:  # the file may be mid-rename
            return False

    try:
        assert _wait_for(checkpointed_past_four, 240, proc), "no checkpoint past episode 4"
        proc.send_signal(signal.SIGKILL)  # a real crash: no cleanup runs
        proc.wait(30)
    finally:
        if proc.poll() is None:
            proc.kill()
    saved = read_checkpoint(last)
    counters = saved["counters"]
    trainer = MPAIL2Trainer.resume(run)
    assert trainer.counters == counters
    assert len(trainer.replay) == counters["env_steps"] == 50 * counters["episodes"]
    for k, v in trainer.agent.modules.state_dict().items():
        assert torch.equal(v, saved["modules"][k]), k
    assert trainer.agent.loss.log_alpha.item() == saved["loss"]["actor_loss.log_alpha"].item()
    summary = trainer.train()
    assert summary["episodes"] == 10 and summary["env_steps"] == 500 and len(trainer.replay) == 500
    records = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    assert [r["episode"] for r in records] == list(range(1, 11))
    assert summary["updates"] > counters["updates"]


class _FlakyPointMass:
    """Builds point-mass envs whose 3rd episode raises inside the simulator step, once."""

    def __init__(self):
        self.raised = False

    def __call__(self, seed=0):
        from torchrl_mpail2.envs import PointMassEnv, with_bookkeeping

        factory = self

        class Flaky(PointMassEnv):
            steps = 0

            def _step(self, tensordict):
                Flaky.steps += 1
                if seed < 1_000_000 and not factory.raised and Flaky.steps == 2 * 50 + 10:  # not the demo env
                    factory.raised = True
                    raise RuntimeError("simulated simulator instability")
                return super()._step(tensordict)

        return with_bookkeeping(Flaky(seed=seed))


def test_simulator_exception_ends_the_episode_with_a_warning_and_training_goes_on(tmp_path):
    env_fn = _FlakyPointMass()
    trainer = MPAIL2Trainer(_cfg("train.total_episodes=4", "train.warmup_episodes=3", "train.utd=0.05", "train.eval_every=0"),
                            env_fn=env_fn, run_dir=tmp_path / "r")
    with pytest.warns(RuntimeWarning, match="simulated simulator instability"):
        summary = trainer.train()
    assert env_fn.raised and summary["episodes"] == 4 and trainer.counters["warnings"] == 1
    assert len(trainer.replay) == 4 * 50  # the aborted episode never reached the buffer


def test_init_from_transfers_everything_or_only_the_world_model(tmp_path):
    cfg = _cfg("train.total_episodes=2", "train.warmup_episodes=1", "train.utd=0.05", "train.eval_every=0")
    source = MPAIL2Trainer(cfg, run_dir=tmp_path / "a")
    source.train()
    ckpt = tmp_path / "a" / "checkpoints" / "last"
    for transfer, copied in (("world-model", {"encoder", "dynamics"}), ("all", {"encoder", "dynamics", "reward", "value", "policy"})):
        torch.manual_seed(123)
        target = MPAIL2Trainer(cfg, run_dir=tmp_path / transfer)
        target.init_from(ckpt, transfer)
        for part in ("encoder", "dynamics", "reward", "value", "policy"):
            same = all(torch.equal(v, source.agent.modules.state_dict()[f"{part}.{k}"])
                       for k, v in getattr(target.agent.modules, part).state_dict().items())
            assert same == (part in copied), (transfer, part)
    with pytest.raises(ValueError, match="transfer must be one of"):
        target.init_from(ckpt, "policy")


def test_resume_names_a_missing_or_broken_config_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="config.json is missing"):
        MPAIL2Trainer.resume(tmp_path)
    (tmp_path / "config.json").write_text("{not json")
    with pytest.raises(ValueError, match="config.json is not valid JSON"):
        MPAIL2Trainer.resume(tmp_path)


def test_a_step_budget_ends_the_run_and_evaluations_record_env_steps(tmp_path):
    """``train.total_env_steps`` ends the run after the episode that reaches it (the point mass's episodes are at most
    100 steps), evaluates there, and every evaluation records the env steps done; a resume may raise the budget."""
    small = ["train.num_demos=2", "train.warmup_episodes=1", "train.utd=0.05", "train.eval_episodes=1",
             "planner.num_candidates=32", "planner.num_elites=4", "train.eval_every=2"]
    run = tmp_path / "run"
    summary = MPAIL2Trainer(_cfg(*small, "train.total_episodes=50", "train.total_env_steps=150"), run_dir=run).train()
    assert 150 <= summary["env_steps"] < 250 and summary["episodes"] < 50, summary
    evaluations = [json.loads(line) for line in (run / "eval.jsonl").read_text().splitlines()]
    assert evaluations[-1]["episode"] == summary["episodes"] and evaluations[-1]["env_steps"] == summary["env_steps"]
    assert all("env_steps" in e for e in evaluations)
    resumed = MPAIL2Trainer.resume(run, ["train.total_env_steps=300"]).train()
    assert 300 <= resumed["env_steps"] < 400 and resumed["episodes"] > summary["episodes"]
    with pytest.raises(ConfigError, match="total_env_steps"):
        _cfg("train.total_env_steps=0")
