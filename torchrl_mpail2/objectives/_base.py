"""Shared plumbing of the MPAIL2 losses: keys, latents of replayed observations, reduction."""
from __future__ import annotations

from dataclasses import dataclass

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey
from torch import Tensor
from torchrl.objectives.common import LossModule

from torchrl_mpail2.modules.encoder import ObservationEncoder


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
        return self.encoder_network.net(*(self.require(td, (*prefix, k)) for k in self.encoder_network.in_keys))

    @torch.no_grad()
    def replay_latents(self, td: TensorDictBase) -> tuple[Tensor, Tensor]:
        """Stop-gradient latents ``(z, z')`` of the replayed transitions, shaped like the batch."""
        return self.encode(td), self.encode(td, self._prefix(self.tensor_keys.next))

    @torch.no_grad()
    def expert_latents(self, td: TensorDictBase) -> tuple[Tensor, Tensor]:
        """Stop-gradient latents ``(z, z')`` of the expert pairs under the ``expert`` prefix."""
        prefix = self._prefix(self.tensor_keys.expert)
        return self.encode(td, prefix), self.encode(td, prefix + self._prefix(self.tensor_keys.next))

    def reduce(self, x: Tensor) -> Tensor:
        if self.reduction == "mean":
            return x.mean()
        if self.reduction == "sum":
            return x.sum()
        return x
