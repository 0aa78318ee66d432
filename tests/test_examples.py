"""Each example runs end to end for a handful of steps with tiny settings."""
import importlib.util
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]
TINY = ["train.total_episodes=2", "train.warmup_episodes=1", "train.utd=0.02", "train.eval_every=2",
        "train.eval_episodes=1", "train.batch_size=4", "train.progress=false", "model.latent_dim=16",
        "model.hidden_dims=32,32", "model.coder_dim=32", "model.vector_coder_hidden=32", "model.cnn_channels=4",
        "planner.num_candidates=16", "planner.num_elites=4", "planner.iterations=1"]


def run_example(script, tmp_path, *args, timeout=600):
    run_dir = tmp_path / "run"
    cmd = [sys.executable, str(ROOT / "examples" / script), *args, *TINY, f"train.run_dir={run_dir}"]
    proc = subprocess.run(cmd, cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(ROOT)}, capture_output=True,
                          text=True, timeout=timeout)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["episodes"] == 2 and summary["updates"] > 0
    assert (run_dir / "checkpoints" / "last" / "state.pt").exists() and (run_dir / "curves.png").exists()
    return summary


def test_point_mass_example(tmp_path):
    assert run_example("point_mass.py", tmp_path)["env_steps"] == 2 * 50


def test_gym_example_with_user_demonstrations(tmp_path):
    """Hopper with demonstrations built from a user's own recordings (here: short random rollouts)."""
    from torchrl_mpail2.data import demos_from_arrays, save_demos
    from torchrl_mpail2.envs import make_env

    env = make_env("gym/Hopper-v5", seed=0)
    episodes = []
    for _ in range(2):
        traj = env.rollout(20, break_when_any_done=True)
        obs = torch.cat([traj["observation"], traj["next", "observation"][-1:]])
        episodes.append({"observation": obs})
    save_demos(demos_from_arrays(episodes, env_id="gym/Hopper-v5"), tmp_path / "demos")
    summary = run_example("gym_mujoco.py", tmp_path, "--env", "gym/Hopper-v5", f"train.demos={tmp_path / 'demos'}")
    assert 2 <= summary["env_steps"] <= 2 * 1000  # Hopper episodes end on termination


@pytest.mark.parametrize("script", ["robosuite_lift.py",
                                    # the same entry point as Lift's with another preset: slow only
                                    pytest.param("robosuite_push.py", marks=pytest.mark.slow)])
def test_robosuite_examples(tmp_path, script):
    pytest.importorskip("robosuite")
    assert run_example(script, tmp_path, "train.num_demos=1")["env_steps"] == 2 * 100  # horizon 100, no termination


def test_gym_example_records_demonstrations_from_the_committed_expert_and_caches_them(tmp_path):
    first = run_example("gym_mujoco.py", tmp_path, "--env", "gym/Hopper-v5", "train.num_demos=1")
    cached = list((tmp_path / "demos").iterdir())
    assert len(cached) == 1 and "Hopper" in cached[0].name
    header = json.loads((cached[0] / "header.json").read_text())
    assert header["env_id"] == "gym/Hopper-v5" and len(header["episodes"]) == 1
    assert header["episodes"][0]["task_return"] > 500  # the SAC expert, not random actions (5-54)
    assert first["env_steps"] >= 2


def _example(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "examples" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _minimal_loop():
    return _example("minimal_loop")


def test_minimal_loop_runs_with_tiny_settings():
    """The README's TorchRL loop: a few episodes and updates, then a deterministic evaluation (about 5 s)."""
    out = _minimal_loop().main(episodes=3, num_demos=2, batch_size=8, updates_per_episode=3, num_candidates=32,
                               eval_episodes=1)
    actions = out["actions"]
    assert actions.shape == (50, 2) and bool(torch.isfinite(actions).all()) and bool((actions.abs() <= 1).all())
    assert actions.std() > 0  # the planner acts, it does not return a constant
    losses = {k: v for k, v in out["metrics"].items() if k.startswith("loss_")}
    assert sorted(losses) == ["loss_actor", "loss_alpha", "loss_dynamics", "loss_reward", "loss_value"]
    assert all(math.isfinite(v) for v in losses.values()) and out["metrics"]["nonfinite_skips"] == 0
    assert 0.0 <= out["success_rate"] <= 1.0


def test_readme_shows_the_minimal_loop_as_it_is():
    readme = (ROOT / "README.md").read_text()
    section = readme[readme.index("## Use the pieces in your own TorchRL code"):]
    start = section.index("```python\n") + len("```python\n")
    shown = section[start:section.index("\n```", start)]
    example = (ROOT / "examples" / "minimal_loop.py").read_text()
    assert shown == example[example.index("import torch"):example.index("\n\n\nif __name__")]


@pytest.mark.slow
def test_minimal_loop_learns_the_point_mass():
    """The loop at its defaults: >= 80% deterministic evaluation success on 10 episodes (a few minutes)."""
    assert _minimal_loop().main()["success_rate"] >= 0.8


def _algorithm1():
    return _example("algorithm1")


#: Loss settings the spelled-out update must follow as the updater does: the point-mass preset's, Lift's (standard
#: TD(lambda), one transition per window, the raw critic with penalty 10) and the other switches of the losses.
ALGORITHM1_SETTINGS = {
    "point_mass": {"loss.transitions_per_window": 2, "loss.encoder_lr": 3e-5},  # the paper: the encoder 10x slower
    "lift_losses": {"loss.return_form": "td_lambda", "loss.transitions_per_window": 1,
                    "loss.reward_scale_momentum": None, "loss.gp_coef": 10.0},
    "other_switches": {"loss.value_head_reduce": "mean", "loss.actor_q_reduce": "min", "loss.return_form": "authors",
                       "loss.mask_terminal": True, "loss.value_grad_clip": 0.5, "loss.rho": 0.9},
}


@pytest.mark.parametrize("setting", sorted(ALGORITHM1_SETTINGS))
def test_algorithm1_spelled_out_updates_every_weight_exactly_like_the_updater(setting):
    """The readable example's four losses and five optimisers equal MPAIL2Updater's update, weight for weight,
    whatever the loss settings."""
    import copy

    from tensordict import TensorDict

    from torchrl_mpail2 import MPAIL2Loss, MPAIL2Updater, make_mpail2_modules
    from torchrl_mpail2.config import apply_overrides, preset
    from torchrl_mpail2.envs import make_env

    cfg = apply_overrides(preset("point_mass"), ALGORITHM1_SETTINGS[setting])
    env = make_env("point_mass")
    torch.manual_seed(0)
    modules = make_mpail2_modules(env.observation_spec, env.action_spec, cfg.model)
    twin = copy.deepcopy(modules)
    losses = _algorithm1().Losses(modules, cfg.loss)
    updater = MPAIL2Updater(MPAIL2Loss(twin, cfg.loss), retain_memory=False)
    B, H = 6, cfg.model.horizon
    o = lambda: torch.randn(B, H, 4)  # noqa: E731
    batches = [TensorDict({"observation": o(), "action": torch.rand(B, H, 2) * 2 - 1, ("next", "observation"): o(),
                           ("next", "terminated"): torch.zeros(B, H, 1, dtype=torch.bool),
                           ("expert", "observation"): o(), ("expert", "next", "observation"): o()}, [B, H])
               for _ in range(3)]
    for batch in batches:  # three updates: Adam's moments and the Polyak targets must agree too
        torch.manual_seed(1)
        mine = losses.update(batch.clone())
        torch.manual_seed(1)
        theirs = updater.update(batch.clone())
    for key, value in twin.state_dict().items():
        torch.testing.assert_close(modules.state_dict()[key], value, rtol=1e-5, atol=1e-6, msg=key)
    target = updater.loss.value_loss.target_qvalue_network_params
    torch.testing.assert_close(losses.loss.value_loss.target_qvalue_network_params, target, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(losses.loss.actor_loss.log_alpha, updater.loss.actor_loss.log_alpha)
    assert mine["loss_value"] == pytest.approx(float(theirs["loss_value"]), rel=1e-5)


def test_algorithm1_runs_end_to_end_with_tiny_settings():
    history = _algorithm1().main("point_mass", episodes=3, num_demos=2, eval_every=3, eval_episodes=2,
                                 updates_per_episode=2,
                                 overrides={"planner.num_candidates": 32, "planner.num_elites": 4})
    assert [row["episode"] for row in history] == [3]
    assert history[0]["episodes"] == 2 and 0.0 <= history[0]["success_rate_any_step"] <= 1.0
    assert all(math.isfinite(history[0][k]) for k in ("loss_dynamics", "loss_reward", "loss_value", "loss_actor"))
