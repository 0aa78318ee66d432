"""How an action of :class:`~torchrl_mpail2.envs.robosuite_env.RobosuiteEnv` becomes a robosuite command.

Control: robosuite ``OSC_POSITION`` at 20 Hz. An action in ``[-1, 1]`` per axis is an end-effector
displacement target of up to 5 cm per step (robosuite's default ``output_max``; ``max_eef_delta`` shrinks it),
relative to the current end-effector position. The controller lags its targets: a full action held along one
axis moves the hand 0.5, 0.9, 1.0, ... 1.3 cm over its first steps (Lift, seed 0), in proportion to the target.
Lift adds a gripper command (-1 open, +1 close); Push keeps the gripper closed so the fingers act as a rigid
pusher.

Workspace box: the commanded displacement is shortened so that the target stays inside
``x, y in [-0.25, 0.25]``, ``z in [0.81, 1.15]`` (world frame, metres; table top at ``z = 0.8``, table centre
at the origin, robot base at ``x = -0.56``). The floor of 1 cm keeps the closed fingers off the table while
still reaching a 4-5 cm cube's centre.
"""
from __future__ import annotations

import numpy as np

CONTROL_FREQ_HZ = 20
MAX_EEF_DELTA = 0.05  # metres per unit action: robosuite's OSC_POSITION output_max
WORKSPACE_LOW = np.array([-0.25, -0.25, 0.81])
WORKSPACE_HIGH = np.array([0.25, 0.25, 1.15])
GRIPPER_CLOSED = 1.0
#: ``integrating``: robosuite's Panda gripper, each step moves its internal command by 0.2 towards the sign of
#: the action (up to ten steps from open to closed); ``binary``: the sign of the action opens or closes it at once.
GRIPPER_MODES = ("integrating", "binary")

#: robosuite controller settings of the arm (its ``BASIC`` composite controller's ``right`` part).
OSC_POSITION_ARM = {
    "type": "OSC_POSITION",
    "input_max": 1,
    "input_min": -1,
    "output_max": [MAX_EEF_DELTA] * 3,
    "output_min": [-MAX_EEF_DELTA] * 3,
    "kp": 150,
    "damping_ratio": 1,
    "impedance_mode": "fixed",
    "kp_limits": [0, 300],
    "damping_ratio_limits": [0, 10],
    "position_limits": None,
    "input_type": "delta",
    "input_ref_frame": "base",
    "interpolation": None,
    "ramp_ratio": 0.2,
    "gripper": {"type": "GRIP"},
}


def check_control_settings(gripper: str, max_eef_delta: float) -> float:
    """``max_eef_delta`` as a float once both settings are known to be valid.

    Raises:
        ValueError: on an unknown gripper mode or a ``max_eef_delta`` outside ``(0, MAX_EEF_DELTA]``.
    """
    if not 0.0 < float(max_eef_delta) <= MAX_EEF_DELTA:
        raise ValueError(f"max_eef_delta must lie in (0, {MAX_EEF_DELTA}] metres per step, got {max_eef_delta!r}.")
    if gripper not in GRIPPER_MODES:
        raise ValueError(f"Unknown gripper mode {gripper!r}; valid modes: {', '.join(GRIPPER_MODES)}.")
    return float(max_eef_delta)


def position_command(action: np.ndarray, eef_pos: np.ndarray, max_eef_delta: float) -> np.ndarray:
    """robosuite's position input ``[3]`` for an action's first three entries.

    The target ``eef_pos + max_eef_delta * action`` is clipped to the workspace box, then expressed in the
    controller's own scale (:data:`MAX_EEF_DELTA` per unit of its input). A NaN entry stays NaN on purpose: the
    step then fails loudly instead of silently doing nothing.

    Examples:
        >>> position_command(np.array([1.0, 0.0, np.nan]), np.zeros(3) + [0, 0, 1.0], 0.025).tolist()
        [0.5, 0.0, nan]
    """
    target = np.clip(eef_pos + max_eef_delta * action[:3], WORKSPACE_LOW, WORKSPACE_HIGH)
    command = np.clip((target - eef_pos) / MAX_EEF_DELTA, -1.0, 1.0)
    command[np.isnan(action[:3])] = np.nan
    return command


def binary_gripper_state(command: float) -> np.ndarray:
    """The Panda gripper's stored two-finger command once a binary command has acted: fully open or closed."""
    return np.array([-1.0, 1.0]) * np.sign(command)
