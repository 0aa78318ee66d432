"""Scripted expert for :class:`~torchrl_mpail2.envs.point_mass.PointMassEnv`."""
from __future__ import annotations

from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase

from torchrl_mpail2.envs.point_mass import IMAGE_KEY, locate_point

__all__ = ["PointMassExpert"]


class PointMassExpert(TensorDictModuleBase):
    r"""Proportional-derivative controller that drives the point mass to the origin.

    ``a = clip(-position_gain * p - velocity_gain * v, -1, 1)``, read from ``"observation"`` =
    ``[x, y, vx, vy]`` (``[*B, 4]``) and written to ``"action"`` (``[*B, 2]``). Deterministic:
    the diversity of the demonstrations comes from the random start states.

    In the pixel mode (no ``"observation"``, a picture ``"external_image"`` ``[*B, 3, 64, 64]``) it reads the
    position off the picture (:func:`~torchrl_mpail2.envs.point_mass.locate_point`, within 0.006 of the true one
    away from the box's edge), as a person demonstrating from a camera would, instead of a privileged state: the
    expert stays a plain policy that :func:`~torchrl_mpail2.experts.get_expert` builds without the env. A picture
    shows no velocity, so there ``velocity_gain`` must be 0.

    Args:
        position_gain (float): gain on the position. Defaults to 4.0.
        velocity_gain (float): gain on the velocity (damping). Defaults to 0.0: the env's own
            velocity inertia already damps the loop enough at this gain.

    Raises:
        KeyError: from :meth:`forward` when the input holds neither key.
        ValueError: from :meth:`forward` on a picture with ``velocity_gain != 0``.

    Examples:
        >>> from torchrl_mpail2.envs.point_mass import PointMassEnv
        >>> env = PointMassEnv(batch_size=[8], seed=0)
        >>> rollout = env.rollout(50, policy=PointMassExpert())
        >>> rollout["next", "success"][:, -1].all().item()
        True
        >>> rollout = PointMassEnv(batch_size=[8], seed=0, obs="pixels").rollout(50, policy=PointMassExpert())
        >>> rollout["next", "success"][:, -1].all().item()
        True
    """

    in_keys = []  # "observation", or the picture where the env has no state observation
    out_keys = ["action"]

    def __init__(self, position_gain: float = 4.0, velocity_gain: float = 0.0) -> None:
        super().__init__()
        self.position_gain = float(position_gain)
        self.velocity_gain = float(velocity_gain)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        observation = tensordict.get("observation", None)
        if observation is not None:
            position, velocity = observation[..., :2], observation[..., 2:4]
            action = -self.position_gain * position - self.velocity_gain * velocity
        elif IMAGE_KEY in tensordict.keys():
            if self.velocity_gain:
                raise ValueError(f"PointMassExpert reads {IMAGE_KEY!r}, a picture without velocity: velocity_gain "
                                 f"must be 0, got {self.velocity_gain}.")
            action = -self.position_gain * locate_point(tensordict.get(IMAGE_KEY))
        else:
            raise KeyError(f"PointMassExpert reads 'observation' [*B, 4] or {IMAGE_KEY!r} [*B, 3, 64, 64]; present: "
                           f"{sorted(tensordict.keys())}")
        tensordict.set("action", action.clamp(-1.0, 1.0))
        return tensordict
