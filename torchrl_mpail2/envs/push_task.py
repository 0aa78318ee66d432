"""A robosuite cube-pushing task (robosuite 1.5 ships none) and a mujoco compatibility patch.

Importing this module registers ``Push`` and ``PushMirrored`` with robosuite, so
``robosuite.make("Push", robots="Panda", ...)`` works, and patches robosuite for newer mujoco releases
(see :func:`apply_mujoco_compat_patches`).

Scene (world frame, metres; the table top is at ``z = 0.8``, the Panda base at ``x = -0.56``):

* a 4.5 cm cube spawns uniformly in a 10 cm (x) by 6 cm (y) region centred at ``(0, +0.06)``;
* a 2 cm wide, visual-only blue stripe on the table marks the target line ``y = -0.06``;
* success once the cube centre is past the line (``cube_y < -0.06``).

``PushMirrored`` reflects the scene through the x-z plane: the cube spawns around ``y = -0.06`` and must be
pushed past ``y = +0.06``.
"""

from __future__ import annotations

import mujoco
import numpy as np
from robosuite.controllers.parts import controller as _robosuite_controller
from robosuite.environments.manipulation.manipulation_env import ManipulationEnv
from robosuite.models.arenas import TableArena
from robosuite.models.objects import BoxObject
from robosuite.models.tasks import ManipulationTask
from robosuite.utils import binding_utils as _robosuite_bindings
from robosuite.utils.mjcf_utils import new_geom
from robosuite.utils.observables import Observable, sensor
from robosuite.utils.placement_samplers import UniformRandomSampler
from robosuite.utils.transform_utils import convert_quat

TABLE_TOP = np.array([0.0, 0.0, 0.8])
CUBE_HALF_SIZE = 0.0225
SPAWN_CENTER_Y = 0.06
SPAWN_HALF_EXTENT_X = 0.05
SPAWN_HALF_EXTENT_Y = 0.03
SPAWN_MAX_YAW = 0.3
LINE_Y = -0.06
LINE_HALF_WIDTH = 0.01
LINE_HALF_LENGTH = 0.2
LINE_HALF_THICKNESS = 0.0005


# ---------------------------------------------------------------------------------------------------------------
# robosuite 1.5.2 / new mujoco compatibility
# ---------------------------------------------------------------------------------------------------------------


def _joint_address(model, name: str, address_table, free_dim: int, ball_dim: int):
    joint_id = model.joint_name2id(name)
    joint_type = int(model.jnt_type[joint_id])
    start = int(address_table[joint_id])
    width = {int(mujoco.mjtJoint.mjJNT_FREE): free_dim, int(mujoco.mjtJoint.mjJNT_BALL): ball_dim}.get(joint_type, 1)
    return start if width == 1 else (start, start + width)


def _controller_update_sparse_inertia(self, force: bool = False) -> None:
    """``Controller.update`` for mujoco builds whose ``mj_fullM`` reads the inertia from ``MjData`` itself."""
    if not (self.new_update or force):
        return
    if force or not self.lite_physics:
        self.sim.forward()
    if self.ref_name is not None:
        self.update_reference_data()
    self.joint_pos = np.array(self.sim.data.qpos[self.qpos_index])
    self.joint_vel = np.array(self.sim.data.qvel[self.qvel_index])
    num_dofs = self.sim.model.nv
    full_inertia = np.zeros((num_dofs, num_dofs))
    mujoco.mj_fullM(self.sim.model._model, self.sim.data._data, full_inertia)
    self.mass_matrix = full_inertia[np.ix_(self.qvel_index, self.qvel_index)]
    self.new_update = False


def apply_mujoco_compat_patches() -> None:
    """Make robosuite 1.5.2 run on the mujoco installed here (3.17); idempotent, harmless on mujoco 3.3.

    Two breakages, both fixed by replacing one robosuite method each:

    * ``MjModel.get_joint_qpos_addr`` / ``get_joint_qvel_addr`` test ``jnt_type in (mjtJoint.mjJNT_HINGE, ...)``.
      With new bindings the enum's ``__eq__`` rejects ``numpy.int32``, so that test is False for every hinge
      and ``robosuite.make`` dies on an ``AssertionError``. The patch compares plain ints.
    * ``Controller.update`` reads ``MjData.qM`` and calls ``mj_fullM(m, dst, qM)``; new mujoco removed ``qM`` and
      changed the call to ``mj_fullM(m, d, dst)``. Patched only when ``qM`` is missing.
    """
    model_cls = _robosuite_bindings.MjModel
    model_cls.get_joint_qpos_addr = lambda self, name: _joint_address(self, name, self.jnt_qposadr, 7, 4)
    model_cls.get_joint_qvel_addr = lambda self, name: _joint_address(self, name, self.jnt_dofadr, 6, 3)
    if not hasattr(mujoco.MjData, "qM"):
        _robosuite_controller.Controller.update = _controller_update_sparse_inertia


apply_mujoco_compat_patches()


# ---------------------------------------------------------------------------------------------------------------
# The task
# ---------------------------------------------------------------------------------------------------------------


class Push(ManipulationEnv):
    """Push a cube across a target line on the table, single arm (Panda).

    Args:
        robots: robosuite robot name(s); a single arm.
        mirrored: push towards +y instead of -y (spawn region and line reflected through ``y = 0``).
        table_full_size: table dimensions (x, y, z) in metres.
        table_friction: mujoco friction triple of the table.
        use_object_obs: add ``cube_pos``, ``cube_quat`` and ``cube_to_line`` robosuite observables.
        reward_shaping: dense reward (see :meth:`reward`); otherwise 1 on success, 0 elsewhere.
        **kwargs: forwarded to :class:`robosuite.environments.manipulation.manipulation_env.ManipulationEnv`
            (controller_configs, use_camera_obs, camera_names, horizon, seed, ...).
    """

    def __init__(
        self,
        robots="Panda",
        mirrored: bool = False,
        table_full_size=(0.8, 0.8, 0.05),
        table_friction=(1.0, 5e-3, 1e-4),
        use_object_obs: bool = True,
        reward_shaping: bool = True,
        **kwargs,
    ):
        self.mirrored = mirrored
        # +1 / -1: the y direction the cube has to travel.
        self.push_sign = 1.0 if mirrored else -1.0
        self.line_y = -LINE_Y if mirrored else LINE_Y
        self.spawn_center_y = -self.line_y
        self.table_full_size = table_full_size
        self.table_friction = table_friction
        self.table_offset = TABLE_TOP.copy()
        self.use_object_obs = use_object_obs
        self.reward_shaping = reward_shaping
        self.placement_initializer = None
        super().__init__(robots=robots, **kwargs)

    # -- geometry helpers used by the reward, the observables and the scripted expert -------------------------

    @property
    def cube_pos(self) -> np.ndarray:
        """Cube centre, world frame, shape ``[3]``."""
        return np.array(self.sim.data.body_xpos[self.cube_body_id])

    def distance_to_line(self) -> float:
        """Distance the cube centre still has to travel to cross the line; negative once it has crossed."""
        return float((self.line_y - self.cube_pos[1]) * self.push_sign)

    def reward(self, action=None) -> float:
        """Task reward, for logging only.

        Dense: ``0.25 * reach + 0.5 * progress + 1.0 * success`` with
        ``reach = 1 - tanh(10 * |eef - pre-push point|)`` (the point just behind the cube, opposite the line)
        and ``progress = 1 - tanh(10 * max(distance_to_line, 0))``. Sparse: ``1.0 * success``.
        """
        success = float(self._check_success())
        if not self.reward_shaping:
            return success
        pre_push_point = self.cube_pos - np.array([0.0, self.push_sign * (CUBE_HALF_SIZE + 0.01), 0.0])
        eef_pos = np.array(self.sim.data.site_xpos[self.robots[0].eef_site_id["right"]])
        reach = 1.0 - np.tanh(10.0 * np.linalg.norm(eef_pos - pre_push_point))
        progress = 1.0 - np.tanh(10.0 * max(self.distance_to_line(), 0.0))
        return 0.25 * reach + 0.5 * progress + success

    def _check_success(self) -> bool:
        return self.distance_to_line() < 0.0

    # -- robosuite model construction ---------------------------------------------------------------------------

    def _load_model(self):
        super()._load_model()
        robot_model = self.robots[0].robot_model
        robot_model.set_base_xpos(robot_model.base_xpos_offset["table"](self.table_full_size[0]))

        arena = TableArena(
            table_full_size=self.table_full_size,
            table_friction=self.table_friction,
            table_offset=self.table_offset,
        )
        arena.set_origin([0, 0, 0])
        # Visual only (no contype/conaffinity): it must show up in the cameras without touching the cube.
        arena.worldbody.append(
            new_geom(
                name="target_line",
                type="box",
                size=(LINE_HALF_LENGTH, LINE_HALF_WIDTH, LINE_HALF_THICKNESS),
                pos=(self.table_offset[0], self.line_y, self.table_offset[2] + LINE_HALF_THICKNESS),
                group=1,
                contype=0,
                conaffinity=0,
                rgba=(0.1, 0.3, 0.9, 1.0),
            )
        )

        self.cube = BoxObject(name="cube", size=[CUBE_HALF_SIZE] * 3, rgba=[0.9, 0.1, 0.1, 1.0], rng=self.rng)
        # The sampler shares self.rng, so reseeding that generator in place reseeds the spawn positions too.
        self.placement_initializer = UniformRandomSampler(
            name="CubeSampler",
            mujoco_objects=self.cube,
            x_range=[-SPAWN_HALF_EXTENT_X, SPAWN_HALF_EXTENT_X],
            y_range=[self.spawn_center_y - SPAWN_HALF_EXTENT_Y, self.spawn_center_y + SPAWN_HALF_EXTENT_Y],
            rotation=(-SPAWN_MAX_YAW, SPAWN_MAX_YAW),
            ensure_object_boundary_in_range=False,
            ensure_valid_placement=True,
            reference_pos=self.table_offset,
            z_offset=0.002,
            rng=self.rng,
        )
        self.model = ManipulationTask(
            mujoco_arena=arena,
            mujoco_robots=[robot.robot_model for robot in self.robots],
            mujoco_objects=self.cube,
        )

    def _setup_references(self):
        super()._setup_references()
        self.cube_body_id = self.sim.model.body_name2id(self.cube.root_body)

    def _setup_observables(self):
        observables = super()._setup_observables()
        if not self.use_object_obs:
            return observables

        @sensor(modality="object")
        def cube_pos(obs_cache):
            return self.cube_pos

        @sensor(modality="object")
        def cube_quat(obs_cache):
            return convert_quat(np.array(self.sim.data.body_xquat[self.cube_body_id]), to="xyzw")

        @sensor(modality="object")
        def cube_to_line(obs_cache):
            return np.array([self.distance_to_line()])

        for object_sensor in (cube_pos, cube_quat, cube_to_line):
            observables[object_sensor.__name__] = Observable(
                name=object_sensor.__name__, sensor=object_sensor, sampling_rate=self.control_freq
            )
        return observables

    def _reset_internal(self):
        super()._reset_internal()
        if self.deterministic_reset:
            return
        for position, quaternion, placed_object in self.placement_initializer.sample().values():
            self.sim.data.set_joint_qpos(placed_object.joints[0], np.concatenate([position, quaternion]))


class PushMirrored(Push):
    """:class:`Push` reflected through ``y = 0``: the cube is pushed towards +y."""

    def __init__(self, robots="Panda", **kwargs):
        kwargs.pop("mirrored", None)
        super().__init__(robots=robots, mirrored=True, **kwargs)
