"""Where each seed of a learning benchmark stands, read from its run folder without touching it.

    python -m benchmarks.learning.run_status                      # every NAME under runs/learning
    python -m benchmarks.learning.run_status NAME [NAME ...] [--runs-root DIR]

One row per seed folder (``runs/learning/NAME/seed<k>``): episodes done of the run's budget, whether a training holds
the folder now (its lock), finished, stopped by a signal or at its wall-clock budget (resumable by the same
``learning_seeds`` command), how many training episodes succeeded at some step (sampled actions; the warm-up's
random episodes left out) and the first of them, the latest evaluation on the fixed episodes, the held-out scores
once played, and the wall time of its launches so far.
"""
from __future__ import annotations

import argparse
import fcntl
import json
from pathlib import Path

from benchmarks.learning.learning_seeds import _read_jsonl, read_summary
from benchmarks.records import ROOT
from torchrl_mpail2.trainers.run_folder import LOCK_FILE

COLUMNS = ("run", "seed", "episodes", "state", "training successes", "last evaluation", "held out: Best / last",
           "wall (min)")


def held_by_a_training(run_dir: Path) -> bool:
    """Whether a training process holds the run folder's lock now (tested with a shared lock, released at once)."""
    lock = run_dir / LOCK_FILE
    if not lock.exists():
        return False
    with open(lock) as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except OSError:
            return True
        fcntl.flock(handle, fcntl.LOCK_UN)
    return False


def _budget(run_dir: Path) -> int | None:
    try:
        return json.loads((run_dir / "config.json").read_text())["train"]["total_episodes"]
    except (OSError, json.JSONDecodeError, KeyError):
        return None


def _held_out(run_dir: Path) -> str:
    """``Best / last`` any-step success on the held-out episodes (``checkpoint_evals.json``), ``-`` where unplayed."""
    path = run_dir / "checkpoint_evals.json"
    if not path.exists():
        return "-"
    evals = json.loads(path.read_text())
    best, last = evals.get("held_out"), evals.get("held_out_last")
    show = [f"{s['success_rate_any_step']:.2f} ({s['checkpoint'].removeprefix('episode_').lstrip('0') or '0'})"
            if s else "-" for s in (best, last)]
    return " / ".join(show)


def _training_successes(episodes: list[dict]) -> str:
    """``N (first at E)``: the acted training episodes (not the warm-up's random ones) that succeeded at some step."""
    hits = [row["episode"] for row in episodes if row.get("success_any_step", 0) > 0 and not row.get("random_actions")]
    return f"{len(hits)} (first at {hits[0]})" if hits else "0"


def seed_status(run_dir: Path) -> dict:
    """One seed's row (see the module docstring)."""
    episodes = _read_jsonl(run_dir / "metrics.jsonl")
    done = len(episodes)
    budget = _budget(run_dir)
    summary = read_summary(run_dir)
    parts = [json.loads(p.read_text()) for p in sorted(run_dir.glob("summary.part*.json"))]
    if held_by_a_training(run_dir):
        state = "running"
    elif summary is None:
        state = "stopped, resumable" if (run_dir / "checkpoints" / "last").exists() else "not started"
    elif summary.get("stopped_by"):
        state = f"stopped by {summary['stopped_by']}, resumable"
    elif budget is not None and done < budget:
        state = "stopped at its wall-clock budget"
    else:
        state = "finished"
    evaluations = _read_jsonl(run_dir / "eval.jsonl")
    last = (f"{evaluations[-1]['success_rate_any_step']:.2f} at {evaluations[-1]['episode']}" if evaluations else "-")
    # a summary's run_wall_time_s counts every launch before it; older ones have the launch's wall_time_s alone
    launches = [*parts, *([summary] if summary else [])]
    wall = max([s.get("run_wall_time_s", 0.0) for s in launches] + [sum(s.get("wall_time_s", 0.0) for s in launches)],
               default=0.0)
    return {"run": run_dir.parent.name, "seed": run_dir.name.removeprefix("seed"),
            "episodes": f"{done} of {budget}" if budget else str(done), "state": state,
            "training successes": _training_successes(episodes), "last evaluation": last,
            "held out: Best / last": _held_out(run_dir), "wall (min)": f"{wall / 60:.0f}" if wall else "-"}


def status_table(runs_root: Path, names: list[str] | None = None) -> str:
    """The markdown table of every seed folder of ``names`` (default: every name) under ``runs_root``."""
    if not names:
        names = sorted(p.name for p in runs_root.iterdir() if p.is_dir()) if runs_root.is_dir() else []
    missing = [n for n in names if not (runs_root / n).is_dir()]
    if missing:
        raise SystemExit(f"no run folder {', '.join(str(runs_root / n) for n in missing)}")
    rows = [seed_status(d) for n in names for d in sorted((runs_root / n).glob("seed*")) if d.is_dir()]
    lines = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    lines += ["| " + " | ".join(row[c] for c in COLUMNS) + " |" for row in rows]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("names", nargs="*", metavar="NAME")
    p.add_argument("--runs-root", type=Path, default=ROOT / "runs" / "learning")
    args = p.parse_args(argv)
    print(status_table(args.runs_root, args.names))


if __name__ == "__main__":
    main()
