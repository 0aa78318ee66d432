r"""A tiny 2-D point-mass reaching task, pure torch and batched.

The task exists to test the whole MPAIL2 pipeline in seconds: its dynamics are nearly linear, an
expert is three lines, and a random policy almost never succeeds, so a learning curve that rises
means the learner works.

Dynamics (one step, ``dt`` folded into the constants)::

    v' = 0.5 v + 0.5 a            # the action sets the velocity, with some inertia
    p' = clip(p + 0.1 v', -1.5, 1.5)

The goal is the origin. Observations are ``[x, y, vx, vy]`` under the key ``"observation"``.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

__all__ = ["PointMassEnv"]

#: Fraction of the previous velocity kept at each step (the "inertia").
VELOCITY_RETENTION = 0.5
#: Displacement per unit of velocity per step.
POSITION_GAIN = 0.1
#: Positions are clipped to this box so that random policies cannot drift away forever.
POSITION_LIMIT = 1.5
#: Starting positions are drawn uniformly (in area) on the ring START_RADIUS_MIN <= |p| <= START_RADIUS_MAX.
START_RADIUS_MIN = 0.8
START_RADIUS_MAX = 1.0
#: The point reaches the goal when its distance to the origin is below this.
SUCCESS_RADIUS = 0.1
OBSERVATION_DIM = 4
ACTION_DIM = 2


class PointMassEnv(EnvBase):
    r"""Reach the origin with a 2-D point mass.

    Keys: ``"observation"`` ``[*B, 4]`` float32 (position then velocity), ``"success"`` ``[*B, 1]``
    bool (distance to the goal below 0.1 at the current step, written after reset and every step),
    ``"task_reward"`` ``[*B, 1]`` (minus the distance to the goal; for logging only, the learner
    must not see it), ``"done"``/``"terminated"``/``"truncated"`` ``[*B, 1]``. Actions are
    ``Bounded(-1, 1)`` ``[*B, 2]``. Episodes end by truncation after ``horizon`` steps and never
    terminate.

    The simulator state lives on the environment (like a physics engine), so ``step`` ignores an
    ``"observation"`` written into its input. Partial resets through ``"_reset"`` are supported.
    Random starts come from a CPU :class:`torch.Generator` whatever the device, so a seed gives the
    same episodes on CPU and GPU.

    Args:
        batch_size (sequence of int): number of independent point masses, e.g. ``()`` or ``(4,)``.
            Defaults to ``()``.
        device (torch.device or str): where tensors live. Defaults to ``"cpu"``.
        seed (int, optional): seed of the start-state generator. If ``None``, it is drawn from the
            global torch RNG so that :func:`torch.manual_seed` controls it.
        horizon (int): episode length (truncation). Defaults to 50.

    Examples:
        >>> env = PointMassEnv(batch_size=[3], seed=0)
        >>> td = env.reset()
        >>> td["observation"].shape, td["success"].any().item()
        (torch.Size([3, 4]), False)
        >>> rollout = env.rollout(100)  # random actions; stops at the 50-step truncation
        >>> rollout.shape, rollout["next", "truncated"][:, -1].all().item()
        (torch.Size([3, 50]), True)
    """

    def __init__(
        self,
        batch_size: Sequence[int] = (),
        device: torch.device | str = "cpu",
        seed: int | None = None,
        horizon: int = 50,
    ) -> None:
        super().__init__(device=device, batch_size=torch.Size(batch_size))
        if horizon < 1:
            raise ValueError(f"horizon must be >= 1, got {horizon}.")
        self.horizon = int(horizon)
        self._make_specs()
        batch = self.batch_size
        self._position = torch.zeros(*batch, 2, device=self.device)
        self._velocity = torch.zeros(*batch, 2, device=self.device)
        self._elapsed = torch.zeros(batch, dtype=torch.long, device=self.device)
        self._generator = torch.Generator(device="cpu")
        if seed is None:
            seed = int(torch.randint(0, 2**62, ()).item())
        self.set_seed(seed)

    def render(self, size: int = 128) -> np.ndarray:
        """An RGB frame ``[size, size, 3]`` uint8 of the arena (batch size ``[]`` only): the goal disc in green,
        the point in blue."""
        if self.batch_size:
            raise ValueError(f"PointMassEnv.render draws one point mass; this env has batch size {list(self.batch_size)}")
        grid = (np.arange(size) + 0.5) / size * 2 * POSITION_LIMIT - POSITION_LIMIT  # pixel centres in env units
        x, y = np.meshgrid(grid, -grid)  # image rows go down, y goes up
        frame = np.full((size, size, 3), 255, dtype=np.uint8)
        frame[x**2 + y**2 <= SUCCESS_RADIUS**2] = (120, 200, 120)
        px, py = self._position.cpu().double().numpy()
        frame[(x - px) ** 2 + (y - py) ** 2 <= (2.5 * POSITION_LIMIT / size * 2) ** 2] = (40, 60, 220)
        return frame

    def _make_specs(self) -> None:
        batch = self.batch_size
        flag = lambda: Categorical(2, shape=(*batch, 1), dtype=torch.bool, device=self.device)  # noqa: E731
        self.observation_spec = Composite(
            observation=Unbounded(shape=(*batch, OBSERVATION_DIM), dtype=torch.float32, device=self.device),
            success=flag(),
            shape=batch,
            device=self.device,
        )
        self.action_spec = Bounded(-1.0, 1.0, shape=(*batch, ACTION_DIM), dtype=torch.float32, device=self.device)
        self.reward_spec = Composite(
            task_reward=Unbounded(shape=(*batch, 1), dtype=torch.float32, device=self.device),
            shape=batch,
            device=self.device,
        )
        self.done_spec = Composite(
            done=flag(), terminated=flag(), truncated=flag(), shape=batch, device=self.device
        )

    def _set_seed(self, seed: int | None) -> None:
        if seed is None:
            seed = int(torch.randint(0, 2**62, ()).item())
        self._generator.manual_seed(int(seed))

    def _sample_start(self) -> torch.Tensor:
        # Draw for the whole batch even on partial resets so that the random stream does not
        # depend on which envs were reset; sqrt of a uniform radius^2 makes the ring uniform in area.
        shape = self.batch_size
        u_radius = torch.rand(shape, generator=self._generator)
        u_angle = torch.rand(shape, generator=self._generator)
        radius = torch.sqrt(START_RADIUS_MIN**2 + u_radius * (START_RADIUS_MAX**2 - START_RADIUS_MIN**2))
        angle = 2 * math.pi * u_angle
        start = torch.stack([radius * torch.cos(angle), radius * torch.sin(angle)], dim=-1)
        return start.to(self.device)

    def _observation(self) -> TensorDict:
        distance = self._position.norm(dim=-1, keepdim=True)
        return TensorDict(
            {
                "observation": torch.cat([self._position, self._velocity], dim=-1),
                "success": distance < SUCCESS_RADIUS,
            },
            batch_size=self.batch_size,
            device=self.device,
        )

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        reset_mask = None if tensordict is None else tensordict.get("_reset", None)
        start = self._sample_start()
        if reset_mask is None:
            self._position = start
            self._velocity = torch.zeros_like(self._velocity)
            self._elapsed = torch.zeros_like(self._elapsed)
        else:
            mask = reset_mask.reshape(self.batch_size).to(self.device)
            self._position = torch.where(mask.unsqueeze(-1), start, self._position)
            self._velocity = torch.where(mask.unsqueeze(-1), torch.zeros_like(self._velocity), self._velocity)
            self._elapsed = torch.where(mask, torch.zeros_like(self._elapsed), self._elapsed)
        out = self._observation()
        not_done = torch.zeros(*self.batch_size, 1, dtype=torch.bool, device=self.device)
        out.update({"done": not_done, "terminated": not_done.clone(), "truncated": not_done.clone()})
        return out

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = tensordict.get("action").to(self.device, torch.float32).clamp(-1.0, 1.0)
        self._velocity = VELOCITY_RETENTION * self._velocity + (1.0 - VELOCITY_RETENTION) * action
        self._position = (self._position + POSITION_GAIN * self._velocity).clamp(-POSITION_LIMIT, POSITION_LIMIT)
        self._elapsed = self._elapsed + 1
        out = self._observation()
        truncated = (self._elapsed >= self.horizon).unsqueeze(-1)
        out.update(
            {
                "task_reward": -self._position.norm(dim=-1, keepdim=True),
                "done": truncated,
                "terminated": torch.zeros_like(truncated),
                "truncated": truncated.clone(),
            }
        )
        return out
