"""Tests for the robosuite TorchRL envs (Lift, Push, PushMirrored) and their scripted experts."""

from __future__ import annotations

import numpy as np
import pytest
import torch

pytest.importorskip("robosuite")

from torchrl.envs.utils import check_env_specs  # noqa: E402

from torchrl_mpail2.envs.robosuite_control import MAX_EEF_DELTA, WORKSPACE_HIGH, WORKSPACE_LOW  # noqa: E402
from torchrl_mpail2.envs.robosuite_env import RobosuiteEnv, make_robosuite_env  # noqa: E402
from torchrl_mpail2.envs.robosuite_observations import PROPRIO_DIM  # noqa: E402
from torchrl_mpail2.experts.scripted import LiftExpert, PushExpert  # noqa: E402

STATE_TASKS = ("Lift", "Push", "PushMirrored")
OBJECT_DIMS = {"Lift": 10, "Push": 11, "PushMirrored": 11}
ACTION_DIMS = {"Lift": 4, "Push": 3, "PushMirrored": 3}
IMAGE_KEYS = ("external_image", "wrist_image")


@pytest.fixture(scope="module")
def state_envs():
    """One state-mode env per task, built lazily: robosuite construction costs about a second each."""
    cache = {}

    def get(task):
        if task not in cache:
            cache[task] = make_robosuite_env(task, obs="state", seed=0)
        return cache[task]

    yield get
    for env in cache.values():
        env.close()


def _expert_for(env):
    return (LiftExpert if env.base_env.task == "Lift" else PushExpert)(env)


@pytest.mark.parametrize("task", STATE_TASKS)
def test_state_specs_and_keys(state_envs, task):
    env = state_envs(task)
    check_env_specs(env)
    assert env.action_spec.shape == (ACTION_DIMS[task],)
    assert env.reward_key == "task_reward"
    td = env.reset()
    assert td["proprio"].shape == (26,) and td["proprio"].dtype == torch.float32
    assert td["object"].shape == (OBJECT_DIMS[task],) and td["object"].dtype == torch.float32
    assert td["success"].shape == (1,) and td["success"].dtype == torch.bool
    assert not any(key in td.keys() for key in IMAGE_KEYS)
    step = env.rand_step(td)["next"]
    assert "reward" not in step.keys() and step["task_reward"].shape == (1,)
    assert step["success"].shape == (1,)
    # the env's tensordicts name its device: a TensorDictPrimer (the planner's warm start) builds its reset mask on
    # the input's device, and a device-less reset made it a CPU mask beside CUDA values on a GPU
    assert td.device == env.device and step.device == env.device


def test_pixels_step_renders_upright_images():
    env = make_robosuite_env("Lift", obs="pixels", horizon=5)
    try:
        td = env.rand_step(env.reset())
        for observation in (td, td["next"]):
            assert "object" not in observation.keys()
            assert observation["proprio"].shape == (26,)
            for key in IMAGE_KEYS:
                image = observation[key]
                assert image.shape == (3, 64, 64) and image.dtype == torch.uint8
                assert image.float().std() > 10.0, f"{key} is (nearly) constant"
        # Upright: the external camera sees the robot and wall at the top and the white table at the bottom;
        # the wrist camera sees its fingers at the bottom. Unflipped robosuite images are the other way round.
        external = td["next", "external_image"].float().mean(0)
        wrist = td["next", "wrist_image"].float().mean(0)
        assert external[:16].mean() < external[-16:].mean() - 40
        assert wrist[-16:].mean() < wrist[:16].mean() - 40
    finally:
        env.close()


@pytest.mark.slow
@pytest.mark.parametrize("task", STATE_TASKS)
@pytest.mark.parametrize("obs", ["pixels", "external_pixels"])
def test_pixel_mode_specs(task, obs):
    env = make_robosuite_env(task, obs=obs, horizon=10)
    try:
        check_env_specs(env)
        td = env.reset()
        expected = {"pixels": {"proprio", *IMAGE_KEYS}, "external_pixels": {"external_image"}}[obs]
        observed = set(env.observation_spec.keys()) - {"success", "step_count", "is_init", "episode_task_return"}
        assert observed == expected
        assert td["external_image"].shape == (3, 64, 64)
    finally:
        env.close()


@pytest.mark.parametrize("task", STATE_TASKS)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_scripted_expert_succeeds(state_envs, task, seed):
    env = state_envs(task)
    env.set_seed(seed)
    with torch.no_grad():
        rollout = env.rollout(env.base_env.horizon, _expert_for(env))
    success = rollout["next", "success"].squeeze(-1)
    assert success[-1], f"{task} expert failed on seed {seed}"
    assert not success[0], "the task must not start solved"
    assert not rollout["next", "terminated"].any(), "success must not terminate the episode"
    if task != "Lift":
        assert rollout["next", "object"][-1, -1] < 0, "success flag set but the cube is not past the line"


def _lift_profile(env, expert):
    """Steps with the cube between 0.5 and 4 cm above its resting height, and whether the episode succeeds."""
    env.set_seed(0)
    with torch.no_grad():
        rollout = env.rollout(env.base_env.horizon, expert)
    heights = rollout["next", "object"][:, 2]  # cube z
    rest = rollout["object"][0, 2]
    rising = ((heights > rest + 0.005) & (heights < rest + 0.04)).sum().item()
    return rising, bool(rollout["next", "success"][-1])


def test_slow_lift_expert_spends_longer_between_table_and_lift_height(state_envs):
    env = state_envs("Lift")
    fast_rising, fast_success = _lift_profile(env, LiftExpert(env))
    slow_rising, slow_success = _lift_profile(env, LiftExpert(env, max_lift_speed=0.005))
    assert fast_success and slow_success
    assert slow_rising >= 2 * fast_rising, (fast_rising, slow_rising)
    with pytest.raises(ValueError, match="max_lift_speed"):
        LiftExpert(env, max_lift_speed=0.2)


def _first_success_step(env, expert, seed):
    env.set_seed(seed)
    with torch.no_grad():
        success = env.rollout(env.base_env.horizon, expert, break_when_any_done=False)["next", "success"].reshape(-1)
    return int(success.float().argmax()) if success.any() else None


def test_footprint_grasp_width_lifts_a_turned_cube_at_once():
    """Seed 6 turns the cube by about 36 degrees: the fingers stop on it 1.4 times wider than its side. With the
    binary gripper the ``side`` rule then waits for a narrower grip that never comes; ``footprint`` lifts."""
    env = make_robosuite_env("Lift", obs="state", seed=0, gripper="binary")
    try:
        assert _first_success_step(env, LiftExpert(env), seed=6) is None
        first = _first_success_step(env, LiftExpert(env, grasp_width="footprint"), seed=6)
        assert first is not None and first < 40, first
        with pytest.raises(ValueError, match="grasp_width"):
            LiftExpert(env, grasp_width="diagonal")
    finally:
        env.close()


def test_expert_rejects_wrong_task(state_envs):
    with pytest.raises(ValueError, match="Lift"):
        PushExpert(state_envs("Lift"))


def test_horizon_truncates_and_never_terminates():
    horizon = 5
    env = make_robosuite_env("Push", horizon=horizon)
    try:
        rollout = env.rollout(3 * horizon)  # stops at the first done
        assert rollout.shape == (horizon,)
        truncated = rollout["next", "truncated"].squeeze(-1)
        assert truncated.tolist() == [False] * (horizon - 1) + [True]
        assert not rollout["next", "terminated"].any()
        assert torch.equal(rollout["next", "done"], rollout["next", "truncated"])
        assert rollout["next", "step_count"][-1].item() == horizon
        # Across the auto-reset, the episode counter restarts.
        rollout = env.rollout(2 * horizon + 1, break_when_any_done=False)
        assert rollout["next", "truncated"].squeeze(-1).nonzero().flatten().tolist() == [horizon - 1, 2 * horizon - 1]
        assert rollout["is_init"].squeeze(-1).nonzero().flatten().tolist() == [0, horizon, 2 * horizon]
    finally:
        env.close()


def test_seeding_reproduces_resets(state_envs):
    env = state_envs("Push")
    cube_positions = []
    for seed in (3, 3, 4):
        env.set_seed(seed)
        td = env.reset()
        cube_positions.append(td["object"][:3])
        env.rand_step(td)
    assert torch.equal(cube_positions[0], cube_positions[1])
    assert not torch.allclose(cube_positions[0], cube_positions[2])


def test_workspace_box_bounds_the_end_effector(state_envs):
    env = state_envs("Lift")
    td = env.reset()
    tolerance = 0.01  # the OSC controller overshoots its target slightly
    # Down onto the floor, then up and out to the far corner (away from the cube, which starts near x = y = 0).
    for action, axis, bound in (([0.0, 0.0, -1.0, -1.0], 2, "low"), ([1.0, -1.0, 1.0, -1.0], 0, "high")):
        for _ in range(40):
            td["action"] = torch.tensor(action)
            td = env.step(td)["next"].clone()
        eef = torch.as_tensor(env.base_env.privileged_state()["eef_pos"])
        if bound == "low":
            assert eef[axis] >= WORKSPACE_LOW[axis] - tolerance
            assert eef[axis] < WORKSPACE_LOW[axis] + 2 * MAX_EEF_DELTA, "the arm should have reached the floor"
        else:
            assert eef[axis] <= WORKSPACE_HIGH[axis] + tolerance
            assert eef[axis] > WORKSPACE_HIGH[axis] - 2 * MAX_EEF_DELTA, "the arm should have reached the wall"


def _eef_travel(env, action, steps):
    td = env.reset()
    start = env.base_env.privileged_state()["eef_pos"].copy()
    for _ in range(steps):
        td["action"] = torch.tensor(action)
        td = env.step(td)["next"].clone()
    return env.base_env.privileged_state()["eef_pos"] - start


def test_max_eef_delta_scales_the_step_and_the_experts_follow(state_envs):
    fine = make_robosuite_env("Lift", obs="state", seed=0, max_eef_delta=0.03)
    try:
        steps = 8  # sideways along +y, away from the cube and inside the box at both scales
        coarse_dy = _eef_travel(state_envs("Lift"), [0.0, 1.0, 0.0, -1.0], steps)[1]
        fine_dy = _eef_travel(fine, [0.0, 1.0, 0.0, -1.0], steps)[1]
        # The OSC controller lags its per-step targets (a full action travels about 1.3 cm per step at 5 cm), but
        # its travel is proportional to the target's distance.
        assert 0.5 < fine_dy / coarse_dy < 0.7, (fine_dy, coarse_dy)
        assert fine_dy < steps * 0.03
        fine.set_seed(0)
        with torch.no_grad():
            rollout = fine.rollout(fine.base_env.horizon, LiftExpert(fine))
        assert rollout["next", "success"][-1].item(), "the Lift expert must still succeed at 3 cm per step"
        with pytest.raises(ValueError, match="max_lift_speed"):
            LiftExpert(fine, max_lift_speed=0.04)  # faster than the env's step
    finally:
        fine.close()
    with pytest.raises(ValueError, match="max_eef_delta"):
        make_robosuite_env("Lift", obs="state", max_eef_delta=0.1)


def test_non_finite_action_raises_naming_the_task(state_envs):
    env = state_envs("Lift")
    td = env.reset()
    td["action"] = torch.full((4,), float("nan"))
    with pytest.raises(RuntimeError, match="Lift"):
        env.step(td)
    td = env.reset()  # the env is usable again after a reset
    assert torch.isfinite(env.rand_step(td)["next", "proprio"]).all()


@pytest.mark.parametrize(
    ("task", "obs", "message"),
    [("Stack", "state", "Lift, Push, PushMirrored"), ("Lift", "rgb", "state, pixels, external_pixels"),
     ("Lift", "pixels_state", "valid modes: state, pixels, external_pixels")],
)
def test_bad_names_raise_value_error(task, obs, message):
    with pytest.raises(ValueError, match=message):
        make_robosuite_env(task, obs=obs)


@pytest.mark.parametrize("mode, expected", [("integrating", [0.2, 0.4, 0.6, 0.4]), ("binary", [1.0, 1.0, 1.0, -1.0])])
def test_gripper_command_is_observed_and_binary_mode_jumps(mode, expected):
    env = make_robosuite_env("Lift", seed=0, horizon=10, gripper=mode, observe_gripper_command=True)
    assert env.observation_spec["proprio"].shape == (PROPRIO_DIM + 1,)
    td = env.reset()
    assert td["proprio"][-1].item() == 0.0  # robosuite clears the command at reset
    commands = []
    for grip in (1.0, 0.3, 0.9, -0.5):  # only the sign counts
        td = env.step(td.set("action", torch.tensor([0.0, 0.0, 0.0, grip])))["next"]
        commands.append(round(td["proprio"][-1].item(), 4))
    assert commands == expected
    with pytest.raises(ValueError, match="gripper mode 'sticky'"):
        make_robosuite_env("Lift", gripper="sticky")


def test_human_like_lift_expert_varies_per_episode_and_is_reproducible(state_envs):
    env = state_envs("Lift")

    def first_actions(expert, seed):
        env.set_seed(seed)
        expert.reset()
        return env.rollout(15, expert, break_when_any_done=True)["action"]

    a = LiftExpert(env, human_like=True, seed=3)
    first, second = first_actions(a, 5), first_actions(a, 5)
    assert not torch.allclose(first, second)  # a new style at every reset, same initial state
    b = LiftExpert(env, human_like=True, seed=3)
    assert torch.equal(first_actions(b, 5), first)  # the same seed replays the same styles
    assert first.abs().max() <= 1.0


def test_render_draws_the_scene_in_state_mode_too():
    from torchrl_mpail2.envs import make_env

    env = make_env("robosuite/Lift", seed=0)
    env.reset()
    frame = env.render(size=96)
    assert frame.shape == (96, 96, 3) and frame.dtype == np.uint8
    assert frame.std() > 10  # a scene: table, robot, cube
    # the cube (red) lies below the image centre row: the frame is upright
    red = np.argwhere((frame[..., 0] > 150) & (frame[..., 1] < 80) & (frame[..., 2] < 80))
    assert len(red) > 0 and red[:, 0].mean() > 96 / 3


def test_light_renderer_settings_and_full_renderer_keeps_robosuites():
    from torchrl_mpail2.envs.robosuite_render import HEAVY_SCENE_FLAGS

    light = RobosuiteEnv("Push", obs="external_pixels", seed=0)
    full = RobosuiteEnv("Push", obs="external_pixels", seed=0, renderer="full")
    try:
        for env, samples, side, flag in ((light, 0, 64, 0), (full, 4, 640, 1)):
            context = env.sim_env.sim._render_context_offscreen
            assert context.con.offSamples == samples and context.con.offWidth == side
            assert all(context.scn.flags[f] == flag for f in HEAVY_SCENE_FLAGS)
        # the same state through both renderers: the same scene (the cube where it is), not the same pixels
        a, b = light.reset()["external_image"].float(), full.reset()["external_image"].float()
        assert (a - b).abs().mean() < 20 and not torch.equal(a, b)
    finally:
        light.close(), full.close()
    with pytest.raises(ValueError, match="unknown renderer 'fast'; valid renderers: light, full"):
        RobosuiteEnv("Push", obs="pixels", renderer="fast")


def test_each_env_renders_into_its_own_context():
    """robosuite renders into the GL context made current last: a second env with a larger buffer (a 256-pixel
    video frame) must not change the first env's camera frames."""
    first = RobosuiteEnv("Lift", obs="pixels", seed=3)
    second = RobosuiteEnv("Lift", obs="pixels", seed=4)
    try:
        first.set_seed(3)
        before = first.reset()
        second.reset()
        assert second.render(size=256).shape == (256, 256, 3)
        first.set_seed(3)
        after = first.reset()
        for key in IMAGE_KEYS:
            assert torch.equal(before[key], after[key]), key
    finally:
        first.close(), second.close()


def test_recorder_and_learner_envs_render_identical_frames():
    """A demonstration recorder's env and the learner's env, built apart, render bit-identical camera frames of the
    same simulator state, at reset and when the state is set from a recording."""
    recorder, learner = RobosuiteEnv("Push", obs="pixels", seed=3), RobosuiteEnv("Push", obs="pixels", seed=8)
    try:
        recorder.set_seed(3)
        recorded = recorder.reset()  # a reset ends on mj_forward: its frames show the state it leaves
        learner.reset()
        seen = learner.observe_state(recorder.sim_env.sim.get_state().flatten())
        td = recorded
        for _ in range(5):
            td = recorder.rand_step(td)["next"]
        state = recorder.sim_env.sim.get_state().flatten()
        again, seen_again = recorder.observe_state(state), learner.observe_state(state)
        for key in IMAGE_KEYS:
            assert torch.equal(recorded[key], seen[key]), key
            assert torch.equal(again[key], seen_again[key]), key
            assert not torch.equal(seen[key], seen_again[key]), key  # the arm moved: the frames are not constant
    finally:
        recorder.close(), learner.close()
