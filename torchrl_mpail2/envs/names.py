"""The names of the project's environments: the one list that the env factory, the robosuite and gym wrappers,
the experts and the benchmarks read."""
from __future__ import annotations

__all__ = ["ENV_NAMES", "GYM_TASKS", "OBS_MODES", "POINT_MASS", "ROBOSUITE_ENV_NAMES", "ROBOSUITE_TASKS"]

POINT_MASS = "point_mass"
#: robosuite tasks with a scripted expert (Panda arm).
ROBOSUITE_TASKS = ("Lift", "Push", "PushMirrored")
#: gymnasium MuJoCo tasks with a committed SAC expert.
GYM_TASKS = ("Hopper-v5", "Ant-v5", "Humanoid-v5")
ROBOSUITE_ENV_NAMES = tuple(f"robosuite/{task}" for task in ROBOSUITE_TASKS)
#: Every name :func:`torchrl_mpail2.envs.make_env` accepts.
ENV_NAMES = (POINT_MASS, *ROBOSUITE_ENV_NAMES, *(f"gym/{task}" for task in GYM_TASKS))
#: Observation modes: ``state`` everywhere; robosuite also ``pixels`` (both 64 x 64 cameras + proprioception) and
#: ``external_pixels`` (the external camera + proprioception).
OBS_MODES = ("state", "pixels", "external_pixels")
