"""Lift failure phases read from an episode's observations."""
import pytest
import torch

from conftest import QUIET_RUN
from torchrl_mpail2.config import ConfigError
from torchrl_mpail2.diagnostics.lift_phases import (grasped_without_success, lift_phases, main, summarize_phases,
                                                    use_planner_settings)
from torchrl_mpail2.envs import make_env
from torchrl_mpail2.experts import get_expert
from torchrl_mpail2.trainers import MPAIL2Trainer, apply_overrides, preset

pytest.importorskip("robosuite")


@pytest.fixture(scope="module")
def lift():
    return make_env("robosuite/Lift", seed=0)


def test_the_scripted_expert_passes_every_phase_and_standing_still_none(lift):
    expert = get_expert("robosuite/Lift", lift)
    lift.set_seed(0)
    done = lift_phases(lift.rollout(100, expert, break_when_any_done=True))
    assert done["reach"] and done["grasp"] and done["lift"] and done["success"], done
    assert done["closest_cm"] < 2 and done["highest_rise_cm"] > 4 and done["first_closing_step"] > 0
    assert done["first_grasp_step"] >= done["first_closing_step"] and done["grasped_steps"] > 0
    assert done["hand_rise_after_grasp_cm"] > 4  # the hand carried the cube up
    assert done["held_action"][3] > 0 and done["held_action"][2] > 0  # closing and rising while holding

    def still(td):
        return td.set("action", torch.zeros(4))

    lift.set_seed(0)
    idle = lift_phases(lift.rollout(20, still))
    assert not any(idle[p] for p in ("reach", "grasp", "lift", "success")), idle
    assert idle["first_closing_step"] is None and idle["first_grasp_step"] is None
    assert idle["hand_rise_after_grasp_cm"] is None and idle["grasped_steps"] == 0 and idle["held_action"] is None
    # the cube dropped at reset settles about 1 cm lower: heights count from where it rests, not from the drop
    assert -0.3 < idle["highest_rise_cm"] < 0.3, idle
    assert summarize_phases([done, idle]) == {"reach": 0.5, "grasp": 0.5, "lift": 0.5, "success": 0.5}
    slipped = dict(done, success=False)
    assert grasped_without_success([done, idle, slipped]) == [
        {k: done[k] for k in ("highest_rise_cm", "hand_rise_after_grasp_cm", "grasped_steps", "held_action")}]


def test_a_rollout_without_state_keys_and_a_missing_checkpoint_are_named(lift, tmp_path):
    lift.set_seed(0)
    rollout = lift.rollout(2, lambda td: td.set("action", torch.zeros(4)))
    assert lift_phases(rollout)["grasp"] is False  # shorter than the cube takes to settle: still read
    with pytest.raises(ValueError, match="'object'"):
        lift_phases(rollout.exclude(("next", "object")))
    with pytest.raises(Exception, match="nothere"):
        main([str(tmp_path / "nothere")])
    with pytest.raises(ConfigError, match="train.seed"):  # refused before any checkpoint is read
        main([str(tmp_path / "nothere"), "--planner", "train.seed=1"])


def test_a_checkpoint_can_be_played_with_other_planner_settings(tmp_path):
    cfg = apply_overrides(preset("point_mass"), QUIET_RUN)
    agent = MPAIL2Trainer(cfg, run_dir=tmp_path / "run").agent
    agent.run_config = cfg.to_dict()
    use_planner_settings(agent, ["planner.num_candidates=64", "planner.iterations=2"])
    assert (agent.planner.cfg.num_candidates, agent.planner.cfg.iterations) == (64, 2)
    assert agent.planner.cfg.num_elites == cfg.planner.num_elites  # the rest as the run had it
    with pytest.raises(ConfigError, match="planner.nope"):
        use_planner_settings(agent, ["planner.nope=1"])
    with pytest.raises(ConfigError, match="num_elites"):
        use_planner_settings(agent, ["planner.num_elites=1000"])


def test_a_camera_run_reads_its_phases_from_the_simulator_as_a_state_run_does(lift):
    from torchrl_mpail2.envs.robosuite_env import SimulatorObject

    pixels = make_env("robosuite/Lift", obs="pixels", seed=0).append_transform(SimulatorObject())
    rollouts = []
    for env in (lift, pixels):
        env.set_seed(0)
        rollouts.append(env.rollout(60, get_expert("robosuite/Lift", env), break_when_any_done=True))
    state, camera = rollouts
    assert "wrist_image" in camera["next"].keys() and "object" in pixels.observation_spec.keys()
    assert torch.allclose(camera["next", "object"], state["next", "object"], atol=1e-5)
    phases = lift_phases(camera)
    assert phases == lift_phases(state) and phases["success"] and phases["grasped_steps"] > 0
    pixels.close()


def test_simulator_object_on_push_adds_the_distance_to_the_line():
    from torchrl_mpail2.envs.robosuite_env import SimulatorObject

    state, pixels = (make_env("robosuite/Push", obs=obs, seed=3) for obs in ("state", "external_pixels"))
    pixels = pixels.append_transform(SimulatorObject())
    assert pixels.observation_spec["object"].shape == state.observation_spec["object"].shape == (11,)
    for env in (state, pixels):
        env.set_seed(3)
    assert torch.allclose(pixels.reset()["object"], state.reset()["object"], atol=1e-5)
    with pytest.raises(ValueError, match="robosuite env"):
        make_env("point_mass", seed=0).append_transform(SimulatorObject()).reset()
    pixels.close()
