"""Pictures of planning: recorded elites, the side probe, and the drawn episodes."""
import json

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchrl_mpail2.agents import MPAIL2Agent
from torchrl_mpail2.config import ModelConfig, PlannerConfig
from torchrl_mpail2.diagnostics import draw_plan_pictures, fit_latent_probe
from torchrl_mpail2.diagnostics.plan_pictures import plane_position
from torchrl_mpail2.envs import make_env

MODEL = ModelConfig(latent_dim=16, hidden_dims=(32,), coder_dim=32, vector_coder_hidden=32, horizon=4)
PLANNER = PlannerConfig(num_candidates=32, num_elites=6, iterations=2)


def point_mass_agent(**kwargs):
    env = make_env("point_mass", seed=0)
    torch.manual_seed(0)
    return env, MPAIL2Agent(env.observation_spec, env.action_spec, MODEL, planner=PLANNER, **kwargs)


def test_recorded_elites_are_the_ones_the_chosen_plan_averages():
    env, agent = point_mass_agent()
    planner = agent.planner
    td = TensorDict({"observation": torch.randn(3, 4)}, [3])
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        assert "elite_plans" not in planner(td.clone()).keys()  # off by default
        planner.reset()
        planner.record_elites = True
        out = planner(td.clone())
    elites, weights = out["elite_plans"], out["elite_weights"]
    assert elites.shape == (3, 6, 4, 2) and weights.shape == (3, 6)
    torch.testing.assert_close(weights.sum(-1), torch.ones(3))
    torch.testing.assert_close((weights[..., None, None] * elites).sum(1), out["plan"])  # the MPPI mean


def test_the_probe_recovers_a_linear_readout_and_refuses_bad_shapes():
    z = torch.randn(400, 6)
    probe, stats = fit_latent_probe(z, z[:, :2] @ torch.tensor([[1.0, 0.5], [-2.0, 1.0]]) + 3.0, steps=400)
    assert stats["held_out_r2"] > 0.95 and stats["held_out_mae"] < 0.3
    assert not any(p.requires_grad for p in probe.parameters())  # nothing trains it afterwards
    with pytest.raises(ValueError, match="same N"):
        fit_latent_probe(z, z[:10, :2])


def test_pictures_are_drawn_per_episode_with_the_probe_quality(tmp_path):
    env, agent = point_mass_agent()
    key, cols = plane_position("point_mass")
    summary = draw_plan_pictures(agent, env, [100, 101], tmp_path, position_key=key, position_columns=cols, panels=3,
                                 probe_steps=200)
    assert summary["files"] == ["plans_episode_00.png", "plans_episode_01.png"]
    assert all((tmp_path / f).stat().st_size > 10_000 for f in summary["files"])
    assert json.loads((tmp_path / "plan_pictures.json").read_text()) == summary
    assert 0.0 <= summary["probe_held_out_mae"] and summary["probe_held_out_r2"] <= 1.0
    assert not agent.planner.record_elites  # switched off again


def test_without_a_planner_or_a_known_plane_there_is_nothing_to_draw(tmp_path):
    env, agent = point_mass_agent(ablation="P")
    with pytest.raises(ValueError, match="does not act with the latent planner"):
        draw_plan_pictures(agent, env, [0], tmp_path, position_key="observation", position_columns=(0, 1))
    with pytest.raises(ValueError, match="no plane position is known for 'gym/Hopper-v5'"):
        plane_position("gym/Hopper-v5")
    assert plane_position("robosuite/Push") == ("proprio", (0, 1))
    assert plane_position("robosuite/Lift", "xz") == ("proprio", (0, 2))
    with pytest.raises(ValueError, match="plane 'xz' is not known for 'point_mass'"):
        plane_position("point_mass", "xz")


def test_the_command_line_draws_a_checkpoint_of_a_run(tmp_path):
    from torchrl_mpail2.data import record_demos
    from torchrl_mpail2.diagnostics.plan_pictures import main
    from torchrl_mpail2.experts import PointMassExpert
    from torchrl_mpail2.trainers import MPAIL2Trainer, apply_overrides, preset

    record_demos(make_env("point_mass", seed=5), PointMassExpert(), 2, out=tmp_path / "demos", progress=False)
    cfg = apply_overrides(preset("point_mass"), {
        "train.progress": False, "train.logger": "none", "train.figures": False, "train.total_episodes": 2,
        "train.warmup_episodes": 1, "train.utd": 0.05, "train.eval_every": 2, "train.eval_episodes": 1,
        "train.checkpoint_every": 2,
        "train.num_demos": 2, "train.demos": str(tmp_path / "demos"), "planner.num_candidates": 32,
        "planner.num_elites": 4})
    MPAIL2Trainer(cfg, run_dir=tmp_path / "run").train()
    summary = main([str(tmp_path / "run" / "checkpoints" / "episode_000002"), "--episodes", "1", "--panels", "2"])
    assert (tmp_path / "run" / "checkpoints" / "episode_000002" / "plan_pictures" / summary["files"][0]).is_file()
