r"""Latent dynamics :math:`f_\psi : (z, a) \mapsto \hat z'` (Section 3, Eq. 2)."""
from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict.nn import TensorDictModule
from torch import Tensor, nn

from torchrl_mpail2.modules._mlp import check_last_dim, mlp


class DynamicsNet(nn.Module):
    r"""MLP of :math:`f_\psi`: ``[z, a] -> Linear/LayerNorm/SiLU x len(hidden) -> Linear -> LayerNorm``."""

    def __init__(self, latent_dim: int, action_dim: int, hidden_dims: Sequence[int]):
        super().__init__()
        self.latent_dim = latent_dim
        self.action_dim = action_dim
        self.net = mlp(latent_dim + action_dim, hidden_dims, latent_dim, out_norm=True)

    def forward(self, z: Tensor, a: Tensor) -> Tensor:
        """``z [*B, Z]``, ``a [*B, A]`` -> ``z' [*B, Z]``."""
        check_last_dim("dynamics input 'z'", z, self.latent_dim)
        check_last_dim("dynamics input 'action'", a, self.action_dim)
        return self.net(torch.cat([z, a], dim=-1))


class LatentDynamics(TensorDictModule):
    r"""Latent dynamics :math:`\hat z_{t+1} = f_\psi(z_t, a_t)`, trained only by the JEP loss (Eq. 2).

    Args:
        latent_dim (int): ``Z``.
        action_dim (int): ``A``.
        hidden_dims (Sequence[int]): hidden widths (Table 4: ``[512, 512]``).

    Keyword Args:
        in_keys: defaults to ``["z", "action"]``.
        out_keys: defaults to ``[("next", "z")]``.

    Examples:
        >>> from tensordict import TensorDict
        >>> f = LatentDynamics(8, 2, [16])
        >>> td = f(TensorDict({"z": torch.zeros(4, 8), "action": torch.zeros(4, 2)}, [4]))
        >>> td["next", "z"].shape
        torch.Size([4, 8])
    """

    def __init__(self, latent_dim: int, action_dim: int, hidden_dims: Sequence[int], *, in_keys=None, out_keys=None):
        super().__init__(
            DynamicsNet(latent_dim, action_dim, hidden_dims),
            in_keys=list(in_keys or ["z", "action"]),
            out_keys=list(out_keys or [("next", "z")]),
        )
