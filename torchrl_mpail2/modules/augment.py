r"""Random-shift augmentation of camera frames for the update (not in the paper; departure 26).

Each frame ``o`` of a batch is moved by its own integer offset ``(dy, dx)``, drawn uniformly from
``{-p, ..., p}^2``, with its border pixels repeated into the space it leaves:

.. math::
    \tilde o[c, i, j] = o\big[c,\ \mathrm{clip}(i + dy, 0, H - 1),\ \mathrm{clip}(j + dx, 0, W - 1)\big],

the same as padding the frame by ``p`` replicated pixels and cropping an ``H x W`` window at a random place.
Pixel-based agents (DrQ, TD-MPC2) train their encoders on frames shifted this way (``p = 4`` at 64 x 64), meant to
give nearby places nearby latents; on the point mass from pixels it did not help (docs/results/camera_latent.md). The
agent acts on the frames as they are.
"""
from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["random_shift"]


def random_shift(images: Tensor, pad: int, generator: torch.Generator | None = None) -> Tensor:
    """Each of the ``[N, C, H, W]`` frames shifted by its own random offset of at most ``pad`` pixels per axis,
    border pixels repeated; any dtype (uint8 frames stay uint8). ``pad=0`` returns ``images`` itself.

    Examples:
        >>> frames = torch.arange(2 * 3 * 4 * 4, dtype=torch.uint8).reshape(2, 3, 4, 4)
        >>> random_shift(frames, 1).shape
        torch.Size([2, 3, 4, 4])
    """
    if pad < 0:
        raise ValueError(f"random_shift: pad must be >= 0, got {pad}")
    if images.dim() != 4:
        raise ValueError(f"random_shift: expected frames [N, C, H, W], got shape {tuple(images.shape)}")
    if pad == 0 or images.shape[0] == 0:
        return images
    n, c, h, w = images.shape
    offsets = torch.randint(-pad, pad + 1, (2, n, 1), generator=generator, device=images.device)
    rows = (torch.arange(h, device=images.device) + offsets[0]).clamp_(0, h - 1)  # [N, H]
    cols = (torch.arange(w, device=images.device) + offsets[1]).clamp_(0, w - 1)  # [N, W]
    shifted = images.gather(2, rows[:, None, :, None].expand(n, c, h, w))
    return shifted.gather(3, cols[:, None, None, :].expand(n, c, h, w))
