"""The agent object: built from switches, loaded from a checkpoint on its own, handed to the trainer."""
import importlib
import json
import math
import shutil

import pytest
import torch

from conftest import QUIET_RUN
from torchrl_mpail2.agents import ABLATIONS, AgentSwitches, MPAIL2Agent, switches_for
from torchrl_mpail2.config import ModelConfig, PlannerConfig
from torchrl_mpail2.data import record_demos
from torchrl_mpail2.data.checkpoint import CheckpointError
from torchrl_mpail2.envs import make_env
from torchrl_mpail2.experts import PointMassExpert
from torchrl_mpail2.trainers import MPAIL2Trainer, apply_overrides, preset
from torchrl_mpail2.trainers.evaluation import evaluate_episodes, evaluation_seeds, summarize_outcomes

TINY_MODEL = ModelConfig(latent_dim=8, hidden_dims=(16,), coder_dim=16, vector_coder_hidden=16, horizon=3)
TINY_PLANNER = PlannerConfig(num_candidates=16, num_elites=4, iterations=2)


def _cfg(*overrides):
    return apply_overrides(preset("point_mass"), [*QUIET_RUN, "train.eval_episodes=3", "planner.num_candidates=32",
                                                  "planner.num_elites=4", *overrides])


@pytest.fixture(scope="module")
def trained_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("agent")
    cfg = _cfg("train.total_episodes=3", "train.warmup_episodes=1", "train.utd=0.05", "train.eval_every=3",
               "train.checkpoint_every=3", f"train.demos={root / 'demos'}")
    record_demos(make_env("point_mass", seed=5), PointMassExpert(), 3, out=root / "demos", progress=False)
    trainer = MPAIL2Trainer(cfg, run_dir=root / "run")
    trainer.train()
    return trainer, root / "run"


def test_ablation_names_are_presets_of_the_switches():
    assert switches_for("none") == AgentSwitches(description=ABLATIONS["none"].description)
    assert switches_for("P").act_with == "policy" and switches_for("P").world_model
    assert switches_for("O").latest_episode_only and switches_for("O").act_with == "planner"
    assert not switches_for("PM").world_model and not switches_for("PM").latest_episode_only
    assert not switches_for("PMO").world_model and switches_for("PMO").latest_episode_only
    with pytest.raises(ValueError, match="unknown ablation 'Q'"):
        switches_for("Q")
    with pytest.raises(ValueError, match="world_model=False"):
        AgentSwitches(act_with="planner", world_model=False)
    with pytest.raises(ValueError, match="policy_data"):
        AgentSwitches(policy_data="latest")


@pytest.mark.parametrize("ablation", sorted(ABLATIONS))
def test_the_agent_builds_what_its_switches_say(ablation):
    env = make_env("point_mass")
    agent = MPAIL2Agent(env.observation_spec, env.action_spec, TINY_MODEL, planner=TINY_PLANNER, ablation=ablation)
    s = agent.switches
    assert (agent.planner is not None) == s.world_model
    assert (agent.policy is agent.planner) == (s.act_with == "planner")
    assert agent.modules.policy.net.horizon == (TINY_MODEL.horizon if s.world_model else 1)
    td = agent.actor(env.reset())
    assert td["action"].shape == env.action_spec.shape


def test_bad_agent_settings_are_refused_by_name():
    env = make_env("point_mass")
    with pytest.raises(ValueError, match="update_precision 'fp8'"):
        MPAIL2Agent(env.observation_spec, env.action_spec, TINY_MODEL, update_precision="fp8")
    with pytest.raises(ValueError, match="model-based updater only"):
        MPAIL2Agent(env.observation_spec, env.action_spec, TINY_MODEL, ablation="PM", update_precision="bf16")


@pytest.mark.parametrize("native", [False, True])
def test_a_bf16_planner_on_a_device_without_native_bf16_warns_by_setting_name(native, monkeypatch):
    import warnings

    from torchrl_mpail2.config import ablations

    monkeypatch.setattr(ablations, "runs_bf16_natively", lambda device="cpu": native)
    env = make_env("point_mass")
    bf16_planner = PlannerConfig(num_candidates=16, num_elites=4, iterations=2, bf16=True)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        MPAIL2Agent(env.observation_spec, env.action_spec, TINY_MODEL, planner=bf16_planner)
    emulated = [w for w in caught if "no native bfloat16" in str(w.message)]
    assert len(emulated) == (0 if native else 1)
    if emulated:
        assert issubclass(emulated[0].category, RuntimeWarning) and "planner.bf16=True" in str(emulated[0].message)
    assert not [w for w in caught if "image observations" in str(w.message)]
    pixels = make_env("point_mass", obs="pixels")
    with pytest.warns(RuntimeWarning, match="planner.bf16=True with image observations"):
        MPAIL2Agent(pixels.observation_spec, pixels.action_spec, TINY_MODEL, planner=bf16_planner)


def test_the_planner_discounts_with_the_loss_gamma():
    from torchrl_mpail2.config import LossConfig

    env = make_env("point_mass")
    agent = MPAIL2Agent(env.observation_spec, env.action_spec, TINY_MODEL, loss=LossConfig(gamma=0.9))
    assert agent.planner.gamma == agent.loss.value_loss.gamma == agent.loss.actor_loss.gamma == 0.9


def test_an_agent_loaded_from_a_checkpoint_plays_exactly_like_the_trainer(trained_run):
    trainer, run_dir = trained_run
    path = run_dir / "checkpoints" / "episode_000003"
    trainer.load(path, with_replay=False)
    expected = trainer.evaluate()
    # on its own: no trainer, no replay, no demos; the env is the run's own, built from the checkpoint's config
    agent = MPAIL2Agent.from_checkpoint(path)
    for key, value in trainer.agent.modules.state_dict().items():
        assert torch.equal(agent.modules.state_dict()[key], value), key
    env = make_env("point_mass")
    seeds = evaluation_seeds(trainer.cfg.train.eval_seed, trainer.cfg.train.eval_episodes)
    got = summarize_outcomes(evaluate_episodes(env, agent.policy, seeds, agent.planner))
    assert got == {k: v for k, v in expected.items() if k != "normalized_return"}
    # the optimisers stay fresh unless asked for
    assert not agent.updater.optimizers["dynamics"].state
    assert MPAIL2Agent.from_checkpoint(path, env, with_optimizers=True).updater.optimizers["dynamics"].state


def test_a_damaged_or_configless_checkpoint_is_refused_by_name(trained_run, tmp_path):
    _, run_dir = trained_run
    damaged = tmp_path / "damaged"
    shutil.copytree(run_dir / "checkpoints" / "best", damaged)
    with open(damaged / "state.pt", "r+b") as f:
        f.truncate(100)
    with pytest.raises(CheckpointError, match="state.pt"):
        MPAIL2Agent.from_checkpoint(damaged)
    configless = tmp_path / "configless"
    shutil.copytree(run_dir / "checkpoints" / "best", configless)
    state = torch.load(configless / "state.pt", weights_only=False)
    del state["config"]
    torch.save(state, configless / "state.pt")
    (configless / "manifest.json").unlink()  # an unverified checkpoint (warned about), but readable
    with pytest.warns(RuntimeWarning), pytest.raises(CheckpointError, match="no run config"):
        MPAIL2Agent.from_checkpoint(configless)


def test_the_trainer_trains_the_agent_it_is_given(tmp_path):
    cfg = _cfg("train.total_episodes=2", "train.warmup_episodes=1", "train.utd=0.05", "train.eval_every=0")
    env = make_env("point_mass")
    agent = MPAIL2Agent(env.observation_spec, env.action_spec, cfg.model, cfg.loss, cfg.planner)
    before = {k: v.clone() for k, v in agent.modules.state_dict().items()}
    trainer = MPAIL2Trainer(cfg, run_dir=tmp_path / "run", agent=agent)
    assert trainer.agent is agent
    summary = trainer.train()
    assert summary["updates"] > 0
    # where the wall time went, by stage (the whole-loop speed benchmark reads this)
    split = summary["time_split_s"]
    assert {"act", "env", "update", "log", "checkpoint", "total"} <= set(split), split
    assert all(v >= 0 for v in split.values()) and split["act"] > 0 and split["update"] > 0
    assert sum(v for k, v in split.items() if k != "total") <= split["total"]
    assert any(not torch.equal(v, agent.modules.state_dict()[k]) for k, v in before.items())
    saved = json.loads((tmp_path / "run" / "config.json").read_text())
    assert saved["model"]["latent_dim"] == cfg.model.latent_dim


def test_re_evaluating_checkpoints_scores_the_runs_own_evaluation_episodes(trained_run, monkeypatch):
    """``benchmarks/learning/evaluate_checkpoints.py`` loads agents alone and replays the fixed evaluation set."""
    trainer, run_dir = trained_run
    bench = importlib.import_module("benchmarks.learning.evaluate_checkpoints")
    result = bench.evaluate_run(run_dir, reuse_run_evals=False)  # as many episodes as the run's own
    logged = [json.loads(line) for line in (run_dir / "eval.jsonl").read_text().splitlines()]
    assert [row["episode"] for row in result["checkpoints"]] == [3]
    row = result["checkpoints"][0]
    assert row["source"] == "re-evaluated" and row["episodes"] == trainer.cfg.train.eval_episodes
    assert row["success_any_step_per_episode"] == logged[-1]["success_any_step_per_episode"]
    assert row["success_rate"] == logged[-1]["success_rate"]
    with pytest.raises(SystemExit, match="no numbered checkpoints from episode 4"):
        bench.evaluate_run(run_dir, from_episode=4)
    # only the checkpoints the run evaluated itself: nothing is played again on the fixed episodes
    only = bench.evaluate_run(run_dir, only_evaluated=True)
    assert [(r["episode"], r["source"]) for r in only["checkpoints"]] == [(3, "run")] and only["only_evaluated"]
    with pytest.raises(SystemExit, match="no checkpoint from episode 0 that the run evaluated itself on 7 episodes"):
        bench.evaluate_run(run_dir, episodes=7, only_evaluated=True)


def test_the_actor_versus_planner_diagnostic_scores_a_runs_checkpoint(trained_run, tmp_path):
    """``python -m torchrl_mpail2.diagnostics actor_vs_planner`` on a run's numbered checkpoint: both plans scored,
    the policy re-trained under each objective, the result written where ``--out`` says."""
    from torchrl_mpail2.data.checkpoint import numbered_checkpoints
    from torchrl_mpail2.diagnostics import actor_vs_planner
    from torchrl_mpail2.diagnostics.__main__ import COMMANDS

    _, run_dir = trained_run
    assert [(episode, path.name) for episode, path in numbered_checkpoints(run_dir)] == [(3, "episode_000003")]
    assert COMMANDS["actor_vs_planner"] is actor_vs_planner.main
    out = tmp_path / "avp.json"
    actor_vs_planner.main([str(run_dir), "--checkpoint", "episode_000003", "--steps", "2", "--rollouts", "1",
                           "--out", str(out)])
    result = json.loads(out.read_text())
    assert result["start_states"] > 0 and result["checkpoint"] == "episode_000003"
    assert set(result["retrained"]) == set(actor_vs_planner.OBJECTIVES)
    for curve in (r["curve"] for r in result["retrained"].values()):
        assert len(curve) == 3 and all(math.isfinite(c) for c in curve)  # before, then after each of the 2 steps
    with pytest.raises(SystemExit, match="no checkpoint"):
        actor_vs_planner.main([str(run_dir), "--checkpoint", "episode_000099"])


def test_checkpoint_evaluation_reads_the_runs_own_resumes_from_its_file_and_scores_the_best_held_out(
        trained_run, monkeypatch, tmp_path):
    trainer, run_dir = trained_run
    bench = importlib.import_module("benchmarks.learning.evaluate_checkpoints")
    out = tmp_path / "checkpoint_evals.json"
    result = bench.evaluate_run(run_dir, held_out=2, out=out)
    logged = json.loads((run_dir / "eval.jsonl").read_text().splitlines()[-1])
    row = result["checkpoints"][0]
    assert row["source"] == "run" and row["success_any_step_per_episode"] == logged["success_any_step_per_episode"]
    held = result["held_out"]
    assert held["checkpoint"] == result["best_checkpoint"] == "episode_000003" and held["episodes"] == 2
    assert held["first_seed"] == trainer.cfg.train.eval_seed + bench.HELD_OUT_SEED_OFFSET
    assert result["held_out_last"] == held  # one checkpoint: the best is the last
    # the run evaluated deterministically: its rows do not stand for another way of acting
    assert bench.evaluate_run(run_dir, acting="random")["checkpoints"][0]["source"] == "re-evaluated"
    assert json.loads(out.read_text()) == result
    # a row already in the file is kept, not played again; one for other episodes is not reused
    marked = {**result, "checkpoints": [{**row, "success_rate_any_step": 0.125}]}
    out.write_text(json.dumps(marked))
    assert bench.evaluate_run(run_dir, out=out)["checkpoints"][0]["success_rate_any_step"] == 0.125
    out.write_text(json.dumps({**marked, "episodes_per_checkpoint": 7}))
    assert bench.evaluate_run(run_dir, out=out)["checkpoints"][0]["success_rate_any_step"] == row["success_rate_any_step"]
    # a held-out score in the file is kept too, unless asked for on another number of episodes
    held_marked = {**held, "success_rate_any_step": 0.375}
    out.write_text(json.dumps({**result, "held_out": held_marked, "held_out_last": held_marked}))
    assert bench.evaluate_run(run_dir, held_out=2, out=out)["held_out"] == held_marked
    longer = bench.evaluate_run(run_dir, held_out=3, out=out)["held_out"]
    assert longer["episodes"] == 3 and longer["first_seed"] == held["first_seed"]
    # a call without --held-out keeps every score played so far and reports the longest for the Best
    again = bench.evaluate_run(run_dir, out=out)
    assert again["held_out"] == longer and again["held_out_last"] == longer
    assert [h["episodes"] for h in json.loads(out.read_text())["held_out_scores"]] == [2, 3]


def test_train_device_is_checked_and_the_device_smoke_script_runs_on_the_cpu(monkeypatch, tmp_path):
    """``benchmarks/speed/device_smoke.py`` is the GPU check; its CPU path keeps it from rotting between GPU sessions."""
    from torchrl_mpail2.config import ConfigError
    from torchrl_mpail2.trainers import MPAIL2Trainer

    with pytest.raises(ConfigError, match="TrainConfig.device: 'gpu0' is not a torch device"):
        apply_overrides(preset("point_mass"), ["train.device=gpu0"])
    if not torch.cuda.is_available():
        gpu_run = apply_overrides(preset("point_mass"), ["train.device=cuda"])  # a GPU run's config reads here
        with pytest.raises(ConfigError, match="sees no CUDA device"):
            MPAIL2Trainer(gpu_run, run_dir=tmp_path / "run")  # but trains only where there is one
        assert not (tmp_path / "run").exists()
    smoke = importlib.import_module("benchmarks.speed.device_smoke")
    cpu = torch.device("cpu")
    same = smoke.agreement(cpu, "state", PlannerConfig(num_candidates=32, num_elites=4, iterations=2), batch=8)
    assert same["first_action_distance"] == 0.0 and same["losses_cpu"] == same["losses_device"]
    trained = smoke.train_two_episodes(cpu, utd=0.1)
    assert trained["episodes"] == 2 and trained["updates"] == 10  # 0.1 x the learning episode's 100 steps
