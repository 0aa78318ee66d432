"""Scripted expert for :class:`~torchrl_mpail2.envs.point_mass.PointMassEnv`."""
from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase

__all__ = ["PointMassExpert"]


class PointMassExpert(TensorDictModuleBase):
    r"""Proportional-derivative controller that drives the point mass to the origin.

    ``a = clip(-position_gain * p - velocity_gain * v, -1, 1)``, read from ``"observation"`` =
    ``[x, y, vx, vy]`` (``[*B, 4]``) and written to ``"action"`` (``[*B, 2]``). Deterministic:
    the diversity of the demonstrations comes from the random start states.

    Args:
        position_gain (float): gain on the position. Defaults to 4.0.
        velocity_gain (float): gain on the velocity (damping). Defaults to 0.0: the env's own
            velocity inertia already damps the loop enough at this gain.

    Examples:
        >>> from torchrl_mpail2.envs.point_mass import PointMassEnv
        >>> env = PointMassEnv(batch_size=[8], seed=0)
        >>> rollout = env.rollout(50, policy=PointMassExpert())
        >>> rollout["next", "success"][:, -1].all().item()
        True
    """

    in_keys = ["observation"]
    out_keys = ["action"]

    def __init__(self, position_gain: float = 4.0, velocity_gain: float = 0.0) -> None:
        super().__init__()
        self.position_gain = float(position_gain)
        self.velocity_gain = float(velocity_gain)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        observation = tensordict.get("observation")
        position, velocity = observation[..., :2], observation[..., 2:4]
        action = -self.position_gain * position - self.velocity_gain * velocity
        tensordict.set("action", action.clamp(-1.0, 1.0))
        return tensordict
