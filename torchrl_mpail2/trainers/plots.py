"""Learning-curve plots of a run folder (``python -m torchrl_mpail2.trainers.plots RUN_DIR``)."""
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


def plot_run(run_dir: str | Path, window: int = 25) -> Path:
    """Writes ``curves.png``: cumulative successes, windowed success rate, evaluation success and policy influence."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    run_dir = Path(run_dir)
    episodes = read_jsonl(run_dir / METRICS_FILE)
    evals = read_jsonl(run_dir / EVAL_FILE)
    fig, axes = plt.subplots(2, 2, figsize=(11, 7))
    if episodes:
        ep = np.array([e["episode"] for e in episodes])
        success = np.array([float(e["success"]) for e in episodes])
        axes[0, 0].plot(ep, np.cumsum(success))
        axes[0, 1].plot(ep, moving_average(success, window))
        influence = [(e["episode"], e["policy_influence"]) for e in episodes if e.get("policy_influence") is not None]
        if influence:
            axes[1, 1].plot(*zip(*influence))
    if evals:
        axes[1, 0].plot([e["episode"] for e in evals], [e["success_rate"] for e in evals], marker="o")
    titles = [("Cumulative successes", "successes"), (f"Success rate ({window}-episode window)", "success rate"),
              ("Evaluation success (deterministic planner)", "success rate"), ("Policy influence", "elite weight share")]
    for ax, (title, ylabel) in zip(axes.flat, titles):
        ax.set_title(title)
        ax.set_xlabel("episode")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    for ax in (axes[0, 1], axes[1, 0], axes[1, 1]):
        ax.set_ylim(-0.05, 1.05)
    fig.suptitle(run_dir.name)
    fig.tight_layout()
    out = run_dir / "curves.png"
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python -m torchrl_mpail2.trainers.plots RUN_DIR")
    print(plot_run(sys.argv[1]))
