"""Speed of the whole training loop: environment steps per second of a real run, and where its time goes.

    python -m benchmarks.speed.loop_speed [--episodes 8] [--presets lift_state paper_lift_state] [--threads 1 2]
    python -m benchmarks.speed.loop_speed --presets lift_state --threads 1 --num-envs 1 2 4 --episodes 12 --name num_envs_speed

Each (preset, threads) pair trains a fresh robosuite Lift run (state observations) for ``--episodes`` episodes
with an evaluation and checkpoints inside the measured window (``train.eval_every`` = ``--episodes``, 5 evaluation
episodes), one after the other so that no two share the cores. It reports env steps per second over the whole
run and the trainer's split of the wall time (``summary.json``'s ``time_split_s``: planning, env, update,
evaluation, checkpoint, logging). ``--num-envs`` adds runs collecting from several environments at once
(``train.num_envs``); every run then starts with the same random warm-up (``max(--num-envs)`` episodes), so the
planned episodes are the same in number. ``--runs DIR [DIR ...]`` tabulates finished training runs instead (any
length, e.g. a 300-episode learning run at its default evaluation schedule), read from their ``summary.json`` and
``config.json``. Writes ``docs/results/speed/<name>.json`` and ``<name>.md`` (``--name``, default
``loop_speed``). Run it on a quiet machine: anything else running slows every figure (say what was).
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

from benchmarks.records import ROOT, child_env, write_record

RESULTS = ROOT / "docs" / "results" / "speed"
STAGES = ("act", "env", "update", "evaluate", "checkpoint", "log")


def run_one(preset: str, threads: int, episodes: int, scratch: Path, extra: list[str], num_envs: int = 1,
            warmup: int = 1) -> dict:
    run_dir = scratch / f"{preset}-t{threads}-n{num_envs}"
    cmd = [sys.executable, "-m", "torchrl_mpail2.train", "--preset", preset, f"train.run_dir={run_dir}",
           f"train.threads={threads}", "train.progress=false", "train.logger=none",
           f"train.total_episodes={episodes}", f"train.eval_every={episodes}", "train.eval_episodes=5",
           f"train.checkpoint_every={episodes}", f"train.warmup_episodes={warmup}", f"train.num_envs={num_envs}",
           *extra]
    proc = subprocess.run(cmd, cwd=scratch, env=child_env(threads), capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"training run {run_dir.name} failed (exit {proc.returncode}):\n{proc.stderr[-3000:]}")
    # the run lived in a temporary folder, gone once the benchmark ends: its name alone, no machine path
    return {**read_run(run_dir, preset), "run": run_dir.name}


def read_run(run_dir: Path, preset: str | None = None) -> dict:
    """The speed row of a finished run folder: env steps per second over its whole wall time and its time split."""
    for name in ("summary.json", "config.json"):
        if not (run_dir / name).is_file():
            raise SystemExit(f"{run_dir / name} is missing: not a finished training run")
    summary = json.loads((run_dir / "summary.json").read_text())
    train = json.loads((run_dir / "config.json").read_text())["train"]
    split = summary["time_split_s"]
    total = split["total"]
    return {"preset": preset or f"{run_dir.parent.name}/{run_dir.name}", "run": str(run_dir), "threads": train["threads"],
            "num_envs": train.get("num_envs", 1), "episodes": summary["episodes"], "env_steps": summary["env_steps"],
            "updates": summary["updates"], "wall_s": total, "env_steps_per_s": summary["env_steps"] / total,
            # collection alone (planning + env steps): what several environments at once speed up
            "collect_steps_per_s": summary["env_steps"] / max(split.get("act", 0.0) + split.get("env", 0.0), 1e-9),
            "split_s": {stage: split.get(stage, 0.0) for stage in STAGES},
            "split_share": {stage: split.get(stage, 0.0) / total for stage in STAGES}}


def table(rows: list[dict]) -> str:
    head = ("| preset | threads | envs | env steps/s | collection steps/s | updates | "
            + " | ".join(f"{s} %" for s in STAGES) + " |")
    lines = [head, "|" + "---|" * (6 + len(STAGES))]
    for r in rows:
        shares = " | ".join(f"{100 * r['split_share'][s]:.0f}" for s in STAGES)
        lines.append(f"| {r['preset']} | {r['threads']} | {r.get('num_envs', 1)} | {r['env_steps_per_s']:.2f} | "
                     f"{r.get('collect_steps_per_s', float('nan')):.2f} | {r['updates']} | {shares} |")
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--episodes", type=int, default=8)
    p.add_argument("--presets", nargs="+", default=["lift_state", "paper_lift_state"])
    p.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    p.add_argument("--num-envs", type=int, nargs="+", default=[1], help="train.num_envs of each run")
    p.add_argument("--name", default="loop_speed", help="results file name under --out")
    p.add_argument("--note", default="", help="what else was running, recorded with the figures")
    p.add_argument("--out", type=Path, default=RESULTS, help="folder of loop_speed.json and loop_speed.md")
    p.add_argument("--runs", type=Path, nargs="+", help="tabulate these finished run folders instead of training")
    p.add_argument("overrides", nargs="*", help="config overrides for every run (section.field=value)")
    args = p.parse_args()
    if args.runs:
        rows = [read_run(run) for run in args.runs]
        write_record(args.out, args.name, {"runs": rows}, args.note, ROOT,
                     lambda commit: f"# Whole-loop speed of finished runs\n\n{table(rows)}\n\n"
                                    f"Tabulated at commit {commit}. {args.note}\n")
        print(table(rows))
        return
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        warmup = max(args.num_envs)
        if args.episodes <= warmup:
            raise SystemExit(f"--episodes ({args.episodes}) must exceed the warm-up of {warmup} episodes")
        for preset in args.presets:
            for threads in args.threads:
                for num_envs in args.num_envs:
                    rows.append(run_one(preset, threads, args.episodes, Path(scratch), args.overrides, num_envs, warmup))
                    print(json.dumps(rows[-1]), flush=True)
    fields = {"presets": args.presets, "episodes_per_run": args.episodes, "warmup_episodes": warmup,
              "num_envs": args.num_envs, "overrides": args.overrides, "runs": rows}
    write_record(args.out, args.name, fields, args.note, ROOT,
                 lambda commit: f"# Whole-loop speed ({', '.join(args.presets)})\n\n{table(rows)}\n\n"
                                f"Commit {commit}; {args.episodes} episodes per run. {args.note}\n")
    print(table(rows))


if __name__ == "__main__":
    main()
