"""Learning-curve and learner-diagnostic plots of a run folder (``python -m torchrl_mpail2.trainers.plots RUN_DIR``)."""
from __future__ import annotations

import json
import sys
import warnings
from pathlib import Path

import numpy as np

METRICS_FILE = "metrics.jsonl"
EVAL_FILE = "eval.jsonl"


def read_jsonl(path: Path) -> list[dict]:
    """Records of a JSON-lines log. A torn last line (a kill mid-write) is dropped with a warning.

    Raises:
        ValueError: a line other than the last one is not JSON (the message names the file and the line).
    """
    path = Path(path)
    if not path.exists():
        return []
    lines = path.read_text().splitlines()
    records = []
    for number, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError as error:
            if number == len(lines):
                warnings.warn(f"{path}: dropping its torn last line {number} ({line[:60]!r})", RuntimeWarning,
                              stacklevel=2)
                break
            raise ValueError(f"{path}, line {number} is not JSON ({error}): {line[:80]!r}") from error
    return records


def moving_average(x: np.ndarray, window: int) -> np.ndarray:
    """Mean of the last ``window`` values at each index (shorter at the start)."""
    c = np.cumsum(np.insert(np.asarray(x, dtype=float), 0, 0.0))
    idx = np.arange(1, len(x) + 1)
    lo = np.maximum(idx - window, 0)
    return (c[idx] - c[lo]) / (idx - lo)


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _series(episodes: list[dict], key: str) -> tuple[list, list]:
    """``(episode, value)`` of the records that carry a finite ``key`` (updates are not logged in warm-up)."""
    pairs = [(e["episode"], e[key]) for e in episodes if isinstance(e.get(key), (int, float)) and np.isfinite(e[key])]
    return tuple(map(list, zip(*pairs))) if pairs else ([], [])


def plot_run(run_dir: str | Path, window: int = 25) -> Path:
    """Writes ``curves.png`` (cumulative successes, windowed training success, evaluation success, policy influence;
    success at any step solid, at the last step dashed) and :func:`plot_learner`'s ``learner.png``."""
    plt = _pyplot()
    run_dir = Path(run_dir)
    episodes = read_jsonl(run_dir / METRICS_FILE)
    evals = read_jsonl(run_dir / EVAL_FILE)
    fig, axes = plt.subplots(2, 2, figsize=(11, 7))
    if episodes:
        ep = np.array([e["episode"] for e in episodes])
        success = np.array([float(e["success"]) for e in episodes])
        any_step = np.array([float(e.get("success_any_step", e["success"])) for e in episodes])
        axes[0, 0].plot(ep, np.cumsum(any_step), label="any step")
        axes[0, 0].plot(ep, np.cumsum(success), ls="--", label="last step")
        axes[0, 1].plot(ep, moving_average(any_step, window), label="any step")
        axes[0, 1].plot(ep, moving_average(success, window), ls="--", label="last step")
        influence = _series(episodes, "policy_influence")
        if influence[0]:
            axes[1, 1].plot(*influence)
    if evals:
        x = [e["episode"] for e in evals]
        axes[1, 0].plot(x, [e.get("success_rate_any_step", e["success_rate"]) for e in evals], marker="o", label="any step")
        axes[1, 0].plot(x, [e["success_rate"] for e in evals], marker="o", ls="--", label="last step")
    titles = [("Cumulative successes (training)", "episodes succeeded"),
              (f"Training success ({window}-episode window)", "success rate"),
              ("Evaluation success (deterministic planner)", "success rate"), ("Policy influence", "elite weight share")]
    for ax, (title, ylabel) in zip(axes.flat, titles):
        ax.set_title(title)
        ax.set_xlabel("episode")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(loc="upper left", fontsize=8)
    for ax in (axes[0, 1], axes[1, 0], axes[1, 1]):
        ax.set_ylim(-0.05, 1.05)
    fig.suptitle(run_dir.name)
    fig.tight_layout()
    out = run_dir / "curves.png"
    fig.savefig(out, dpi=100)
    plt.close(fig)
    plot_learner(run_dir)
    return out


#: Panels of ``learner.png``: title, y label, metrics (drawn together), log scale.
LEARNER_PANELS = (
    ("Critic r(z, z'): expert minus agent (raw)", "score gap", ("reward_gap",), False),
    ("Gradient penalty (Eq. 3's GP term before beta)", "GP", ("grad_penalty",), True),
    ("Value: Q and its target", "value", ("q_mean", "q_target_mean"), False),
    ("Entropy temperature alpha", "alpha", ("alpha",), True),
    ("Policy entropy per action step", "nats", ("entropy", "target_entropy"), False),
    ("Planner: effective elites 1 / sum w^2", "elites", ("elite_ess",), False),
)


def learner_series(episodes: list[dict]) -> dict[str, tuple[list, list]]:
    """``{metric: (episodes, values)}`` for every metric of :data:`LEARNER_PANELS` that the records carry."""
    series = {key: _series(episodes, key) for panel in LEARNER_PANELS for key in panel[2]}
    return {key: xy for key, xy in series.items() if xy[0]}


def plot_learner(run_dir: str | Path) -> Path:
    """Writes ``learner.png``: what the learner's stages log per episode (critic gap and gradient penalty, Q and its
    target, alpha, the policy's entropy against its target, the planner's effective number of elites), so that a
    run's health can be read at a glance. Metrics a run did not log leave their panel empty."""
    plt = _pyplot()
    run_dir = Path(run_dir)
    series = learner_series(read_jsonl(run_dir / METRICS_FILE))
    fig, axes = plt.subplots(2, 3, figsize=(14, 7))
    for ax, (title, ylabel, keys, log_scale) in zip(axes.flat, LEARNER_PANELS):
        for key in keys:
            if key in series:
                ax.plot(*series[key], label=key, ls="--" if key.startswith("target") else "-")
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("episode")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
        values = [np.asarray(line.get_ydata(), dtype=float) for line in ax.get_lines()]
        if log_scale and values and all(v.size and (v > 0).all() for v in values):
            ax.set_yscale("log")
        if len(ax.get_lines()) > 1:
            ax.legend(fontsize=8)
    fig.suptitle(f"{run_dir.name}: learner diagnostics (per-episode means over its updates)")
    fig.tight_layout()
    out = run_dir / "learner.png"
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python -m torchrl_mpail2.trainers.plots RUN_DIR")
    print(plot_run(sys.argv[1]))
