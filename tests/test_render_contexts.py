"""robosuite's offscreen GL contexts are freed in their own GL context: building, closing or garbage-collecting one
camera env never changes the frames of another env in the same process."""
from __future__ import annotations

import gc

import numpy as np
import pytest
import torch

pytest.importorskip("robosuite")

from torchrl_mpail2.envs.robosuite_env import RobosuiteEnv  # noqa: E402
from torchrl_mpail2.envs.robosuite_observations import EXTERNAL_CAMERA, WRIST_CAMERA, upright_chw  # noqa: E402
from torchrl_mpail2.envs.robosuite_render import make_renderer_current  # noqa: E402

IMAGE_KEYS = ("external_image", "wrist_image")


def _reset_frames(env, seed=3):
    env.set_seed(seed)
    td = env.reset()
    return {key: td[key] for key in IMAGE_KEYS}


def _assert_same(frames, expected, when):
    for key in IMAGE_KEYS:
        assert torch.equal(frames[key], expected[key]), f"{key} changed {when}"


@pytest.mark.parametrize("renderer", ["light", "full"])
def test_closing_or_collecting_another_env_leaves_this_envs_frames_unchanged(renderer):
    env = RobosuiteEnv("Push", obs="pixels", seed=3, renderer=renderer)
    try:
        expected = _reset_frames(env)
        # closed and dropped before this env renders again: robosuite frees a context only when it is collected,
        # and mujoco frees a context's buffers in whichever GL context is current then
        closed = RobosuiteEnv("Push", obs="pixels", seed=4, renderer=renderer)
        closed.reset()
        closed.close()
        del closed
        _reset_frames(env)
        gc.collect()
        _assert_same(_reset_frames(env), expected, "after another env was closed and collected")

        # never closed, collected in the middle of this env's step: after this env claimed its context and before
        # robosuite renders through it
        dropped = RobosuiteEnv("Push", obs="pixels", seed=5, renderer=renderer)
        dropped.reset()
        _reset_frames(env)
        make_renderer_current(env.sim_env.sim)
        del dropped
        gc.collect()
        raw = env.sim_env._get_observations(force_update=True)  # robosuite's own render, no context claimed, unchecked
        frames = {"external_image": raw[f"{EXTERNAL_CAMERA}_image"], "wrist_image": raw[f"{WRIST_CAMERA}_image"]}
        _assert_same({key: torch.as_tensor(upright_chw(frame)) for key, frame in frames.items()}, expected,
                     "when another env was collected between claiming the context and rendering")
        _assert_same(_reset_frames(env), expected, "after another env was collected")
    finally:
        env.close()


def test_a_closed_env_releases_its_gl_context_at_once():
    env = RobosuiteEnv("Push", obs="pixels", seed=3)
    context = env.sim_env.sim._render_context_offscreen
    env.close()
    assert context.gl_ctx is None  # freed by close, not left to the garbage collector


def test_a_trainer_that_recorded_its_demonstrations_renders_the_same_frames_after_a_collection(tmp_path):
    """The env that records the scripted demonstrations is dropped once they are saved; before the fix, collecting it
    (at about the sixth episode of a camera run) left the training env reading noise for the rest of the run."""
    from conftest import QUIET_RUN
    from torchrl_mpail2.envs.robosuite_env import robosuite_base
    from torchrl_mpail2.trainers import MPAIL2Trainer, apply_overrides, preset

    cfg = apply_overrides(preset("push_pixels"), [*QUIET_RUN, "train.num_demos=1", "model.latent_dim=16",
                                                  "model.hidden_dims=32,32", "model.coder_dim=32"])
    gc.disable()  # the recorder is collected below, once the training env renders, as in a run
    try:
        trainer = MPAIL2Trainer(cfg, run_dir=tmp_path / "run")  # records one demonstration in this process
        env = robosuite_base(trainer.env)
        expected = _reset_frames(env, seed=0)
    finally:
        gc.enable()
    try:
        gc.collect()
        _assert_same(_reset_frames(env, seed=0), expected, "after the demonstration recorder was collected")
    finally:
        env.close()
        trainer.close()


def test_a_frame_that_is_no_render_is_rendered_again_and_a_camera_that_fails_twice_is_named(monkeypatch):
    env = RobosuiteEnv("Push", obs="pixels", seed=3)
    try:
        expected = _reset_frames(env)
        sim_obs = env.sim_env._get_observations(force_update=True)
        rng = np.random.default_rng(0)
        noise = rng.integers(0, 256, sim_obs["agentview_image"].shape, dtype=np.uint8)
        with pytest.warns(RuntimeWarning, match="external_image"):
            td = env._observation_td({**sim_obs, "agentview_image": noise})  # a failed read: rendered again
        _assert_same({key: td[key] for key in IMAGE_KEYS}, expected, "after a failed read was rendered again")
        black = np.zeros_like(noise)
        monkeypatch.setattr(env.sim_env, "_get_observations", lambda force_update=False: {
            **sim_obs, "robot0_eye_in_hand_image": rng.integers(0, 256, noise.shape, dtype=np.uint8)})
        with pytest.raises(RuntimeError, match="'robot0_eye_in_hand'.*no render twice"):
            env._observation_td({**sim_obs, "robot0_eye_in_hand_image": black})
    finally:
        env.close()
