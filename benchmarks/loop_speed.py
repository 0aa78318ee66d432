"""Speed of the whole training loop: environment steps per second of a real run, and where its time goes.

    python benchmarks/loop_speed.py [--episodes 8] [--presets lift_state paper_lift_state] [--threads 1 2]

Each (preset, threads) pair trains a fresh robosuite Lift run (state observations) for ``--episodes`` episodes
with an evaluation and checkpoints inside the measured window (``train.eval_every`` = ``--episodes``, 5 evaluation
episodes), one after the other so that no two share the cores. It reports env steps per second over the whole
run and the trainer's split of the wall time (``summary.json``'s ``time_split_s``: planning, env, update,
evaluation, checkpoint, logging). Writes ``docs/results/loop_speed.json`` and ``loop_speed.md``. Run it on a quiet
machine: anything else running slows every figure (say what was).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results"
STAGES = ("act", "env", "update", "evaluate", "checkpoint", "log")


def run_one(preset: str, threads: int, episodes: int, scratch: Path, extra: list[str]) -> dict:
    run_dir = scratch / f"{preset}-t{threads}"
    cmd = [sys.executable, "-m", "torchrl_mpail2.train", "--preset", preset, f"train.run_dir={run_dir}",
           f"train.threads={threads}", "train.progress=false", "train.logger=none",
           f"train.total_episodes={episodes}", f"train.eval_every={episodes}", "train.eval_episodes=5",
           f"train.checkpoint_every={episodes}", "train.warmup_episodes=1", *extra]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": str(threads)}
    subprocess.run(cmd, check=True, cwd=scratch, env=env, capture_output=True)
    summary = json.loads((run_dir / "summary.json").read_text())
    split = summary["time_split_s"]
    total = split["total"]
    return {"preset": preset, "threads": threads, "episodes": summary["episodes"], "env_steps": summary["env_steps"],
            "updates": summary["updates"], "wall_s": total, "env_steps_per_s": summary["env_steps"] / total,
            "split_s": {stage: split.get(stage, 0.0) for stage in STAGES},
            "split_share": {stage: split.get(stage, 0.0) / total for stage in STAGES}}


def table(rows: list[dict]) -> str:
    head = "| preset | threads | env steps/s | " + " | ".join(f"{s} %" for s in STAGES) + " |"
    lines = [head, "|" + "---|" * (3 + len(STAGES))]
    for r in rows:
        shares = " | ".join(f"{100 * r['split_share'][s]:.0f}" for s in STAGES)
        lines.append(f"| {r['preset']} | {r['threads']} | {r['env_steps_per_s']:.2f} | {shares} |")
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--episodes", type=int, default=8)
    p.add_argument("--presets", nargs="+", default=["lift_state", "paper_lift_state"])
    p.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    p.add_argument("--note", default="", help="what else was running, recorded with the figures")
    p.add_argument("--out", type=Path, default=RESULTS, help="folder of loop_speed.json and loop_speed.md")
    p.add_argument("overrides", nargs="*", help="config overrides for every run (section.field=value)")
    args = p.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        for preset in args.presets:
            for threads in args.threads:
                rows.append(run_one(preset, threads, args.episodes, Path(scratch), args.overrides))
                print(json.dumps(rows[-1]), flush=True)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=ROOT).stdout.strip()
    result = {"presets": args.presets, "episodes_per_run": args.episodes, "overrides": args.overrides,
              "commit": commit, "note": args.note, "machine": {"cpu": platform.processor() or platform.machine()},
              "runs": rows}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "loop_speed.json").write_text(json.dumps(result, indent=2))
    (args.out / "loop_speed.md").write_text(f"# Whole-loop speed (robosuite Lift, state)\n\n{table(rows)}\n\n"
                                           f"Commit {commit}; {args.episodes} episodes per run. {args.note}\n")
    print(table(rows))


if __name__ == "__main__":
    main()
