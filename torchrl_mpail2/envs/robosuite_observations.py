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

__all__ = ["EXTERNAL_CAMERA", "IMAGE_SIZE", "OBJECT_EEF_TO_CUBE", "PROPRIO_DIM", "WRIST_CAMERA", "object_vector",
           "proprio_vector", "upright_chw"]

#: Side of the camera observations, pixels.
IMAGE_SIZE = 64
EXTERNAL_CAMERA = "agentview"
WRIST_CAMERA = "robot0_eye_in_hand"
#: Width of ``"proprio"`` without the gripper command.
PROPRIO_DIM = 26
#: Where ``"object"`` holds the end effector's position minus the cube's (Lift and Push).
OBJECT_EEF_TO_CUBE = slice(7, 10)


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
