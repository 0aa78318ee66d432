"""Gymnasium MuJoCo locomotion tasks (Hopper, Ant, Humanoid) with the project's conventions.

These tasks have no notion of success: the ``"success"`` key is always ``False`` and exists only so
that every env of the project has the same keys. Judge them by ``"episode_task_return"``.
Terminations (the robot falls) are kept as ``"terminated"``; the 1000-step time limit is
``"truncated"``.
"""
from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.data import Categorical, Composite
from torchrl.envs import (
    ActionScaling,
    Compose,
    DoubleToFloat,
    GymEnv,
    RenameTransform,
    Transform,
    TransformedEnv,
)

from torchrl_mpail2.envs.keys import with_bookkeeping
from torchrl_mpail2.envs.names import GYM_TASKS

__all__ = ["ConstantSuccess", "make_gym_env"]



class ConstantSuccess(Transform):
    """Writes a boolean ``"success"`` ``[*B, 1]`` key that is always ``False``.

    For tasks without a success criterion, so that trainers and demo recorders can read the key
    everywhere without special cases.

    Args:
        key (str): key to write. Defaults to ``"success"``.
    """

    def __init__(self, key: str = "success") -> None:
        super().__init__(in_keys=[], out_keys=[key])
        self.key = key

    def _false(self, tensordict: TensorDictBase) -> torch.Tensor:
        device = tensordict.device if tensordict.device is not None else torch.device("cpu")
        return torch.zeros(*tensordict.batch_size, 1, dtype=torch.bool, device=device)

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        return next_tensordict.set(self.key, self._false(next_tensordict))

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        return tensordict_reset.set(self.key, self._false(tensordict_reset))

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        observation_spec[self.key] = Categorical(
            2, shape=(*observation_spec.shape, 1), dtype=torch.bool, device=observation_spec.device
        )
        return observation_spec


def make_gym_env(
    env_id: str, seed: int = 0, device: torch.device | str = "cpu", bookkeeping: bool = True
) -> TransformedEnv:
    """Builds a gymnasium MuJoCo task through torchrl's :class:`~torchrl.envs.GymEnv`.

    Transforms: float64 observations to float32 (``DoubleToFloat``), ``"reward"`` renamed to
    ``"task_reward"``, a constant-``False`` ``"success"`` key, actions rescaled from the env's
    bounds to ``[-1, 1]`` (Humanoid's are ``[-0.4, 0.4]``; a no-op for Hopper and Ant), then the
    bookkeeping transforms unless ``bookkeeping=False``.

    Args:
        env_id (str): one of ``"Hopper-v5"``, ``"Ant-v5"``, ``"Humanoid-v5"``.
        seed (int): env seed. Defaults to 0.
        device (torch.device or str): device of the env's tensors. Defaults to ``"cpu"``.
        bookkeeping (bool): append ``StepCounter``, ``InitTracker``, ``RewardSum``. Defaults to ``True``.

    Examples:
        >>> env = make_gym_env("Hopper-v5", seed=0)
        >>> env.observation_spec["observation"].dtype, env.reward_keys
        (torch.float32, ['task_reward'])
        >>> env.action_spec.space.high.tolist()
        [1.0, 1.0, 1.0]
    """
    if env_id not in GYM_TASKS:
        raise ValueError(f"Unknown gym env {env_id!r}. Valid ids: {', '.join(GYM_TASKS)}.")
    base = GymEnv(env_id, device=device)
    transforms = [
        DoubleToFloat(),
        RenameTransform(in_keys=["reward"], out_keys=["task_reward"]),
        ConstantSuccess(),
    ]
    space = base.action_spec.space
    if not (torch.all(space.low == -1) and torch.all(space.high == 1)):
        transforms.append(ActionScaling())
    env = TransformedEnv(base, Compose(*transforms))
    env.set_seed(seed)
    return with_bookkeeping(env) if bookkeeping else env
