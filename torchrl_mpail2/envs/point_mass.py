r"""A tiny 2-D point-mass reaching task, pure torch and batched.

The task exists to test the whole MPAIL2 pipeline in seconds: its dynamics are nearly linear, an
expert is three lines, and a random policy almost never succeeds, so a learning curve that rises
means the learner works.

Dynamics (one step, ``dt`` folded into the constants)::

    v' = 0.5 v + 0.5 a            # the action sets the velocity, with some inertia
    p' = clip(p + 0.1 v', -1.5, 1.5)

The goal is the origin. Observations (``obs``) are ``[x, y, vx, vy]`` under the key ``"observation"``
(``"state"``, the default) or a 64 x 64 RGB picture of the arena under ``"external_image"`` (``"pixels"``): a
fast image task for tests. The picture is drawn with torch alone (:func:`draw_arena`, also behind
:meth:`PointMassEnv.render`): a white arena spanning the position box, the goal disc in green, the point in
blue, both anti-aliased so that a sub-pixel move changes the picture.
"""
from __future__ import annotations

import functools
import math
from typing import Sequence

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from torchrl_mpail2.envs.names import POINT_MASS, obs_modes_of

__all__ = ["IMAGE_KEY", "IMAGE_SIZE", "PointMassEnv", "draw_arena", "locate_point"]

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
#: Side of the pixel observation (the encoder's CNN takes 64 x 64).
IMAGE_SIZE = 64
#: Key of the pixel observation: robosuite's external camera's, so that image settings read the same key.
IMAGE_KEY = "external_image"
#: Colours (RGB) of the pictures.
BACKGROUND_RGB, GOAL_RGB, POINT_RGB = (255, 255, 255), (120, 200, 120), (40, 60, 220)
#: Radius of the drawn point in pixels, whatever the picture's size (0.12 position units at 64 x 64).
POINT_RADIUS_PIXELS = 2.5
#: The glow around the point: a Gaussian of this std (position units) in the green channel alone, darkening it by
#: up to ``GLOW_PEAK`` of the way to ``GLOW_GREEN``. Without it, pictures of any two positions more than a point's
#: width apart differ equally, whatever the distance; with it they differ more the farther apart the positions are
#: (see ``point_mass_pixels``). Red and blue are left to the point, so :func:`locate_point` reads it exactly.
GLOW_SIGMA, GLOW_PEAK, GLOW_GREEN = 0.6, 0.6, 100.0


@functools.lru_cache(maxsize=8)
def _empty_arena(size: int, device: torch.device) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Pixel-centre coordinates ``x``, ``y`` ``[S, S]`` in position units and the arena without the point
    ``[3, S, S]`` (float, whole colour values), for a ``size`` x ``size`` picture; cached per size and device."""
    pixel = 2 * POSITION_LIMIT / size
    centres = (torch.arange(size, dtype=torch.float32, device=device) + 0.5) * pixel - POSITION_LIMIT
    x, y = centres.expand(size, size), -centres.unsqueeze(-1).expand(size, size)  # image rows go down, y goes up
    background, goal = (torch.tensor(rgb, dtype=torch.float32, device=device).view(3, 1, 1)
                        for rgb in (BACKGROUND_RGB, GOAL_RGB))
    empty = torch.lerp(background, goal, _coverage(torch.hypot(x, y), SUCCESS_RADIUS, pixel)).round()
    return x, y, empty


def _coverage(distance: torch.Tensor, radius: float, pixel: float) -> torch.Tensor:
    """Share of each pixel inside a disc (a linear ramp one pixel wide across the rim: anti-aliasing)."""
    return ((radius - distance) / pixel + 0.5).clamp(0.0, 1.0)


def draw_arena(position: torch.Tensor, size: int = IMAGE_SIZE, glow: float = GLOW_SIGMA) -> torch.Tensor:
    """Pictures of the arena with the point at ``position``: the pixel observation and the video frames.

    The picture spans the position box ``[-1.5, 1.5]^2`` (x to the right, y up); the goal disc (radius
    ``SUCCESS_RADIUS``) is green, the point (radius ``POINT_RADIUS_PIXELS``) blue over it, on white, with a soft
    glow around the point in the green channel (:data:`GLOW_SIGMA`).

    Args:
        position (Tensor): ``[*B, 2]`` positions ``(x, y)``.
        size (int): side ``S`` of the pictures in pixels. Defaults to 64.
        glow (float): std of the glow in position units; 0 draws none. Defaults to :data:`GLOW_SIGMA`.

    Returns:
        Tensor: ``[*B, 3, S, S]`` uint8 RGB pictures, on ``position``'s device.

    Examples:
        >>> frames = draw_arena(torch.tensor([[0.0, 0.0], [1.0, -1.0]]))
        >>> frames.shape, frames.dtype
        (torch.Size([2, 3, 64, 64]), torch.uint8)
        >>> frames[1, :, 53, 53].tolist()  # the pixel at (1.0, -1.0) is the point's blue
        [40, 60, 220]
    """
    if glow < 0:
        raise ValueError(f"draw_arena: glow must be >= 0 (0 draws none), got {glow}")
    x, y, empty = _empty_arena(int(size), position.device)
    pixel = 2 * POSITION_LIMIT / size
    px, py = position[..., 0, None, None].float(), position[..., 1, None, None].float()
    distance = torch.hypot(x - px, y - py)
    inside = _coverage(distance, POINT_RADIUS_PIXELS * pixel, pixel)
    if glow > 0:  # the green channel moves towards GLOW_GREEN by the shade; red and blue stay
        shade = GLOW_PEAK * torch.exp(-0.5 * (distance / glow) ** 2)
        green_only = torch.tensor([0.0, 1.0, 0.0], device=position.device).view(3, 1, 1)
        empty = empty + green_only * (shade * (GLOW_GREEN - empty[1])).unsqueeze(-3)
    point = torch.tensor(POINT_RGB, dtype=torch.float32, device=position.device).view(3, 1, 1)
    return torch.lerp(empty, point, inside.unsqueeze(-3)).round().to(torch.uint8)


def locate_point(image: torch.Tensor) -> torch.Tensor:
    """Where the point is in pictures of :func:`draw_arena`: the centroid of its coverage, in position units.

    Each pixel's share of the point is read back from its red channel (the arena without the point is known there:
    the glow leaves red alone), so the estimate follows sub-pixel moves: within 0.006 position units (an eighth of a pixel at 64 x 64) while the whole
    point is in the picture (``|x|, |y| < 1.38``), within 0.06 when the frame cuts it at the box's edge.

    Args:
        image (Tensor): ``[*B, 3, S, S]`` uint8 pictures.

    Returns:
        Tensor: ``[*B, 2]`` float32 positions ``(x, y)``.

    Examples:
        >>> position = torch.tensor([0.3, -0.71])
        >>> torch.allclose(locate_point(draw_arena(position)), position, atol=0.01)
        True
    """
    x, y, empty = _empty_arena(image.shape[-1], image.device)
    red = empty[0]
    share = ((image[..., 0, :, :].float() - red) / (POINT_RGB[0] - red)).clamp(0.0, 1.0)
    total = share.sum((-2, -1)).clamp_min(1e-6)
    return torch.stack([(share * x).sum((-2, -1)) / total, (share * y).sum((-2, -1)) / total], dim=-1)


class PointMassEnv(EnvBase):
    r"""Reach the origin with a 2-D point mass.

    Keys: ``"observation"`` ``[*B, 4]`` float32 (position then velocity) with ``obs="state"``, or
    ``"external_image"`` ``[*B, 3, 64, 64]`` uint8 (:func:`draw_arena`) with ``obs="pixels"``; ``"success"`` ``[*B, 1]``
    bool (distance to the goal below 0.1 at the current step, written after reset and every step),
    ``"task_reward"`` ``[*B, 1]`` (minus the distance to the goal; for logging only, the learner
    must not see it), ``"done"``/``"terminated"``/``"truncated"`` ``[*B, 1]``. Actions are
    ``Bounded(-1, 1)`` ``[*B, 2]``. Episodes end by truncation after ``horizon`` steps and never
    terminate.

    The simulator state lives on the environment (like a physics engine), so ``step`` ignores an
    observation written into its input. Partial resets through ``"_reset"`` are supported.
    Random starts come from a CPU :class:`torch.Generator` whatever the device, so a seed gives the
    same episodes on CPU and GPU.

    The picture shows where the point is, not how fast it moves: the velocity is the difference of two
    pictures (anti-aliasing makes even a sub-pixel step visible), which the learned reward reads from its
    transition ``(z, z')``; no velocity vector is observed beside it. The glow around the point
    (:data:`GLOW_SIGMA`) is what lets MPAIL2 learn the task from the pictures: see the preset
    ``point_mass_pixels``.

    Args:
        batch_size (sequence of int): number of independent point masses, e.g. ``()`` or ``(4,)``.
            Defaults to ``()``.
        device (torch.device or str): where tensors live. Defaults to ``"cpu"``.
        seed (int, optional): seed of the start-state generator. If ``None``, it is drawn from the
            global torch RNG so that :func:`torch.manual_seed` controls it.
        horizon (int): episode length (truncation). Defaults to 50.
        obs (str): observation mode: ``"state"`` (default: ``"observation"``, position and velocity), ``"pixels"``
            (the picture ``"external_image"`` alone) or ``"pixels_state"`` (both: the point mass's video-only setting,
            in which the demonstrations keep the picture and the learner sees the state as well).
        glow (float): std of the glow around the point in the pictures (:func:`draw_arena`). Defaults to
            :data:`GLOW_SIGMA`.

    Raises:
        ValueError: for another ``obs`` (the message names the valid modes) or ``horizon < 1``.

    Examples:
        >>> env = PointMassEnv(batch_size=[3], seed=0)
        >>> td = env.reset()
        >>> td["observation"].shape, td["success"].any().item()
        (torch.Size([3, 4]), False)
        >>> rollout = env.rollout(100)  # random actions; stops at the 50-step truncation
        >>> rollout.shape, rollout["next", "truncated"][:, -1].all().item()
        (torch.Size([3, 50]), True)
        >>> PointMassEnv(obs="pixels").reset()["external_image"].shape
        torch.Size([3, 64, 64])
        >>> sorted(PointMassEnv(obs="pixels_state").observation_spec.keys())
        ['external_image', 'observation', 'success']
    """

    def __init__(
        self,
        batch_size: Sequence[int] = (),
        device: torch.device | str = "cpu",
        seed: int | None = None,
        horizon: int = 50,
        obs: str = "state",
        glow: float = GLOW_SIGMA,
    ) -> None:
        super().__init__(device=device, batch_size=torch.Size(batch_size))
        if glow < 0:
            raise ValueError(f"PointMassEnv: glow must be >= 0 (0 draws none), got {glow}")
        self.glow = float(glow)
        if horizon < 1:
            raise ValueError(f"horizon must be >= 1, got {horizon}.")
        if obs not in obs_modes_of(POINT_MASS):
            raise ValueError(f"PointMassEnv: unknown obs {obs!r}; valid modes: {', '.join(obs_modes_of(POINT_MASS))}.")
        self.horizon = int(horizon)
        self.obs_mode = obs
        self._make_specs()
        batch = self.batch_size
        self._position = torch.zeros(*batch, 2, device=self.device)
        self._velocity = torch.zeros(*batch, 2, device=self.device)
        self._elapsed = torch.zeros(batch, dtype=torch.long, device=self.device)
        self._generator = torch.Generator(device="cpu")
        if seed is None:
            seed = int(torch.randint(0, 2**62, ()).item())
        self.set_seed(seed)

    @property
    def pictures(self) -> str | None:
        """How the pixel observation is drawn (recorded by demonstrations, :func:`~torchrl_mpail2.envs.keys.pictures_of`);
        None from state."""
        return f"point_mass arena, glow {self.glow}" if self.obs_mode != "state" else None

    def render(self, size: int = 128) -> np.ndarray:
        """An RGB frame ``[size, size, 3]`` uint8 of the arena (batch size ``[]`` only): :func:`draw_arena`."""
        if self.batch_size:
            raise ValueError(f"PointMassEnv.render draws one point mass; this env has batch size {list(self.batch_size)}")
        return draw_arena(self._position, size, self.glow).permute(1, 2, 0).cpu().numpy()

    def _make_specs(self) -> None:
        batch = self.batch_size
        flag = lambda: Categorical(2, shape=(*batch, 1), dtype=torch.bool, device=self.device)  # noqa: E731
        seen = {}
        if self.obs_mode != "pixels":
            seen["observation"] = Unbounded(shape=(*batch, OBSERVATION_DIM), dtype=torch.float32, device=self.device)
        if self.obs_mode != "state":
            seen[IMAGE_KEY] = Bounded(0, 255, shape=(*batch, 3, IMAGE_SIZE, IMAGE_SIZE), dtype=torch.uint8,
                                      device=self.device)
        self.observation_spec = Composite(
            seen,
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
        seen = {}
        if self.obs_mode != "pixels":
            seen["observation"] = torch.cat([self._position, self._velocity], dim=-1)
        if self.obs_mode != "state":
            seen[IMAGE_KEY] = draw_arena(self._position, glow=self.glow)
        return TensorDict(
            {**seen, "success": distance < SUCCESS_RADIUS},
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
