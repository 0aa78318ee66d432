r"""A small decoder from latents :math:`z = e_\omega(o)` to a quantity the latent does not show directly (an
end-effector position), trained on the side on detached latents: no gradient reaches the learner."""
from __future__ import annotations

import torch
from torch import Tensor, nn


class LatentProbe(nn.Module):
    """``z [*B, Z] -> y [*B, D]``: a two-layer MLP on standardised targets (the paper's side decoder for its
    pictures of predicted plans).

    Args:
        latent_dim (int): Z. out_dim (int): D. hidden (int): width of the hidden layer. Defaults to 128.
    """

    def __init__(self, latent_dim: int, out_dim: int, hidden: int = 128):
        super().__init__()
        self.net = nn.Sequential(nn.Linear(latent_dim, hidden), nn.ELU(), nn.Linear(hidden, hidden), nn.ELU(),
                                 nn.Linear(hidden, out_dim))
        self.register_buffer("target_mean", torch.zeros(out_dim))
        self.register_buffer("target_std", torch.ones(out_dim))

    def forward(self, z: Tensor) -> Tensor:
        return self.net(z) * self.target_std + self.target_mean


def fit_latent_probe(z: Tensor, y: Tensor, *, steps: int = 1000, lr: float = 1e-3, batch_size: int = 256,
                     held_out: float = 0.2, seed: int = 0) -> tuple[LatentProbe, dict[str, float]]:
    """Fits a :class:`LatentProbe` to ``(z [N, Z], y [N, D])`` (both detached first) with Adam on the mean squared
    error; a random ``held_out`` share of the pairs is kept out of training.

    Returns:
        ``(probe, stats)``; ``stats`` has ``train_mae`` and ``held_out_mae`` (mean absolute error per coordinate, in
        ``y``'s units) and ``held_out_r2`` (the share of the held-out variance explained, averaged over coordinates).

    Examples:
        >>> z = torch.randn(500, 8)
        >>> probe, stats = fit_latent_probe(z, z[:, :2] * 3.0, steps=300)
        >>> stats["held_out_r2"] > 0.9
        True
    """
    if z.ndim != 2 or y.ndim != 2 or z.shape[0] != y.shape[0]:
        raise ValueError(f"expected z [N, Z] and y [N, D] with the same N, got {tuple(z.shape)} and {tuple(y.shape)}")
    if z.shape[0] < 10:
        raise ValueError(f"a probe needs at least 10 pairs, got {z.shape[0]}")
    z, y = z.detach().float(), y.detach().float()
    generator = torch.Generator().manual_seed(seed)
    order = torch.randperm(z.shape[0], generator=generator)
    n_held = max(1, int(held_out * z.shape[0]))
    held, train = order[:n_held], order[n_held:]
    with torch.random.fork_rng():
        torch.manual_seed(seed)
        probe = LatentProbe(z.shape[1], y.shape[1])
    probe.target_mean.copy_(y[train].mean(0))
    probe.target_std.copy_(y[train].std(0).clamp_min(1e-6))
    optimizer = torch.optim.Adam(probe.net.parameters(), lr=lr)
    for _ in range(steps):
        index = train[torch.randint(len(train), (min(batch_size, len(train)),), generator=generator)]
        error = (probe.net(z[index]) - (y[index] - probe.target_mean) / probe.target_std).pow(2).mean()
        optimizer.zero_grad(set_to_none=True)
        error.backward()
        optimizer.step()
    with torch.no_grad():
        pred = probe(z)
        variance = y[held].var(0).clamp_min(1e-12)
        r2 = 1.0 - (pred[held] - y[held]).pow(2).mean(0) / variance
        stats = {"train_mae": float((pred[train] - y[train]).abs().mean()),
                 "held_out_mae": float((pred[held] - y[held]).abs().mean()), "held_out_r2": float(r2.mean())}
    return probe.requires_grad_(False), stats
