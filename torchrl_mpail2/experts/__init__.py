"""Experts that generate demonstrations, one per env name, found through :func:`get_expert`."""
from __future__ import annotations

from torchrl.envs import EnvBase

from torchrl_mpail2.envs.names import ROBOSUITE_ENV_NAMES
from torchrl_mpail2.experts.point_mass import PointMassExpert

__all__ = ["PointMassExpert", "get_expert"]


def get_expert(env_name: str, env: EnvBase, **expert_kwargs):
    """Returns the expert policy for an env built by :func:`~torchrl_mpail2.envs.make_env`.

    The expert is a callable that reads a tensordict and writes ``"action"``. If it has a
    ``reset()`` method, the demo recorder calls it before each episode.

    Args:
        env_name (str): the name given to ``make_env`` (``"point_mass"``, ``"robosuite/Lift"``, ...).
        env (EnvBase): the env the expert will act in (scripted robosuite experts read its specs).

    Keyword Args:
        **expert_kwargs: passed to a scripted robosuite expert (e.g. ``max_lift_speed`` of
            :class:`~torchrl_mpail2.experts.scripted.LiftExpert`); other experts take none.

    Raises:
        FileNotFoundError: for a gym task whose expert weights are not in ``torchrl_mpail2/assets/experts``.
        ValueError: for an unknown env name.

    Examples:
        >>> from torchrl_mpail2.envs import make_env
        >>> expert = get_expert("point_mass", make_env("point_mass"))
        >>> type(expert).__name__
        'PointMassExpert'
    """
    is_scripted = env_name in ROBOSUITE_ENV_NAMES
    if expert_kwargs and not is_scripted:
        raise ValueError(f"The expert of {env_name!r} takes no options, got {sorted(expert_kwargs)}.")
    if env_name == "point_mass":
        return PointMassExpert()
    if is_scripted:
        # Lazy: scripted experts pull in robosuite.
        from torchrl_mpail2.experts import scripted

        expert_cls = scripted.LiftExpert if env_name == "robosuite/Lift" else scripted.PushExpert
        return expert_cls(env, **expert_kwargs)
    if env_name.startswith("gym/"):
        from torchrl_mpail2.experts.gym import ASSET_DIR, GymExpert

        # committed weights of the expert (FileNotFoundError with the training command if absent)
        return GymExpert(ASSET_DIR / f"{env_name.removeprefix('gym/')}.pt", env.action_spec)
    raise ValueError(f"No expert for env {env_name!r}.")
