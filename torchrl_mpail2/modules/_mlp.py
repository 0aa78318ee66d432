"""Shared MLP builder: Linear -> LayerNorm -> SiLU blocks as in the paper's architecture printout."""
from __future__ import annotations

from collections.abc import Sequence

from torch import nn


def mlp(
    in_dim: int,
    hidden_dims: Sequence[int],
    out_dim: int,
    layer_norm: bool = True,
    out_norm: bool = False,
    out_bias: bool = True,
) -> nn.Sequential:
    """Builds ``in -> [Linear, (LayerNorm), SiLU] * len(hidden) -> Linear (-> LayerNorm)``.

    Args:
        in_dim (int): input width.
        hidden_dims (Sequence[int]): hidden widths.
        out_dim (int): output width.
        layer_norm (bool): LayerNorm after each hidden Linear (the reward uses none).
        out_norm (bool): LayerNorm on the output (latents of the encoder and the dynamics).
        out_bias (bool): bias of the last Linear (the reward has none).
    """
    layers: list[nn.Module] = []
    width = in_dim
    for hidden in hidden_dims:
        layers.append(nn.Linear(width, hidden))
        if layer_norm:
            layers.append(nn.LayerNorm(hidden))
        layers.append(nn.SiLU())
        width = hidden
    layers.append(nn.Linear(width, out_dim, bias=out_bias))
    if out_norm:
        layers.append(nn.LayerNorm(out_dim))
    return nn.Sequential(*layers)


def check_last_dim(name: str, x, expected: int) -> None:
    """Raises a ValueError naming ``name`` when the last dimension of ``x`` is not ``expected``."""
    if x.dim() == 0 or x.shape[-1] != expected:
        raise ValueError(f"{name}: expected shape [*B, {expected}], got {list(x.shape)}")
