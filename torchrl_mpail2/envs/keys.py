"""Which keys of an environment are task observations: the one rule that modules, demonstrations and the trainer use.

An observation is a flat float or uint8 leaf of the observation spec that is not declared as something else:
not a reward or done key of the env, not written by one of TorchRL's bookkeeping transforms (``StepCounter``,
``InitTracker``, ``RewardSum``, ``TrajCounter``, and the state a ``TensorDictPrimer`` carries for a module: read
from the transforms themselves, whatever their key names), and not the project's task flag ``"success"``. Given a bare spec instead of an env, the transforms'
default key names and the project's own stand in for the transforms.
"""
from __future__ import annotations

from collections.abc import Sequence

import torch
from torchrl.data import Composite
from torchrl.envs import EnvBase, InitTracker, RewardSum, StepCounter, TensorDictPrimer, TrajCounter, TransformedEnv

__all__ = ["EPISODE_RETURN_KEY", "TASK_FLAG_KEYS", "TASK_REWARD_KEY", "non_observation_keys", "observation_keys_of",
           "pictures_of", "with_bookkeeping"]

#: Flags the project's environments write beside observations (no TorchRL transform declares them).
TASK_FLAG_KEYS = ("success",)
#: The project's task reward (never ``"reward"``, so that the learner cannot read it by accident).
TASK_REWARD_KEY = "task_reward"
#: Where the project's ``RewardSum`` writes the episode's task return.
EPISODE_RETURN_KEY = "episode_task_return"
_DONE_KEYS = ("done", "terminated", "truncated")


def _declared_keys(transform) -> list:
    """Keys a TorchRL bookkeeping transform writes (step counts, init flags, summed rewards, trajectory ids)."""
    if isinstance(transform, StepCounter):
        return list(transform.step_count_keys)
    if isinstance(transform, InitTracker):
        return list(transform.init_keys)
    if isinstance(transform, (RewardSum, TrajCounter)):
        return list(transform.out_keys)
    if isinstance(transform, TensorDictPrimer):  # state carried for a module (e.g. the planner's warm start)
        return list(transform.primers.keys(True, True))
    return []


def non_observation_keys(source: EnvBase | Composite) -> set:
    """Keys of ``source`` (an env, or a bare observation spec) that are not task observations (see the module)."""
    keys = set(TASK_FLAG_KEYS)
    if not isinstance(source, EnvBase):
        return keys | {StepCounter().step_count_key, InitTracker().init_key, *RewardSum().out_keys,
                       *TrajCounter().out_keys, EPISODE_RETURN_KEY, TASK_REWARD_KEY, *_DONE_KEYS}
    keys |= set(source.reward_keys) | set(source.done_keys)
    env = source
    while isinstance(env, TransformedEnv):
        for transform in env.transform:
            keys.update(_declared_keys(transform))
        env = env.base_env
    return keys


def pictures_of(env: EnvBase) -> str | None:
    """How the env draws its picture observations (its base env's ``pictures``, e.g. ``"point_mass arena, glow
    0.6"``), or None for an env that declares nothing. Demonstrations record it and are refused by an env that draws
    otherwise, so that frames drawn before a change of the picture never mix with frames drawn after it."""
    while isinstance(env, TransformedEnv):
        env = env.base_env
    return getattr(env, "pictures", None)


def observation_keys_of(source: EnvBase | Composite, keys: Sequence[str] | None = None) -> list[str]:
    """The task observation keys of an env (or of a bare observation spec), or the given ``keys`` once checked.

    Examples:
        >>> from torchrl.envs import RewardSum
        >>> from torchrl_mpail2.envs import make_env
        >>> env = make_env("point_mass")
        >>> env.append_transform(RewardSum(in_keys=["task_reward"], out_keys=["episode_reward"]))  # doctest: +ELLIPSIS
        TransformedEnv(...)
        >>> "episode_reward" in env.observation_spec.keys(), observation_keys_of(env)
        (True, ['observation'])
    """
    spec = source.observation_spec if isinstance(source, EnvBase) else source
    if keys is not None:
        for key in keys:
            if key not in spec.keys(True, True):
                raise KeyError(f"observation key {key!r} not in the observation spec; spec keys: {list(spec.keys(True, True))}")
        return list(keys)
    excluded = non_observation_keys(source)
    return [key for key, leaf in spec.items(True, True)
            if isinstance(key, str) and key not in excluded and (leaf.dtype.is_floating_point or leaf.dtype == torch.uint8)]


def with_bookkeeping(env: EnvBase) -> TransformedEnv:
    """Appends ``StepCounter``, ``InitTracker`` and ``RewardSum`` where they are missing.

    Idempotent: a transform is skipped when its output key is already in the observation spec,
    so envs built by other factories that already carry them are not double-wrapped.
    ``StepCounter`` gets no ``max_steps``: truncation is the base env's job.

    Examples:
        >>> from torchrl_mpail2.envs.point_mass import PointMassEnv
        >>> env = with_bookkeeping(PointMassEnv(seed=0))
        >>> sorted(k for k in env.observation_spec.keys() if k != "observation")
        ['episode_task_return', 'is_init', 'step_count', 'success']
        >>> with_bookkeeping(env) is env
        True
    """
    present = set(env.observation_spec.keys())
    transforms = []
    if "step_count" not in present:
        transforms.append(StepCounter())
    if "is_init" not in present:
        transforms.append(InitTracker(init_key="is_init"))
    if EPISODE_RETURN_KEY not in present:
        transforms.append(RewardSum(in_keys=[TASK_REWARD_KEY], out_keys=[EPISODE_RETURN_KEY]))
    if not transforms:
        return env if isinstance(env, TransformedEnv) else TransformedEnv(env)
    if not isinstance(env, TransformedEnv):
        env = TransformedEnv(env)
    for transform in transforms:
        env.append_transform(transform)
    return env
