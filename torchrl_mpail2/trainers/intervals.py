"""Headline figures with intervals: a 95% bootstrap interval over seeds and episodes, and the interquartile mean
over seeds (Agarwal et al., 2021, "Deep RL at the edge of the statistical precipice"). Torch-free."""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

#: Bootstrap resamples of :func:`bootstrap_ci`.
RESAMPLES = 10_000


def bootstrap_ci(per_seed: Sequence[Sequence[float]], level: float = 0.95, resamples: int = RESAMPLES,
                 seed: int = 0) -> tuple[float, float]:
    """Percentile interval of the mean outcome, resampling seeds and then each drawn seed's episodes (a two-level
    bootstrap: both the training seed and the evaluation episodes vary). One seed: episodes only.

    Args:
        per_seed: the outcomes (e.g. any-step successes, 0 or 1) of each seed's episodes.
        level: coverage of the interval.
        resamples: bootstrap draws.
        seed: seed of the resampling generator (the interval is reproducible).

    Returns:
        ``(low, high)``.

    Raises:
        ValueError: no seeds, or a seed without outcomes.
    """
    groups = [np.asarray(g, dtype=float) for g in per_seed]
    if not groups or any(g.size == 0 for g in groups):
        raise ValueError("bootstrap_ci needs at least one seed and one outcome per seed")
    rng = np.random.default_rng(seed)
    means = np.empty(resamples)
    for b in range(resamples):
        picked = rng.integers(len(groups), size=len(groups)) if len(groups) > 1 else [0]
        means[b] = np.mean([groups[i][rng.integers(groups[i].size, size=groups[i].size)].mean() for i in picked])
    tail = (1.0 - level) / 2 * 100
    low, high = np.percentile(means, [tail, 100 - tail])
    return float(low), float(high)


def iqm(values: Sequence[float]) -> float | None:
    """Interquartile mean over seeds: the mean after cutting a quarter of the values from each end (scipy's
    ``trim_mean(values, 0.25)``, as rliable computes it: a quarter rounds down, so 3 seeds keep all three); None
    for fewer than 3 values, where it means little."""
    from scipy.stats import trim_mean

    return None if len(values) < 3 else float(trim_mean(np.asarray(values, dtype=float), 0.25))
