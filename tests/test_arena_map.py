"""The point-mass arena map: reward, value and first action over a grid of positions."""
import json
from pathlib import Path

import pytest

from conftest import tiny_modules
from test_plan_pictures import point_mass_agent
from torchrl_mpail2.diagnostics import arena_map as arena

SHIPPED = str(Path(__file__).resolve().parents[1] / "shipped" / "point_mass")  # trained: 1.00 on 50 held-out episodes


def test_the_maps_cover_the_grid_and_the_shipped_agent_heads_for_the_goal(tmp_path):
    from torchrl_mpail2.agents import MPAIL2Agent

    agent = MPAIL2Agent.from_checkpoint(SHIPPED)
    result = arena.arena_map(agent, grid=9)
    assert len(result["value"]) == 9 and len(result["value"][0]) == 9 and len(result["first_action"][0][0]) == 2
    assert result["actions_towards_goal"] > 0.9 and result["value_near_goal_minus_edge"] > 0
    out = arena.main([SHIPPED, "--grid", "5", "--out", str(tmp_path / "m.json"),
                      "--plot", str(tmp_path / "m.png")])
    assert json.loads((tmp_path / "m.json").read_text())["grid"] == 5 == out["grid"]
    assert (tmp_path / "m.png").stat().st_size > 0


def test_an_agent_of_another_task_is_refused_by_its_keys():
    from types import SimpleNamespace

    with pytest.raises(ValueError, match=r"observes \{'observation': \(3,\)\}"):
        arena.arena_map(SimpleNamespace(modules=tiny_modules(obs_dim=3)))
    _, agent = point_mass_agent()  # untrained, of the right shape: maps without complaint
    assert arena.arena_map(agent, grid=3)["grid"] == 3
