"""What a robosuite env observes, assembled from the simulator's observations (no robosuite import here).

Observation keys (flat, float32 unless stated):

* ``"proprio"`` ``[26]``: end-effector position (3), finger joint positions (2), sin (7) and cos (7) of
  the arm joint angles, arm joint velocities (7); ``[27]`` with ``observe_gripper_command``, which appends the
  gripper controller's current command in ``[-1, 1]`` (the paper's "gripper trigger"; robosuite does not observe it).
* ``"object"`` ``[10]`` (Lift) / ``[11]`` (Push): cube position (3), cube quaternion xyzw (4),
  end-effector minus cube position (3); Push adds the distance the cube still has to travel past the line (1).
* ``"external_image"`` / ``"wrist_image"``: uint8 ``[3, 64, 64]`` from robosuite's ``agentview`` and
  ``robot0_eye_in_hand`` cameras, flipped upright (robosuite renders in the OpenGL convention, bottom row first).

Modes: ``"state"`` = proprio + object; ``"pixels"`` = proprio + both images; ``"external_pixels"`` = external
image only. No renderer is created in state mode.
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np

__all__ = ["BLACK_FRACTION", "EXTERNAL_CAMERA", "IMAGE_SIZE", "NOISE_ROUGHNESS", "OBJECT_EEF_TO_CUBE", "PROPRIO_DIM",
           "WRIST_CAMERA", "object_vector", "proprio_vector", "unrendered", "upright_chw"]

#: Side of the camera observations, pixels.
IMAGE_SIZE = 64
EXTERNAL_CAMERA = "agentview"
WRIST_CAMERA = "robot0_eye_in_hand"
#: Width of ``"proprio"`` without the gripper command.
PROPRIO_DIM = 26
#: Where ``"object"`` holds the end effector's position minus the cube's (Lift and Push).
OBJECT_EEF_TO_CUBE = slice(7, 10)
#: A frame rougher than this (:func:`unrendered`) is noise: rendered 64 x 64 Lift and Push frames measured at most
#: about 12, uniform noise about 85.
NOISE_ROUGHNESS = 30.0
#: A frame with more than this fraction of black pixels is no render of these scenes (rendered frames: at most 0.002).
BLACK_FRACTION = 0.5


def proprio_vector(sim_obs: Mapping[str, np.ndarray], gripper_command: float | None = None) -> np.ndarray:
    """``"proprio"`` from robosuite's observation dict, with the gripper command appended where given."""
    return np.concatenate([
        sim_obs["robot0_eef_pos"], sim_obs["robot0_gripper_qpos"], sim_obs["robot0_joint_pos_sin"],
        sim_obs["robot0_joint_pos_cos"], sim_obs["robot0_joint_vel"],
        [] if gripper_command is None else [gripper_command],
    ]).astype(np.float32)


def object_vector(state: Mapping[str, np.ndarray], distance_to_line: float | None = None) -> np.ndarray:
    """``"object"`` from the privileged state (``cube_pos``, ``cube_quat``, ``eef_pos``), with Push's distance to
    the line appended where given."""
    parts = [state["cube_pos"], state["cube_quat"], state["eef_pos"] - state["cube_pos"]]
    if distance_to_line is not None:
        parts.append([distance_to_line])
    return np.concatenate(parts).astype(np.float32)


def upright_chw(image: np.ndarray) -> np.ndarray:
    """A robosuite ``[H, W, 3]`` frame (bottom row first) as an upright ``[3, H, W]`` array."""
    return np.ascontiguousarray(image[::-1].transpose(2, 0, 1))


def unrendered(frames: np.ndarray) -> np.ndarray:
    r"""``[..., 3, H, W]`` uint8 frames -> ``[...]`` bool: frames that cannot be a render of these scenes, but what a
    failed GL read leaves in the buffer: noise, or mostly black. The roughness of a frame ``I`` is the mean absolute
    difference of horizontally adjacent pixels,
    :math:`\rho = \frac{1}{3 H (W - 1)} \sum_{c, y, x} |I_{c, y, x + 1} - I_{c, y, x}|`; a frame is flagged when
    :math:`\rho >` :data:`NOISE_ROUGHNESS` or more than :data:`BLACK_FRACTION` of its pixels are black. A stale frame
    (an old render left in the buffer) passes.

    Examples:
        >>> smooth = np.broadcast_to(np.linspace(60, 250, 64).astype(np.uint8), (3, 64, 64))
        >>> noise = np.random.default_rng(0).integers(0, 256, (3, 64, 64), dtype=np.uint8)
        >>> unrendered(np.stack([smooth, noise, np.zeros_like(noise)])).tolist()
        [False, True, True]
    """
    x = np.asarray(frames)
    roughness = np.abs(np.diff(x.astype(np.int16), axis=-1)).mean(axis=(-3, -2, -1))
    black = (x == 0).all(axis=-3).mean(axis=(-2, -1))
    return (roughness > NOISE_ROUGHNESS) | (black > BLACK_FRACTION)
