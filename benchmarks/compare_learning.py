"""Side-by-side learning curves of several ``benchmarks/learning.py`` results.

    python benchmarks/compare_learning.py lift_state_learning lift_state_tpw1_b256_utd1 --out lift_state_comparison

Reads ``docs/results/diary/<name>.json`` for each name and writes ``docs/results/diary/<out>.png``: evaluation success per
checkpoint, training success over a moving window of 25 episodes, and the task return (robosuite's dense reward,
which the learner never sees) over the same window. Results written before per-episode curves were stored
show their evaluation points only.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from torchrl_mpail2.trainers.plots import moving_average

RESULTS = Path(__file__).resolve().parents[1] / "docs" / "results" / "diary"


def label(result: dict, name: str) -> str:
    loss, train = result["config"]["loss"], result["config"]["train"]
    tpw = loss.get("transitions_per_window") or "all"
    scale = "raw critic" if loss.get("reward_scale_momentum") is None else "scaled reward"
    eta = result["config"].get("planner", {}).get("temperature", 2.0)
    extras = [f"{train['update_precision']} updates"] if train.get("update_precision", "float32") != "float32" else []
    if train.get("demos"):
        extras.append(f"demos {Path(train['demos']).name}")
    elif train.get("num_demos", 10) != 10:
        extras.append(f"{train['num_demos']} demos")
    if "resumed_budget_s" in result:
        extras.append(f"resumed for {result['resumed_budget_s'] / 60:.0f} more minutes")
    return ", ".join([f"{name}: batch {train['batch_size']}, UTD {train['utd']}, {tpw} transitions/window, {scale}",
                      f"eta {eta:g}", *extras])


def plot(names: list[str], out: str, window: int = 25) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    fig, axes = plt.subplots(1, 3, figsize=(16, 4.8))
    handles = []
    for i, name in enumerate(names):
        result = json.loads((RESULTS / f"{name}.json").read_text())
        color = f"C{i}"
        evals = result["evaluations"]
        axes[0].plot([e["episode"] for e in evals], [e["success_rate"] for e in evals], marker="o", color=color)
        handles.append(Line2D([], [], color=color, marker="o", label=label(result, name)))
        curve = result.get("curve")
        if curve:
            episode = np.asarray(curve["episode"])
            axes[1].plot(episode, moving_average(np.asarray(curve["success"], dtype=float), window), color=color)
            axes[2].plot(episode, moving_average(np.asarray(curve["task_return"], dtype=float), window), color=color)
    for ax, title in zip(axes, ("Evaluation success (deterministic planner)", f"Training success ({window}-episode window)",
                                f"Task return, unseen by the learner ({window}-episode window)")):
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("episode")
        ax.grid(alpha=0.3)
    axes[0].set_ylim(-0.05, 1.05)
    axes[1].set_ylim(-0.05, 1.05)
    fig.legend(handles=handles, loc="lower center", ncol=1, fontsize=8)
    fig.tight_layout(rect=(0, 0.06 * len(names), 1, 1))
    path = RESULTS / f"{out}.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("names", nargs="+", help="result names under docs/results/diary (without .json)")
    p.add_argument("--out", default="lift_state_comparison")
    args = p.parse_args()
    missing = [n for n in args.names if not (RESULTS / f"{n}.json").exists()]
    if missing:
        raise SystemExit(f"no results named {missing} under {RESULTS}")
    print(plot(args.names, args.out))


if __name__ == "__main__":
    main()
