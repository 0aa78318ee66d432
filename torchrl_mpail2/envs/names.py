"""The names of the project's environments: the one list that the env factory, the robosuite and gym wrappers,
the experts and the benchmarks read."""
from __future__ import annotations

__all__ = ["ENV_NAMES", "FAMILY_OBS_MODES", "GYM_TASKS", "OBS_MODES", "POINT_MASS", "ROBOSUITE_ENV_NAMES",
           "ROBOSUITE_TASKS", "obs_modes_of"]

POINT_MASS = "point_mass"
#: robosuite tasks with a scripted expert (Panda arm).
ROBOSUITE_TASKS = ("Lift", "Push", "PushMirrored")
#: gymnasium MuJoCo tasks with a committed expert (SAC or PPO).
GYM_TASKS = ("Hopper-v5", "Ant-v5", "Humanoid-v5")
ROBOSUITE_ENV_NAMES = tuple(f"robosuite/{task}" for task in ROBOSUITE_TASKS)
#: Every name :func:`torchrl_mpail2.envs.make_env` accepts.
ENV_NAMES = (POINT_MASS, *ROBOSUITE_ENV_NAMES, *(f"gym/{task}" for task in GYM_TASKS))
#: Observation modes of each env family (the part of an env name before ``/``): ``state`` everywhere; the point
#: mass also ``pixels`` (a 64 x 64 picture of the arena) and ``pixels_state`` (the picture and the state vector, as
#: robosuite's cameras come with proprioception); robosuite also ``pixels`` (both 64 x 64 cameras + proprioception)
#: and ``external_pixels`` (the external camera alone).
FAMILY_OBS_MODES = {
    POINT_MASS: ("state", "pixels", "pixels_state"),
    "robosuite": ("state", "pixels", "external_pixels"),
    "gym": ("state",),
}
#: Every observation mode of some family, in order of first appearance.
OBS_MODES = tuple(dict.fromkeys(mode for modes in FAMILY_OBS_MODES.values() for mode in modes))


def obs_modes_of(env_name: str) -> tuple[str, ...]:
    """The observation modes an env accepts, from its name (``()`` for a family this project does not know).

    Examples:
        >>> obs_modes_of("point_mass"), obs_modes_of("gym/Hopper-v5")
        (('state', 'pixels', 'pixels_state'), ('state',))
    """
    return FAMILY_OBS_MODES.get(env_name.partition("/")[0], ())
