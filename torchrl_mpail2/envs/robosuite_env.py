"""TorchRL environment around robosuite manipulation tasks (Lift, Push, PushMirrored), Panda arm.

robosuite's own ``GymWrapper`` reports the horizon end as ``terminated`` (wrong for bootstrapping) and drops
the success flag, so this is a small :class:`~torchrl.envs.EnvBase` of its own.

Control (``OSC_POSITION`` at 20 Hz, actions as end-effector displacement targets inside a workspace box, the
gripper modes): :mod:`torchrl_mpail2.envs.robosuite_control`.

Observation keys and modes (state, pixels, external_pixels): :mod:`torchrl_mpail2.envs.robosuite_observations`.

Every reset and step also writes ``"success"`` (bool ``[1]``), and every step the task reward under
``"task_reward"`` (logging only; MPAIL2 learns its own reward), ``"done"``, ``"terminated"`` (always False:
these tasks never terminate) and ``"truncated"`` (True at the horizon).
"""

from __future__ import annotations

import warnings

# first: it chooses robosuite's GL backend, which robosuite reads once, when it is first imported
from torchrl_mpail2.envs.robosuite_render import (  # isort: skip
    adopt_renderer, check_renderer, make_renderer_current, release_renderer, use_light_renderer,
)

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
import robosuite  # noqa: E402
import torch  # noqa: E402
from tensordict import TensorDict, TensorDictBase  # noqa: E402
from torchrl.data import Bounded, Categorical, Composite, Unbounded  # noqa: E402
from torchrl.envs import EnvBase, Transform, TransformedEnv  # noqa: E402

from torchrl_mpail2.envs.keys import with_bookkeeping  # noqa: E402
from torchrl_mpail2.envs.names import obs_modes_of  # noqa: E402
from torchrl_mpail2.envs.names import ROBOSUITE_TASKS  # noqa: E402
from torchrl_mpail2.envs.robosuite_observations import (  # noqa: E402
    EXTERNAL_CAMERA, IMAGE_SIZE, PROPRIO_DIM, WRIST_CAMERA, object_vector, proprio_vector,
    unrendered, upright_chw,
)
from torchrl_mpail2.envs.robosuite_control import (  # noqa: E402
    CONTROL_FREQ_HZ, GRIPPER_CLOSED, MAX_EEF_DELTA, OSC_POSITION_ARM, binary_gripper_state, check_control_settings,
    position_command,
)
from torchrl_mpail2.envs import push_task  # noqa: E402, F401  (registers Push / PushMirrored, patches mujoco compat)

DEFAULT_HORIZON = {"Lift": 100, "Push": 100, "PushMirrored": 100}
#: Side of the frames of :meth:`RobosuiteEnv.render` (evaluation videos), pixels.
RENDER_SIZE = 256

# mujoco warnings that mean the physics or the commanded torques went non-finite or diverged.
_INSTABILITY_WARNINGS = {
    "BADQACC": mujoco.mjtWarning.mjWARN_BADQACC,
    "BADQPOS": mujoco.mjtWarning.mjWARN_BADQPOS,
    "BADQVEL": mujoco.mjtWarning.mjWARN_BADQVEL,
    "BADCTRL": mujoco.mjtWarning.mjWARN_BADCTRL,
}


def _check_names(task: str, obs: str) -> None:
    if task not in ROBOSUITE_TASKS:
        raise ValueError(f"Unknown robosuite task {task!r}; valid tasks: {', '.join(ROBOSUITE_TASKS)}.")
    modes = obs_modes_of("robosuite")
    if obs not in modes:
        raise ValueError(f"Unknown observation mode {obs!r}; valid modes: {', '.join(modes)}.")


class RobosuiteEnv(EnvBase):
    """A robosuite task as a TorchRL environment (batch size ``[]``); see the module docstring for the keys.

    Args:
        task: ``"Lift"``, ``"Push"`` or ``"PushMirrored"``.
        obs: ``"state"``, ``"pixels"`` or ``"external_pixels"``.

    Keyword Args:
        horizon: steps per episode before ``truncated``; defaults to :data:`DEFAULT_HORIZON` of the task.
        seed: seeds robosuite at construction (Lift's cube size is drawn then) and the first resets.
        device: device of the output tensors.
        gripper: one of :data:`~torchrl_mpail2.envs.robosuite_control.GRIPPER_MODES` (``"integrating"``,
            robosuite's own, by default).
        observe_gripper_command: append the gripper's current command to ``"proprio"``.
        max_eef_delta: end-effector displacement of a unit action, metres per step, in ``(0, 0.05]``
            (:data:`~torchrl_mpail2.envs.robosuite_control.MAX_EEF_DELTA`, robosuite's ``output_max``, by
            default). A smaller value gives finer steps for the same action noise and slows the hand in
            proportion (the scripted Lift expert first succeeds at steps 33 / 31 / 49 of seeds 0-2 at 5 cm,
            47 / 45 / 82 at 3 cm); demos recorded by the scripted experts in such an env move with the same scale.
        renderer: one of :data:`~torchrl_mpail2.envs.robosuite_render.RENDERERS`: ``"light"`` (default; see
            :func:`~torchrl_mpail2.envs.robosuite_render.use_light_renderer`) or ``"full"`` (robosuite's own
            settings: shadows, reflections, 4x multisampling; about 4 times the cost of a camera frame).

    Raises:
        ValueError: on an unknown task, observation mode, gripper mode or renderer, or a ``max_eef_delta`` outside
            ``(0, 0.05]``.
        RuntimeError: from :meth:`step` when the simulator fails (exception or unstable physics); the message
            names the task. Reset the env before using it again.

    Examples:
        >>> env = RobosuiteEnv("Push", obs="state", horizon=5)
        >>> td = env.rollout(10)
        >>> td.shape, td["next", "truncated"][-1].item(), td["next", "terminated"].any().item()
        (torch.Size([5]), True, False)
        >>> td["object"].shape
        torch.Size([5, 11])
    """

    def __init__(
        self,
        task: str = "Lift",
        obs: str = "state",
        *,
        horizon: int | None = None,
        seed: int = 0,
        device: torch.device | str = "cpu",
        gripper: str = "integrating",
        observe_gripper_command: bool = False,
        max_eef_delta: float = MAX_EEF_DELTA,
        renderer: str = "light",
    ):
        _check_names(task, obs)
        check_renderer(renderer)
        self.max_eef_delta = check_control_settings(gripper, max_eef_delta)
        self.gripper_mode = gripper
        self.observe_gripper_command = bool(observe_gripper_command)
        super().__init__(device=device, batch_size=torch.Size([]))
        self.task = task
        self.obs_mode = obs
        self.horizon = DEFAULT_HORIZON[task] if horizon is None else int(horizon)
        self.is_push = task != "Lift"
        self._cameras = {"state": [], "pixels": [EXTERNAL_CAMERA, WRIST_CAMERA], "external_pixels": [EXTERNAL_CAMERA]}[
            obs
        ]
        uses_cameras = bool(self._cameras)
        self._sim_env = robosuite.make(
            task,
            robots="Panda",
            controller_configs={"type": "BASIC", "body_parts": {"right": dict(OSC_POSITION_ARM)}},
            use_camera_obs=uses_cameras,
            has_offscreen_renderer=uses_cameras,
            has_renderer=False,
            camera_names=self._cameras or EXTERNAL_CAMERA,
            camera_heights=IMAGE_SIZE,
            camera_widths=IMAGE_SIZE,
            reward_shaping=True,
            control_freq=CONTROL_FREQ_HZ,
            # The horizon is counted here; robosuite's own would raise on the step after it.
            horizon=10**9,
            ignore_done=True,
            # A hard reset rebuilds the mujoco model and renderer every episode; the scene never changes here.
            # Consequence: Lift's cube size is drawn once, from the construction seed.
            hard_reset=False,
            seed=seed,
        )
        self.renderer = renderer
        self._configure_renderer()
        self._steps_taken = 0
        self._make_specs()

    def _configure_renderer(self) -> None:
        """The light renderer for the cameras (robosuite builds a context with its full settings with each model);
        either renderer's context is released in its own GL context when collected."""
        adopt_renderer(self._sim_env.sim)
        if self._cameras and self.renderer == "light":
            use_light_renderer(self._sim_env.sim, IMAGE_SIZE)

    # -- specs ------------------------------------------------------------------------------------------------

    def _make_specs(self) -> None:
        action_dim = 3 if self.is_push else 4
        self.action_spec = Bounded(-1.0, 1.0, (action_dim,), dtype=torch.float32, device=self.device)
        image_spec = Bounded(0, 255, (3, IMAGE_SIZE, IMAGE_SIZE), dtype=torch.uint8, device=self.device)
        observations = {"success": Categorical(2, (1,), dtype=torch.bool, device=self.device)}
        if self.obs_mode in ("state", "pixels"):
            proprio_dim = PROPRIO_DIM + int(self.observe_gripper_command)
            observations["proprio"] = Unbounded((proprio_dim,), dtype=torch.float32, device=self.device)
        if self.obs_mode == "state":
            observations["object"] = self.object_spec()
        if self.obs_mode in ("pixels", "external_pixels"):
            observations["external_image"] = image_spec
        if self.obs_mode == "pixels":
            observations["wrist_image"] = image_spec.clone()
        self.observation_spec = Composite(observations, device=self.device)
        self.reward_spec = Composite(
            task_reward=Unbounded((1,), dtype=torch.float32, device=self.device), device=self.device
        )
        flag = Categorical(2, (1,), dtype=torch.bool, device=self.device)
        self.done_spec = Composite(done=flag, terminated=flag.clone(), truncated=flag.clone(), device=self.device)

    def close(self, *, raise_if_closed: bool = True) -> None:
        """Close the env and release robosuite's offscreen renderer, if any, at once and in its own GL context
        (:func:`~torchrl_mpail2.envs.robosuite_render.release_renderer`)."""
        if self._sim_env.sim is not None:  # torchrl counts an env never reset as closed; robosuite's is open
            release_renderer(self._sim_env.sim)
            self._sim_env.close()
        super().close(raise_if_closed=raise_if_closed)

    # -- privileged access for scripted experts -----------------------------------------------------------------

    @property
    def sim_env(self):
        """The wrapped robosuite environment."""
        return self._sim_env

    def privileged_state(self) -> dict[str, np.ndarray]:
        """Simulator state that is not (necessarily) part of the observation, for scripted experts.

        Returns:
            ``eef_pos [3]``, ``cube_pos [3]``, ``cube_quat [4]`` (xyzw), ``cube_half_size [3]``,
            ``gripper_qpos [2]`` (finger joints, left positive and right negative: the opening
            ``q[0] - q[1]`` is about 0.08 m wide open and 0.003 m shut), ``table_height [1]``;
            Push tasks add ``line_y [1]`` and ``push_sign [1]`` (+1 / -1: the y direction the cube must travel).
        """
        sim_env = self._sim_env
        data = sim_env.sim.data
        robot = sim_env.robots[0]
        state = {
            "eef_pos": np.array(data.site_xpos[robot.eef_site_id["right"]]),
            "cube_pos": np.array(data.body_xpos[sim_env.cube_body_id]),
            "cube_quat": np.array(data.body_xquat[sim_env.cube_body_id])[[1, 2, 3, 0]],
            "cube_half_size": np.array(sim_env.cube.size, dtype=np.float64),
            "gripper_qpos": np.array(data.qpos[robot._ref_gripper_joint_pos_indexes["right"]]),
            "table_height": np.array([sim_env.table_offset[2]]),
        }
        if self.is_push:
            state["line_y"] = np.array([sim_env.line_y])
            state["push_sign"] = np.array([sim_env.push_sign])
        return state

    def object_observation(self) -> np.ndarray:
        """State mode's ``"object"`` vector (:func:`object_vector`) read from the simulator now, in any mode."""
        return object_vector(self.privileged_state(), self._sim_env.distance_to_line() if self.is_push else None)

    def object_spec(self) -> Unbounded:
        """The spec of :meth:`object_observation`: ``[10]`` on Lift, ``[11]`` on Push."""
        return Unbounded((11 if self.is_push else 10,), dtype=torch.float32, device=self.device)

    def render(self, size: int = RENDER_SIZE, camera: str = EXTERNAL_CAMERA) -> np.ndarray:
        """An upright RGB frame ``[size, size, 3]`` uint8 of the current scene from ``camera`` (default: the
        external ``agentview``). The offscreen renderer is created on first use, in state mode too."""
        sim = self._sim_env.sim
        if sim._render_context_offscreen is None:
            from robosuite.utils.binding_utils import MjRenderContextOffscreen

            MjRenderContextOffscreen(sim, device_id=-1)  # registers itself with the sim
            sim._render_context_offscreen.vopt.geomgroup[0] = 0  # collision meshes hidden,
            sim._render_context_offscreen.vopt.geomgroup[1] = 1  # visual meshes shown, as robosuite's cameras
        make_renderer_current(sim)
        return np.ascontiguousarray(sim.render(width=size, height=size, camera_name=camera)[::-1])

    # -- replaying recorded simulator states (robosuite's teleoperation files) ---------------------------------

    def load_model_xml(self, xml: str) -> None:
        """Rebuilds the simulation from a recorded MJCF model (robosuite's ``model_file``: the recorded cube size)."""
        release_renderer(self._sim_env.sim)  # robosuite drops the old sim and builds a new context
        self._sim_env.reset_from_xml_string(xml)
        self._configure_renderer()
        self.reset_gripper_command()
        self._steps_taken = 0

    def reset_gripper_command(self) -> None:
        """Sets the gripper controller's stored command to 0, its value after a reset."""
        self._gripper.current_action = np.zeros_like(np.atleast_1d(self._gripper.current_action))

    def observe_state(self, flat_state: np.ndarray) -> TensorDict:
        """This env's observation (and ``"success"``) of a flattened mujoco state (``sim.get_state().flatten()``)."""
        sim = self._sim_env.sim
        sim.set_state_from_flattened(np.asarray(flat_state, dtype=np.float64))
        sim.forward()
        make_renderer_current(sim)
        return self._observation_td(self._sim_env._get_observations(force_update=True))

    def apply_gripper_command(self, sim_action: np.ndarray) -> None:
        """Advances the gripper controller's stored command as a step with robosuite action ``sim_action`` would
        (what ``observe_gripper_command`` reports), without stepping the simulation."""
        if self.gripper_mode == "binary":
            self._gripper.current_action = binary_gripper_state(sim_action[-1])
        else:
            self._gripper.format_action(np.asarray(sim_action[-1:], dtype=np.float64))

    # -- EnvBase hooks -----------------------------------------------------------------------------------------

    def _set_seed(self, seed: int | None) -> None:
        # robosuite's env generator is shared by the cube sampler and the robot's initial-joint noise, so
        # overwriting its state in place reseeds every consumer at once.
        self._sim_env.rng.bit_generator.state = np.random.default_rng(seed).bit_generator.state

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        make_renderer_current(self._sim_env.sim)
        try:
            sim_obs = self._sim_env.reset()
        except Exception as error:
            raise RuntimeError(f"robosuite task {self.task!r} failed to reset: {error}") from error
        self._steps_taken = 0
        out = self._observation_td(sim_obs)
        for key in ("done", "terminated", "truncated"):
            out.set(key, torch.zeros(1, dtype=torch.bool, device=self.device))
        return out

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = self._to_sim_action(tensordict.get("action"))
        warnings_before = self._instability_warning_counts()
        make_renderer_current(self._sim_env.sim)
        try:
            sim_obs, task_reward, _, _ = self._sim_env.step(action)
        except Exception as error:
            raise RuntimeError(f"robosuite task {self.task!r}: simulator step failed: {error}") from error
        # mujoco does not raise on a divergence or a NaN torque: it warns and silently resets the state (or zeroes
        # the control), which would hand the learner a teleporting or limp robot. Surface it instead.
        new_warnings = [
            name for name, count in self._instability_warning_counts().items() if count > warnings_before[name]
        ]
        if new_warnings:
            raise RuntimeError(
                f"robosuite task {self.task!r}: simulation became unstable (mujoco {', '.join(new_warnings)}); "
                "reset the environment"
            )
        self._steps_taken += 1
        out = self._observation_td(sim_obs)
        truncated = self._steps_taken >= self.horizon
        out.set("task_reward", torch.tensor([task_reward], dtype=torch.float32, device=self.device))
        out.set("terminated", torch.zeros(1, dtype=torch.bool, device=self.device))
        out.set("truncated", torch.tensor([truncated], device=self.device))
        out.set("done", torch.tensor([truncated], device=self.device))
        return out

    def _instability_warning_counts(self) -> dict[str, int]:
        warnings = self._sim_env.sim.data._data.warning
        return {name: int(warnings[int(kind)].number) for name, kind in _INSTABILITY_WARNINGS.items()}

    # -- conversions --------------------------------------------------------------------------------------------

    def _to_sim_action(self, action: torch.Tensor) -> np.ndarray:
        """Scale the displacement by ``max_eef_delta``, clip it to the workspace box; append the fixed gripper for
        Push."""
        action = action.detach().to("cpu", torch.float64).numpy().reshape(-1)
        position_action = position_command(action, self.privileged_state()["eef_pos"], self.max_eef_delta)
        gripper_action = [GRIPPER_CLOSED] if self.is_push else action[3:4]
        if self.gripper_mode == "binary" and not np.isnan(gripper_action[0]):
            # robosuite adds 0.2 * sign(action) to the stored command each step: start it at the target already
            self._gripper.current_action = binary_gripper_state(gripper_action[0])
        return np.concatenate([position_action, gripper_action])

    @property
    def _gripper(self):
        return self._sim_env.robots[0].gripper["right"]

    def gripper_command(self) -> float:
        """The gripper controller's current command in ``[-1, 1]`` (-1 open, +1 closed; 0 after a reset)."""
        return float(np.atleast_1d(self._gripper.current_action)[-1])

    def _observation_td(self, sim_obs: dict) -> TensorDict:
        out = {"success": np.array([bool(self._sim_env._check_success())])}
        if self.obs_mode in ("state", "pixels"):
            out["proprio"] = proprio_vector(sim_obs, self.gripper_command() if self.observe_gripper_command else None)
        if self.obs_mode == "state":
            out["object"] = self.object_observation()
        if self.obs_mode in ("pixels", "external_pixels"):
            out.update(self._camera_frames(sim_obs))
        # the TensorDict names its device: transforms such as TensorDictPrimer build their reset masks on it
        return TensorDict(
            {key: torch.as_tensor(value, device=self.device) for key, value in out.items()}, batch_size=[],
            device=self.device,
        )

    def _camera_frames(self, sim_obs: dict) -> dict[str, np.ndarray]:
        """The upright camera frames of ``sim_obs``, each checked to be a render
        (:func:`~torchrl_mpail2.envs.robosuite_observations.unrendered`). Where one is not, the cameras render the
        same state again in this env's own GL context: a frame that comes back the same was a render after all; one
        that comes back otherwise was a failed read, replaced by the new render, with a warning.

        Raises:
            RuntimeError: a camera failed to render twice running (naming the camera).
        """
        keys = {"external_image": EXTERNAL_CAMERA, **({"wrist_image": WRIST_CAMERA} if self.obs_mode == "pixels" else {})}
        frames = {key: upright_chw(sim_obs[f"{camera}_image"]) for key, camera in keys.items()}
        if not any(unrendered(frame) for frame in frames.values()):
            return frames
        make_renderer_current(self._sim_env.sim)
        again = self._sim_env._get_observations(force_update=True)
        redone = {key: upright_chw(again[f"{camera}_image"]) for key, camera in keys.items()}
        for key, camera in keys.items():
            if unrendered(redone[key]) and not np.array_equal(redone[key], frames[key]):
                raise RuntimeError(f"robosuite camera {camera!r} ({key!r}) returned no render twice running (noise or "
                                   "black frames): its GL context lost its buffers")
        failed = [key for key in keys if not np.array_equal(redone[key], frames[key])]
        if failed:
            warnings.warn(f"robosuite camera frames {failed} were no render (a failed GL read); rendered again",
                          RuntimeWarning, stacklevel=2)
        return redone


def robosuite_base(env) -> RobosuiteEnv | None:
    """The :class:`RobosuiteEnv` inside ``env`` (through TransformedEnvs' ``base_env``), or None if there is none."""
    while env is not None and not isinstance(env, RobosuiteEnv):
        env = getattr(env, "base_env", None)
    return env


class SimulatorObject(Transform):
    """Writes state mode's ``"object"`` vector (:meth:`RobosuiteEnv.object_observation`: cube position and
    quaternion, the end effector's offset from the cube, Push's distance to the line) from the simulator into the
    observations of a camera env, for diagnostics that read a camera run's episodes as a state run's; an agent reads
    only its encoder's keys. Append it to the env: ``env.append_transform(SimulatorObject())``."""

    def __init__(self):
        super().__init__(in_keys=[], out_keys=["object"])

    def _base(self) -> RobosuiteEnv:
        base = robosuite_base(self.parent)
        if base is None:
            raise ValueError("SimulatorObject reads the simulator's cube and hand: it needs a robosuite env")
        return base

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        base = self._base()
        return next_tensordict.set("object", torch.as_tensor(base.object_observation(), device=base.device))

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        return self._call(tensordict_reset)

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        observation_spec["object"] = self._base().object_spec()
        return observation_spec


def with_simulator_object(env):
    """``env`` with :class:`SimulatorObject` appended where it is a robosuite env that does not observe
    ``"object"`` (a camera env); any other env unchanged."""
    if robosuite_base(env) is None or "object" in env.observation_spec.keys():
        return env
    return env.append_transform(SimulatorObject())


def make_robosuite_env(
    task: str,
    obs: str = "state",
    seed: int = 0,
    horizon: int | None = None,
    device: torch.device | str = "cpu",
    gripper: str = "integrating",
    observe_gripper_command: bool = False,
    max_eef_delta: float = MAX_EEF_DELTA,
    renderer: str = "light",
) -> TransformedEnv:
    """Build a seeded :class:`RobosuiteEnv` with step counting, init tracking and an episode task-return sum.

    Args:
        task: ``"Lift"``, ``"Push"`` or ``"PushMirrored"``.
        obs: ``"state"``, ``"pixels"`` or ``"external_pixels"``.
        seed: seed of robosuite's generator (cube placement, initial joint noise).
        horizon: episode length in steps; the task default when ``None``.
        device: device of the output tensors.
        gripper, observe_gripper_command, max_eef_delta, renderer: see :class:`RobosuiteEnv`.

    Returns:
        The env under ``StepCounter``, ``InitTracker`` (``"is_init"``) and
        ``RewardSum(["task_reward"], ["episode_task_return"])``.

    Raises:
        ValueError: on an unknown task or observation mode, listing the valid ones.
    """
    _check_names(task, obs)
    base_env = RobosuiteEnv(task, obs, horizon=horizon, seed=seed, device=device, gripper=gripper,
                            observe_gripper_command=observe_gripper_command, max_eef_delta=max_eef_delta,
                            renderer=renderer)
    base_env.set_seed(seed)
    return with_bookkeeping(base_env)
