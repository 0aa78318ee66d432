"""One entry point, :func:`make_env`, for every environment of the project.

All envs share the conventions the learner relies on: float32 vector observations under flat keys,
``Bounded(-1, 1)`` float32 actions, a boolean ``"success"`` ``[1]`` key, the task reward under
``"task_reward"`` (never ``"reward"``, so that the learner cannot see it by accident),
``"done"``/``"terminated"``/``"truncated"``, and the bookkeeping transforms ``StepCounter``,
``InitTracker`` (``"is_init"``) and ``RewardSum`` (``"task_reward"`` -> ``"episode_task_return"``).
"""
from __future__ import annotations

from functools import partial

import torch
from torchrl.envs import SerialEnv, TransformedEnv

from torchrl_mpail2.envs.keys import with_bookkeeping
from torchrl_mpail2.envs.names import ENV_NAMES, POINT_MASS, obs_modes_of
from torchrl_mpail2.envs.point_mass import PointMassEnv

__all__ = ["ENV_NAMES", "make_env", "with_bookkeeping"]

def make_env(
    name: str,
    obs: str = "state",
    seed: int = 0,
    num_envs: int | None = None,
    device: torch.device | str = "cpu",
    **kwargs,
) -> TransformedEnv:
    """Builds a project environment by name, with the bookkeeping transforms.

    Args:
        name (str): one of :data:`ENV_NAMES`: ``"point_mass"``, ``"robosuite/Lift"``,
            ``"robosuite/Push"``, ``"robosuite/PushMirrored"``, ``"gym/Hopper-v5"``,
            ``"gym/Ant-v5"``, ``"gym/Humanoid-v5"``.
        obs (str): observation mode, one of ``obs_modes_of(name)`` (:mod:`~torchrl_mpail2.envs.names`):
            ``"state"`` everywhere; ``"pixels"`` for the point mass (a 64 x 64 picture) and robosuite;
            ``"external_pixels"`` for robosuite. Defaults to ``"state"``.
        seed (int): seed of the env (of the first sub-env when ``num_envs`` is given).
        num_envs (int, optional): if given, a batch of ``num_envs`` envs with ``batch_size=[num_envs]``
            (one batched :class:`PointMassEnv`; a :class:`~torchrl.envs.SerialEnv` otherwise, since
            the project runs on few cores). If ``None``, a single env with an empty batch size.
        device (torch.device or str): device of the env's tensors.
        **kwargs: forwarded to the underlying constructor (e.g. ``horizon`` for point_mass and robosuite).

    Returns:
        TransformedEnv: the environment.

    Raises:
        ValueError: for an unknown name or an observation mode the env does not have (the message lists
            the valid ones).

    Examples:
        >>> env = make_env("point_mass", seed=0, num_envs=2)
        >>> env.batch_size, env.reward_keys
        (torch.Size([2]), ['task_reward'])
        >>> make_env("cartpole")  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        ValueError: Unknown env 'cartpole'. Valid names: point_mass, robosuite/Lift, ..., gym/Humanoid-v5.
        >>> make_env("point_mass", obs="pixels").observation_spec["external_image"].shape
        torch.Size([3, 64, 64])
        >>> make_env("gym/Hopper-v5", obs="pixels")
        Traceback (most recent call last):
        ...
        ValueError: 'gym/Hopper-v5' has no observation mode 'pixels'; its modes: state.
    """
    if name not in ENV_NAMES:
        raise ValueError(f"Unknown env {name!r}. Valid names: {', '.join(ENV_NAMES)}.")
    family, _, task = name.partition("/")
    if obs not in obs_modes_of(name):
        raise ValueError(f"{name!r} has no observation mode {obs!r}; its modes: {', '.join(obs_modes_of(name))}.")
    if num_envs is not None and num_envs < 1:
        raise ValueError(f"num_envs must be a positive integer or None, got {num_envs}.")

    if family == POINT_MASS:
        batch_size = () if num_envs is None else (num_envs,)
        return with_bookkeeping(PointMassEnv(batch_size=batch_size, device=device, seed=seed, obs=obs, **kwargs))

    if family == "robosuite":
        # Imported lazily: robosuite is an optional dependency and slow to import.
        from torchrl_mpail2.envs.robosuite_env import make_robosuite_env

        make_one = partial(make_robosuite_env, task, obs=obs, device=device, **kwargs)
    else:
        from torchrl_mpail2.envs.gym_env import make_gym_env

        make_one = partial(make_gym_env, task, device=device, **kwargs)

    if num_envs is None:
        return with_bookkeeping(make_one(seed=seed))
    # Sub-envs are seeded by SerialEnv.set_seed (seed, then derived seeds), so they differ.
    batched = SerialEnv(num_envs, partial(make_one, seed=seed), device=device)
    batched.set_seed(seed)
    return with_bookkeeping(batched)
