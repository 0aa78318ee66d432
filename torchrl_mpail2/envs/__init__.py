"""Environments of the project, built through :func:`make_env`.

``make_robosuite_env`` is re-exported lazily: robosuite is optional and slow to import.
"""
from torchrl_mpail2.envs.factory import make_env
from torchrl_mpail2.envs.keys import with_bookkeeping
from torchrl_mpail2.envs.names import ENV_NAMES
from torchrl_mpail2.envs.gym_env import make_gym_env
from torchrl_mpail2.envs.point_mass import PointMassEnv

__all__ = ["ENV_NAMES", "PointMassEnv", "make_env", "make_gym_env", "make_robosuite_env", "with_bookkeeping"]


def __getattr__(name: str):
    if name == "make_robosuite_env":
        from torchrl_mpail2.envs.robosuite_env import make_robosuite_env

        return make_robosuite_env
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
