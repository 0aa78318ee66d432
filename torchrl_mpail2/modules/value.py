r"""Q-ensemble :math:`Q_\zeta(z, a)` (Eq. 4): ``E`` MLP heads evaluated in one batched call."""
from __future__ import annotations

import math
from collections.abc import Sequence

import torch
import torch.nn.functional as F
from tensordict.nn import TensorDictModule
from torch import Tensor, nn

from torchrl_mpail2.modules._mlp import check_last_dim


class StackedLinear(nn.Module):
    """``E`` independent Linear layers stored as one ``[E, in, out]`` weight.

    An input ``[M, in]`` shared by every head becomes one GEMM against ``[in, E * out]``;
    per-head inputs ``[E, M, in]`` become one batched GEMM.
    """

    def __init__(self, num: int, in_dim: int, out_dim: int):
        super().__init__()
        self.weight = nn.Parameter(torch.empty(num, in_dim, out_dim))
        self.bias = nn.Parameter(torch.empty(num, out_dim))
        bound = 1.0 / math.sqrt(in_dim)  # nn.Linear's default init, per head
        nn.init.uniform_(self.weight, -bound, bound)
        nn.init.uniform_(self.bias, -bound, bound)

    def forward(self, x: Tensor, heads: Tensor | None = None) -> Tensor:
        w, b = self.weight, self.bias
        if heads is not None:
            w, b = w.index_select(0, heads), b.index_select(0, heads)
        num, in_dim, out_dim = w.shape
        if x.dim() == 2:  # shared input: one wide GEMM, bias included
            y = torch.addmm(b.reshape(num * out_dim), x, w.permute(1, 0, 2).reshape(in_dim, num * out_dim))
            return y.view(x.shape[0], num, out_dim).transpose(0, 1)
        return torch.baddbmm(b.unsqueeze(1), x, w)


class StackedLayerNorm(nn.Module):
    """Per-head LayerNorm over ``[E, M, D]``."""

    def __init__(self, num: int, dim: int):
        super().__init__()
        self.weight = nn.Parameter(torch.ones(num, dim))
        self.bias = nn.Parameter(torch.zeros(num, dim))

    def forward(self, x: Tensor, heads: Tensor | None = None) -> Tensor:
        w, b = self.weight, self.bias
        if heads is not None:
            w, b = w.index_select(0, heads), b.index_select(0, heads)
        return torch.addcmul(b.unsqueeze(1), F.layer_norm(x, x.shape[-1:]), w.unsqueeze(1))  # one pass, not two


#: Heads drawn from the ensemble for a target, an objective or a plan's score (as in TD-MPC2, which the paper
#: builds on).
HEADS_PER_ESTIMATE = 2


def draw_heads(num_q: int, device: torch.device | str, generator: torch.Generator | None = None) -> Tensor:
    """:data:`HEADS_PER_ESTIMATE` distinct random head indices of an ``num_q``-head ensemble, on ``device``.

    Drawn on the generator's device (the CPU without one: no device sync), from ``generator`` or the global stream.

    Examples:
        >>> heads = draw_heads(5, "cpu", torch.Generator().manual_seed(0))
        >>> heads.shape, bool((heads < 5).all()), heads.unique().numel()
        (torch.Size([2]), True, 2)
    """
    draw_device = generator.device if generator is not None else torch.device("cpu")
    return torch.randperm(num_q, generator=generator, device=draw_device)[:HEADS_PER_ESTIMATE].to(device)


class QEnsembleNet(nn.Module):
    r"""``E`` heads of ``[z, a] -> (Linear, LayerNorm, SiLU) x len(hidden) -> Linear(1)``.

    Args:
        latent_dim (int): ``Z``.
        action_dim (int): ``A``.
        hidden_dims (Sequence[int]): hidden widths.
        num_q (int): ensemble size ``E`` (Table 4: 5).
    """

    def __init__(self, latent_dim: int, action_dim: int, hidden_dims: Sequence[int], num_q: int = 5):
        super().__init__()
        self.latent_dim, self.action_dim, self.num_q = latent_dim, action_dim, num_q
        widths = [latent_dim + action_dim, *hidden_dims]
        self.linears = nn.ModuleList(StackedLinear(num_q, i, o) for i, o in zip(widths[:-1], widths[1:]))
        self.norms = nn.ModuleList(StackedLayerNorm(num_q, o) for o in widths[1:])
        self.head = StackedLinear(num_q, widths[-1], 1)

    def forward(self, z: Tensor, a: Tensor, heads: Tensor | None = None) -> Tensor:
        """``z [*B, Z]``, ``a [*B, A]`` -> ``q [E', *B, 1]`` for all heads or the ``heads`` selected."""
        check_last_dim("value input 'z'", z, self.latent_dim)
        check_last_dim("value input 'action'", a, self.action_dim)
        batch = torch.broadcast_shapes(z.shape[:-1], a.shape[:-1])
        x = torch.cat([z.expand(*batch, -1), a.expand(*batch, -1)], dim=-1).reshape(-1, self.latent_dim + self.action_dim)
        for linear, norm in zip(self.linears, self.norms):
            x = F.silu(norm(linear(x, heads), heads))
        q = self.head(x, heads)
        return q.reshape(q.shape[0], *batch, 1)


class QEnsemble(TensorDictModule):
    r"""Q-ensemble :math:`Q_\zeta(z, a)` with ``E`` heads, written as ``"state_action_value"`` ``[*B, E, 1]``.

    The raw network (``.module``) returns ``[E, *B, 1]`` (ensemble first, as TorchRL's losses
    expect) and can evaluate a subset of heads; the slow Polyak target lives in the value loss.

    Examples:
        >>> from tensordict import TensorDict
        >>> q = QEnsemble(8, 2, [16], num_q=5)
        >>> td = q(TensorDict({"z": torch.zeros(4, 8), "action": torch.zeros(4, 2)}, [4]))
        >>> td["state_action_value"].shape
        torch.Size([4, 5, 1])
    """

    def __init__(self, latent_dim: int, action_dim: int, hidden_dims: Sequence[int], num_q: int = 5, *, in_keys=None, out_keys=None):
        super().__init__(
            _BatchFirst(QEnsembleNet(latent_dim, action_dim, hidden_dims, num_q)),
            in_keys=list(in_keys or ["z", "action"]),
            out_keys=list(out_keys or ["state_action_value"]),
        )

    @property
    def net(self) -> QEnsembleNet:
        """The raw ensemble (``[E, *B, 1]`` outputs, optional ``heads``)."""
        return self.module.net


class _BatchFirst(nn.Module):
    """Moves the ensemble dimension after the batch dimensions for TensorDict outputs."""

    def __init__(self, net: QEnsembleNet):
        super().__init__()
        self.net = net

    def forward(self, z: Tensor, a: Tensor) -> Tensor:
        return self.net(z, a).movedim(0, -2)
