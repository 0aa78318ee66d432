"""Scripted experts for the robosuite tasks, used to record demonstrations.

Each expert is a TensorDict-in / TensorDict-out policy bound to one :class:`RobosuiteEnv` (directly or under
transforms). It ignores the observation and reads the simulator through
:meth:`RobosuiteEnv.privileged_state`, then writes ``"action"``. The phase of the motion is recomputed from
that state at every step (no memory), so the experts need no reset, recover from a failed grasp or a cube that
slipped sideways, and work inside any rollout or collector that steps the same env.

Measured success over 50 seeded episodes: ``benchmarks/learning/scripted_experts.py`` (``docs/results/diagnostics/scripted_experts.json``).
"""

from __future__ import annotations

import numpy as np
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase

from torchrl_mpail2.envs.robosuite_env import RobosuiteEnv, robosuite_base
from torchrl_mpail2.experts.human_like import HumanLikeMotion

GRIPPER_OPEN = -1.0
GRIPPER_CLOSE = 1.0


def _find_robosuite_env(env) -> RobosuiteEnv:
    """Unwrap TransformedEnvs down to the RobosuiteEnv."""
    base = robosuite_base(env)
    if base is None:
        raise TypeError(f"Scripted experts need a RobosuiteEnv (possibly transformed), got {type(env).__name__}.")
    return base


class _ScriptedExpert(TensorDictModuleBase):
    """Shared plumbing: privileged-state lookup, optional Gaussian action noise or human-like motion, writing
    ``"action"``. With ``human_like`` the position commands get a per-episode style (:mod:`.human_like`),
    redrawn at every :meth:`reset` (the demo recorder calls it before each episode)."""

    tasks: tuple[str, ...] = ()

    def __init__(self, env, *, noise_std: float = 0.0, seed: int | None = None, human_like: bool = False):
        super().__init__()
        self.env = _find_robosuite_env(env)
        if self.env.task not in self.tasks:
            raise ValueError(f"{type(self).__name__} drives {self.tasks}, not {self.env.task!r}.")
        self.in_keys = []
        self.out_keys = ["action"]
        self.noise_std = noise_std
        self._rng = np.random.default_rng(seed)
        self.motion = HumanLikeMotion(self._rng) if human_like else None

    def move_towards(self, eef_pos: np.ndarray, target: np.ndarray, gain: float = 1.5) -> np.ndarray:
        """Proportional position command in action units: each step covers ``gain`` times the remaining distance,
        at most the env's ``max_eef_delta`` (5 cm by default)."""
        return np.clip(gain * (target - eef_pos) / self.env.max_eef_delta, -1.0, 1.0)

    def reset(self) -> None:
        """Starts a new episode (a new human-like style, if any)."""
        if self.motion is not None:
            self.motion.reset()

    def scripted_action(self, state: dict[str, np.ndarray]) -> np.ndarray:
        raise NotImplementedError

    def is_careful(self, action: np.ndarray) -> bool:
        """Whether a human-like style moves carefully at this step (no pauses, little drift)."""
        return False

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = self.scripted_action(self.env.privileged_state())
        if self.motion is not None:
            careful = self.is_careful(action)
            action = np.concatenate([np.clip(self.motion.shape(action[:3], careful), -1.0, 1.0), action[3:]])
        if self.noise_std > 0:
            action = np.clip(action + self.noise_std * self._rng.standard_normal(action.shape), -1.0, 1.0)
        action = torch.as_tensor(action, dtype=torch.float32, device=self.env.device)
        tensordict.set("action", action.expand(*tensordict.batch_size, action.shape[-1]).clone())
        return tensordict


#: Where :class:`LiftExpert` takes the fingers to stop on the cube (see :func:`grasp_width`).
GRASP_WIDTHS = ("side", "footprint")


def grasp_width(half_size: np.ndarray, quat_xyzw: np.ndarray, rule: str = "footprint") -> float:
    """Where the closing fingers stop on a cube: its larger side (``rule="side"``, whatever its yaw) or, by default,
    the width of its footprint across the fingers (``"footprint"``).

    The arm keeps the hand's orientation fixed, fingers closing along a world axis (x or y, within a few degrees),
    so a cube turned by yaw ``psi`` about the vertical is gripped across
    ``2 (h_x |cos psi| + h_y |sin psi|)`` or the same with the half sizes swapped: the wider of the two is used.
    For an axis-aligned cube this is its larger side; at 45 degrees it is the diagonal, about 1.4 times wider.

    Example:
        >>> round(grasp_width(np.array([0.02, 0.02, 0.02]), np.array([0.0, 0.0, 0.0, 1.0])), 3)
        0.04
        >>> yaw_45 = np.array([0.0, 0.0, np.sin(np.pi / 8), np.cos(np.pi / 8)])
        >>> round(grasp_width(np.array([0.02, 0.02, 0.02]), yaw_45), 4), grasp_width(np.full(3, 0.02), yaw_45, "side")
        (0.0566, 0.04)
    """
    if rule == "side":
        return 2.0 * float(max(half_size[0], half_size[1]))
    x, y, z, w = (float(v) for v in quat_xyzw)
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    c, s = abs(np.cos(yaw)), abs(np.sin(yaw))
    hx, hy = float(half_size[0]), float(half_size[1])
    return 2.0 * max(hx * c + hy * s, hy * c + hx * s)


class LiftExpert(_ScriptedExpert):
    """Lift: hover over the cube, descend with the gripper open, close, then lift.

    Phases, chosen from the state at every step:

    1. holding (fingers stopped on the cube, neither wide open nor shut): keep closing and move up;
    2. at the cube (grip site within 1 cm horizontally and vertically of the cube centre): close;
    3. otherwise: gripper open; move over the cube, descending only once horizontally aligned.

    A miss leaves the fingers shut (phase 3 again), which re-opens them and re-approaches.

    Args:
        env: the Lift :class:`RobosuiteEnv`, possibly under transforms.

    Keyword Args:
        noise_std: std of Gaussian noise added to the action (diversifies demonstrations).
        seed: seed of that noise (and of the human-like styles).
        human_like: vary speed, approach path (a via point beside the cube), drift and pauses per episode.
        max_lift_speed: cap on the upward command while holding the cube, in metres per step (``None``: no cap,
            the arm rises at up to ``max_eef_delta`` per step). A slow lift fills the demonstrations with grasped cubes at
            every height between the table and the lift height instead of jumping past them in two steps.
        grasp_width: where the fingers are taken to stop on the cube: ``"side"`` (its larger side, whatever its
            yaw) or ``"footprint"`` (:func:`grasp_width`: its footprint across the fingers). With ``"side"`` a cube
            turned by 30-45 degrees stops the fingers wider than expected, and the expert holds still at the cube
            (seeds 0-9: 15-20 steps longer on the three turned cubes; with the ``binary`` gripper, which closes at
            full force at once, one of them is never lifted). ``"footprint"`` lifts as soon as the fingers stop.
    """

    tasks = ("Lift",)

    def is_careful(self, action: np.ndarray) -> bool:
        return bool(action[3] == GRIPPER_CLOSE)  # grasping or holding the cube

    lift_height = 0.15  # above the table; Lift succeeds once the cube is 4 cm up
    hover_clearance = 0.06  # grip site above the cube centre while aligning
    aligned_tolerance = 0.01
    shut_opening = 0.01  # finger opening below which the grasp missed

    def __init__(self, env, *, noise_std: float = 0.0, seed: int | None = None, max_lift_speed: float | None = None,
                 human_like: bool = False, grasp_width: str = "side"):
        super().__init__(env, noise_std=noise_std, seed=seed, human_like=human_like)
        if grasp_width not in GRASP_WIDTHS:
            raise ValueError(f"grasp_width must be one of {GRASP_WIDTHS}, got {grasp_width!r}.")
        self.grasp_rule = grasp_width
        delta = self.env.max_eef_delta
        if max_lift_speed is not None and not 0.0 < max_lift_speed <= delta:
            raise ValueError(f"max_lift_speed must lie in (0, {delta}] metres per step (the env's max_eef_delta), "
                             f"got {max_lift_speed}.")
        self.max_lift_speed = max_lift_speed

    def scripted_action(self, state: dict[str, np.ndarray]) -> np.ndarray:
        eef, cube = state["eef_pos"], state["cube_pos"]
        table_height = float(state["table_height"][0])
        opening = float(state["gripper_qpos"][0] - state["gripper_qpos"][1])
        cube_width = grasp_width(state["cube_half_size"], state["cube_quat"], self.grasp_rule)
        horizontal_error = np.linalg.norm(cube[:2] - eef[:2])
        vertical_error = abs(cube[2] - eef[2])

        at_cube = horizontal_error < 1.5 * self.aligned_tolerance and vertical_error < 1.5 * self.aligned_tolerance
        fingers_on_cube = self.shut_opening < opening < cube_width + 0.01
        if at_cube and fingers_on_cube:
            target = np.array([cube[0], cube[1], table_height + self.lift_height])
            command = self.move_towards(eef, target)
            if self.max_lift_speed is not None:
                command[2] = min(command[2], self.max_lift_speed / self.env.max_eef_delta)
            return np.append(command, GRIPPER_CLOSE)
        if at_cube and opening >= cube_width + 0.01:
            # Hold still while the fingers close: moving now would knock the cube away.
            return np.append(self.move_towards(eef, cube), GRIPPER_CLOSE)
        if horizontal_error > self.aligned_tolerance:
            target_xy = cube[:2] if self.motion is None else self.motion.via_point(cube[:2], eef[:2])
            target = np.array([*target_xy, max(eef[2], cube[2] + self.hover_clearance)])
        else:
            target = cube
        return np.append(self.move_towards(eef, target), GRIPPER_OPEN)


class PushExpert(_ScriptedExpert):
    """Push / PushMirrored: get behind the cube (the side away from the line), lower, push across the line.

    Phases, chosen from the state at every step (``s`` is the push direction along y):

    1. low, behind the cube and laterally within 80 % of its half width: push towards the line, steering x
       towards the cube's x, until the cube centre is 2 cm past the line, then hold;
    2. low but not behind / not aligned: rise to the travel height (never drag across the cube);
    3. high: travel to the pre-push point (cube half width + 3.5 cm behind it) and descend once over it.

    Args:
        env: the Push or PushMirrored :class:`RobosuiteEnv`, possibly under transforms.

    Keyword Args:
        noise_std: std of Gaussian noise added to the action (diversifies demonstrations).
        seed: seed of that noise (and of the human-like styles).
        human_like: vary speed, drift and pauses per episode.
    """

    tasks = ("Push", "PushMirrored")
    push_height = 0.025  # grip site above the table: fingertips at about the cube's mid-height
    travel_height = 0.10  # above the table: clears a 5 cm cube with the fingers
    standoff = 0.035  # gap behind the cube face at the pre-push point
    overshoot = 0.02  # push the centre this far past the line, so it stays past it
    low_margin = 0.02

    def scripted_action(self, state: dict[str, np.ndarray]) -> np.ndarray:
        eef, cube = state["eef_pos"], state["cube_pos"]
        table_height = float(state["table_height"][0])
        half = float(state["cube_half_size"][:2].max())
        s = float(state["push_sign"][0])
        line_y = float(state["line_y"][0])
        push_z = table_height + self.push_height
        travel_z = table_height + self.travel_height

        along = (eef[1] - cube[1]) * s  # negative when the gripper is on the far side from the line
        lateral = abs(eef[0] - cube[0])
        low = eef[2] < push_z + self.low_margin
        behind = along < -(half + 0.005)
        aligned = lateral < 0.8 * half

        if low and behind and aligned:
            remaining = (line_y - cube[1]) * s + self.overshoot
            if remaining <= 0:
                return np.zeros(3)
            target = np.array([cube[0], eef[1] + s * min(remaining + 0.02, 0.1), push_z])
            return self.move_towards(eef, target)
        if low:
            return self.move_towards(eef, np.array([eef[0], eef[1], travel_z]))
        pre_push = np.array([cube[0], cube[1] - s * (half + self.standoff)])
        over_pre_push = np.linalg.norm(pre_push - eef[:2]) < 0.01
        target_z = push_z if over_pre_push else max(travel_z, min(eef[2], travel_z + 0.05))
        return self.move_towards(eef, np.append(pre_push, target_z))
