"""Shared plumbing of the MPAIL2 losses: keys, latents of replayed observations, reduction."""
from __future__ import annotations

from dataclasses import dataclass

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey
from torch import Tensor
from torchrl.objectives.common import LossModule

from torchrl_mpail2.modules.augment import random_shift
from torchrl_mpail2.modules.encoder import ObservationEncoder, is_image_shape


def sample_window_transitions(tensordict: TensorDictBase, per_window: int | None) -> TensorDictBase:
    """``per_window`` distinct random transitions of each ``[B, T]`` window -> ``[B, per_window]``.

    The reward, value and actor objectives are expectations over single transitions; drawing a few of each
    window's ``T`` correlated transitions cuts their cost by ``T / per_window`` while the dynamics loss keeps
    whole windows. ``None`` (or ``per_window >= T``, or a batch without a time dimension) returns the batch as is.

    Examples:
        >>> from tensordict import TensorDict
        >>> td = TensorDict({"t": torch.arange(4).expand(3, 4)}, [3, 4])
        >>> sample_window_transitions(td, 2).shape
        torch.Size([3, 2])
    """
    if per_window is None or tensordict.ndim < 2 or per_window >= tensordict.shape[1]:
        return tensordict
    if per_window < 1:
        raise ValueError(f"per_window must be >= 1, got {per_window}")
    batch, steps = tensordict.shape[:2]
    index = torch.rand(batch, steps, device=tensordict.device).argsort(-1)[:, :per_window]
    return tensordict[torch.arange(batch, device=tensordict.device).unsqueeze(-1), index]


class MPAIL2LossBase(LossModule):
    """Base of the MPAIL2 losses.

    Input layout (any leading batch shape, typically ``[B, T]`` sub-trajectories from a
    ``SliceSampler``): the encoder's observation keys, ``"action"``, the same observation keys under
    ``"next"``, ``("next", "terminated")``; expert observations under ``("expert", key)`` and
    ``("expert", "next", key)``.
    """

    @dataclass
    class _AcceptedKeys:
        """Configurable tensordict keys (``loss.set_keys(action="my_action")``).

        Attributes:
            action (NestedKey): applied action ``[*B, A]``. Defaults to ``"action"``.
            next (NestedKey): prefix of next-step observations. Defaults to ``"next"``.
            terminated (NestedKey): termination flag. Defaults to ``("next", "terminated")``.
            expert (NestedKey): prefix of expert observations. Defaults to ``"expert"``.
        """

        action: NestedKey = "action"
        next: NestedKey = "next"
        terminated: NestedKey = ("next", "terminated")
        expert: NestedKey = "expert"

    tensor_keys: _AcceptedKeys
    default_keys = _AcceptedKeys
    encoder_network: ObservationEncoder
    #: Encode stop-gradient latents (computed with gradients disabled) under bfloat16 autocast, returned in float32.
    #: Off by default: it changes the latents by about 1e-2; ``MPAIL2Updater(..., bf16=True)`` sets it.
    bf16_stop_gradient: bool = False
    #: Random-shift augmentation of camera frames (``LossConfig.image_shift`` pixels; 0: off) wherever this loss
    #: encodes observations in training mode; ``StagedLoss.set_image_shift`` sets it on a composite's objectives.
    image_shift: int = 0

    def __init__(self, encoder_network: ObservationEncoder, reduction: str = "mean"):
        super().__init__()
        self.encoder_network = encoder_network
        self.reduction = reduction

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        pass

    @property
    def in_keys(self):
        keys = list(self.encoder_network.in_keys)
        nxt = self.tensor_keys.next
        nxt = (nxt,) if isinstance(nxt, str) else tuple(nxt)
        return keys + [(*nxt, k) for k in keys] + [self.tensor_keys.action]

    def _prefix(self, key: NestedKey) -> tuple[str, ...]:
        return (key,) if isinstance(key, str) else tuple(key)

    def require(self, td: TensorDictBase, key: NestedKey) -> Tensor:
        """``td[key]``, or a KeyError naming the loss, the key and the keys present."""
        value = td.get(key, None)
        if value is None:
            raise KeyError(f"{type(self).__name__}: missing key {key!r} in the input; present: {list(td.keys(True, True))}")
        return value

    def encode(self, td: TensorDictBase, prefix: tuple[str, ...] = ()) -> Tensor:
        """Latents ``[*B, Z]`` of the observations under ``prefix``."""
        return self._encode([self.require(td, (*prefix, k)) for k in self.encoder_network.in_keys])

    def _encode(self, observations: list[Tensor], keys: list[str] | None = None) -> Tensor:
        """Encodes observations ordered as the encoder's keys (or as ``keys``, some of them, with a compartmentalised
        latent: see :meth:`EncoderNet.encode_blocks`), each ``[*B, *shape]`` -> ``[*B, Z]``.

        The batch is flattened (the image coder takes its images channels-last, oneDNN's fast layout).
        """
        net = self.encoder_network.net
        keys = net.keys if keys is None else keys
        first = observations[0]
        batch = first.shape[: first.dim() - len(net.shapes[keys[0]])]
        flat = [x.reshape(-1, *net.shapes[key]) for key, x in zip(keys, observations)]
        if self.image_shift and self.training:
            flat = [random_shift(x, self.image_shift) if is_image_shape(net.shapes[key]) else x
                    for key, x in zip(keys, flat)]
        encode = net if list(keys) == net.keys else lambda *xs: net.encode_blocks(dict(zip(keys, xs)))
        if self.bf16_stop_gradient and not torch.is_grad_enabled():
            with torch.autocast(first.device.type, dtype=torch.bfloat16):
                return encode(*flat).float().reshape(*batch, -1)
        return encode(*flat).reshape(*batch, -1)

    def _pair_latents(self, td: TensorDictBase, prefix: tuple[str, ...], partial: bool = False
                      ) -> tuple[Tensor, Tensor]:
        """``(z, z')`` of the observations under ``prefix`` and ``prefix + next``.

        Inside a contiguous ``[*B, T]`` window ``o'_t == o_{t+1}``: then the ``T + 1`` distinct
        observations are encoded once instead of ``2 T``. Whether that holds is checked on the data
        (one comparison per key), so batches of unrelated transitions get the plain two encodes.
        With ``partial``, observations may hold only some of the encoder's keys (video-only demonstrations):
        their latent blocks are encoded, the others left at zero (:meth:`EncoderNet.encode_blocks`).
        """
        keys = self.encoder_network.in_keys
        if partial:
            keys = [k for k in keys if td.get((*prefix, k), None) is not None] or keys  # none present: named below
        now = [self.require(td, (*prefix, k)) for k in keys]
        nxt = [self.require(td, (*prefix, *self._prefix(self.tensor_keys.next), k)) for k in keys]
        time = td.batch_dims - 1  # time is the last batch dimension
        steps = td.shape[-1] if td.batch_dims else 0
        if steps >= 2 and all(torch.equal(o.narrow(time, 1, steps - 1), n.narrow(time, 0, steps - 1))
                              for o, n in zip(now, nxt)):
            z = self._encode([torch.cat([o.narrow(time, 0, 1), n], time) for o, n in zip(now, nxt)], keys)
            return z.narrow(time, 0, steps), z.narrow(time, 1, steps)
        return self._encode(now, keys), self._encode(nxt, keys)

    @torch.no_grad()
    def replay_latents(self, td: TensorDictBase) -> tuple[Tensor, Tensor]:
        """Stop-gradient latents ``(z, z')`` of the replayed transitions, shaped like the batch."""
        return self._pair_latents(td, ())

    @torch.no_grad()
    def expert_latents(self, td: TensorDictBase) -> tuple[Tensor, Tensor]:
        """Stop-gradient latents ``(z, z')`` of the expert pairs under the ``expert`` prefix. Where the expert pairs
        hold only some observation keys (video-only demonstrations, compartmentalised latent), only their blocks are
        encoded; the agent checks when it is built that the reward reads nothing else
        (:meth:`~torchrl_mpail2.modules.MPAIL2Modules.demo_keys_missing`)."""
        return self._pair_latents(td, self._prefix(self.tensor_keys.expert), partial=not self.encoder_network.net.fuse_latent)

    def reduce(self, x: Tensor) -> Tensor:
        if self.reduction == "mean":
            return x.mean()
        if self.reduction == "sum":
            return x.sum()
        return x
