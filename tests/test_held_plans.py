"""The planner's returns of straight-up and straight-down plans at held Lift cubes."""
import pytest
import torch

from torchrl_mpail2.agents import MPAIL2Agent
from torchrl_mpail2.config import ModelConfig, PlannerConfig
from torchrl_mpail2.diagnostics.held_plans import (VERTICAL, constant_vertical_plans, fit_height_probe,
                                                   imagined_straight_lift, score_held_states,
                                                   simulated_plan_returns, value_by_rise)
from torchrl_mpail2.diagnostics.held_replays import straight_lift_from_held_states
from torchrl_mpail2.diagnostics.lift_phases import held_states
from torchrl_mpail2.envs import make_env
from torchrl_mpail2.experts import get_expert

pytest.importorskip("robosuite")


def test_the_plans_hold_one_vertical_command_with_the_gripper_closing():
    plans = constant_vertical_plans(3, 4)
    assert plans.shape == (len(VERTICAL), 3, 4)
    assert plans[:, :, 2].tolist() == [[v] * 3 for v in VERTICAL]
    assert (plans[:, :, :2] == 0).all() and (plans[:, :, 3] == 1).all()
    with pytest.raises(ValueError, match="action_dim is 2"):
        constant_vertical_plans(3, 2)


def test_held_states_are_scored_and_grouped_by_the_episode_outcome():
    lift = make_env("robosuite/Lift", seed=0)
    lift.set_seed(0)
    rollout = lift.rollout(100, get_expert("robosuite/Lift", lift), break_when_any_done=True)
    held = held_states(rollout)[:-1]
    assert held.sum() > 5
    model = ModelConfig(latent_dim=8, hidden_dims=(16,), coder_dim=16, vector_coder_hidden=16, horizon=3)
    agent = MPAIL2Agent(lift.observation_spec, lift.action_spec, model,
                        planner=PlannerConfig(num_candidates=16, num_elites=4, iterations=2))
    failed = rollout.clone()
    failed["next", "success"] = torch.zeros_like(failed["next", "success"])
    groups = score_held_states(agent, [rollout, failed])
    assert set(groups) == {"succeeded", "grasped_without_success"}
    for row in groups.values():
        assert row["states"] == int(held.sum())
        assert list(row["mean_return"]) == [str(v) for v in VERTICAL]
        assert 0.0 <= row["up_beats_down"] <= 1.0
        for v in VERTICAL:  # the return is its reward sum plus its terminal value
            parts = row["mean_reward_sum"][str(v)] + row["mean_terminal"][str(v)]
            assert parts == pytest.approx(row["mean_return"][str(v)], abs=2e-3)
        assert row["taken_z_mean"] > 0  # the expert carries the cube up while holding it
    assert groups["succeeded"]["mean_return"] == groups["grasped_without_success"]["mean_return"]
    idle = lift.rollout(5, lambda td: td.set("action", torch.zeros(4)))
    assert score_held_states(agent, [idle]) == {}  # no held state, no group

    # the replay reaches the recorded held states exactly, and a straight lift from the expert's grasps succeeds
    lifts = straight_lift_from_held_states(lift, [0, 0], [rollout, failed], every=15, lift_steps=15)
    assert lifts["succeeded"]["tested"] == len(range(0, int(held_states(rollout).sum()), 15))
    assert lifts["succeeded"]["replay_exact"] == 1.0 and lifts["succeeded"]["lifted"] >= 0.5, lifts
    assert lifts["grasped_without_success"] == lifts["succeeded"]  # same episode, only its label differs
    rise = lifts["succeeded"]
    assert len(rise["cube_rise_cm"]) == len(rise["hand_rise_cm"]) == 15
    assert rise["hand_rise_cm"][-1] > 5.0 and rise["cube_rise_cm"][-1] > 2.0, rise  # the held cube goes up too

    # the dynamics' forecast of the same lifts, read back by a probe of the latents, one row per tested state
    probe, stats = fit_height_probe(agent, [rollout])
    assert stats["pairs"] == len(rollout) and stats["held_out_mae_cm"] >= 0
    imagined = imagined_straight_lift(agent, probe, [rollout, failed], every=15)
    for name, row in imagined.items():
        assert row["tested"] == lifts[name]["tested"]
        assert len(row["cube_rise_cm"]) == len(row["hand_rise_cm"]) == model.horizon
    assert imagined_straight_lift(agent, probe, [idle]) == {}

    # the same plans played in the simulator and scored on their encoded observations
    simulated = simulated_plan_returns(lift, agent, [0, 0], [rollout, failed], every=15)
    for name, row in simulated.items():
        assert row["states"] == lifts[name]["tested"]
        assert list(row["mean_return"]) == ["-1.0", "0.0", "1.0"]
        parts = row["mean_reward_sum"]["1.0"] + row["mean_terminal"]["1.0"]
        assert parts == pytest.approx(row["mean_return"]["1.0"], abs=2e-3)
    assert simulated["succeeded"] == simulated["grasped_without_success"]

    # the value and reward at the held states by the cube's rise: the expert holds it at the table and carries it up
    by_rise = value_by_rise(agent, [rollout, failed])
    assert by_rise["succeeded"] == by_rise["grasped_without_success"]
    bins = by_rise["succeeded"]
    assert sum(row["states"] for row in bins.values()) == int(held.sum())
    assert "-inf..0.5 cm" in bins and "8..inf cm" in bins, list(bins)
    assert value_by_rise(agent, [idle]) == {}
    with pytest.raises(ValueError, match="2 seeds, 1 rollouts"):
        straight_lift_from_held_states(lift, [0, 0], [rollout])
    lift.close()
