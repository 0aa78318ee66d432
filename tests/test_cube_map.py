"""The Push cube map: reward and value over cube positions, the state read back where the cube was placed."""
import pytest

pytest.importorskip("robosuite")

from torchrl_mpail2.agents import MPAIL2Agent  # noqa: E402
from torchrl_mpail2.config import preset  # noqa: E402
from torchrl_mpail2.diagnostics.cube_map import cube_map  # noqa: E402
from torchrl_mpail2.envs import make_env  # noqa: E402


def test_the_cube_is_placed_on_the_grid_and_the_maps_cover_it():
    cfg = preset("point_mass")  # tiny networks; the env is Push
    env = make_env("robosuite/Push", seed=0)
    try:
        agent = MPAIL2Agent(env.observation_spec, env.action_spec, cfg.model, cfg.loss, cfg.planner)
        seen = []
        base = env.base_env
        observe = base.observe_state
        base.observe_state = lambda state: (seen.append(state), observe(state))[1]
        result = cube_map(agent, env, grid=3)
        cubes = [observe(state)["object"][:3].tolist() for state in seen]  # the cube's position in the observation
    finally:
        env.close()
    assert len(result["value"]) == 3 and len(result["reward_of_staying"][0]) == 3 and len(seen) == 9
    placed = [p for row in result["positions"] for p in row]
    assert [v for c in cubes for v in c[:2]] == pytest.approx([v for p in placed for v in p], abs=1e-6)
    assert (result["line_y"], result["push_sign"]) == (pytest.approx(-0.06), -1.0)  # Push: cross y = -0.06 going -y
    ys = [row[0][1] for row in result["positions"]]
    assert ys[0] > -0.06 > ys[-1] and result["reward_past_line_minus_spawn"] is not None  # the grid spans the line


def test_a_lift_env_is_refused():
    cfg = preset("point_mass")
    env = make_env("robosuite/Lift", seed=0)
    try:
        agent = MPAIL2Agent(env.observation_spec, env.action_spec, cfg.model, cfg.loss, cfg.planner)
        with pytest.raises(ValueError, match="reads Push tasks"):
            cube_map(agent, env, grid=2)
    finally:
        env.close()
