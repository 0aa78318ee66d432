"""Learning on the point mass in float32 and in bf16 (same preset, same seed).

``--mode planner`` (default) compares ``planner.bf16=false|true``; ``--mode update`` compares
``train.update_precision=float32|bf16`` (mixed-precision learner updates); ``--mode both`` turns both on at once.
Runs ``python -m torchrl_mpail2.train --preset point_mass ...`` side by side (one thread each), or reads finished
runs, and writes ``docs/results/speed/<mode>_bf16_learning.{json,md}``.

    python benchmarks/bf16_learning.py                         # both runs (about 8 minutes on 2 cores)
    python benchmarks/bf16_learning.py --mode update
    python benchmarks/bf16_learning.py --runs RUN_FP32 RUN_BF16 # summarise finished runs
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


#: The overrides that turn bf16 on, per mode.
MODES = {"planner": ["planner.bf16=true"], "update": ["train.update_precision=bf16"],
         "both": ["planner.bf16=true", "train.update_precision=bf16"]}


def launch(run_dir: Path, overrides: list[str], seed: int) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "torchrl_mpail2.train", "--preset", "point_mass", *overrides,
           f"train.seed={seed}", f"train.run_dir={run_dir}", "train.progress=false"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def read_run(run_dir: Path) -> dict:
    summary = json.loads((run_dir / "summary.json").read_text())
    evals = [json.loads(line) for line in (run_dir / "eval.jsonl").read_text().splitlines() if line.strip()]
    return {"summary": {k: v for k, v in summary.items() if not isinstance(v, (dict, list))}, "evals": evals}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--runs", nargs=2, metavar=("FP32_RUN", "BF16_RUN"))
    p.add_argument("--mode", choices=sorted(MODES), default="planner")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=str(ROOT / "docs" / "results" / "speed"))
    args = p.parse_args()
    if args.runs:
        runs = [Path(r) for r in args.runs]
    else:
        base = Path(tempfile.mkdtemp(prefix="bf16_learning_"))
        runs = [base / "fp32", base / "bf16"]
        procs = [launch(run, overrides, args.seed) for run, overrides in zip(runs, ([], MODES[args.mode]))]
        if any(proc.wait() != 0 for proc in procs):
            sys.exit("a training run failed")
    results = {"fp32": read_run(runs[0]), "bf16": read_run(runs[1]), "seed": args.seed, "mode": args.mode,
               "bf16_overrides": MODES[args.mode]}
    lines = [f"# Point mass learning in bf16 ({args.mode})", "",
             f"`python -m torchrl_mpail2.train --preset point_mass` without and with `{' '.join(MODES[args.mode])}`, "
             "same seed, one thread each, run side by side. Deterministic-planner evaluations (10 episodes each):", "",
             "| episode | fp32 success | fp32 return | bf16 success | bf16 return |", "|---:|---:|---:|---:|---:|"]
    for e32, e16 in zip(results["fp32"]["evals"], results["bf16"]["evals"]):
        lines.append(f"| {e32['episode']} | {e32['success_rate']:.1f} | {e32['return']:.1f} | {e16['success_rate']:.1f} | "
                     f"{e16['return']:.1f} |")
    lines += ["", "| run | best eval success | wall time (s) |", "|---|---:|---:|"]
    for name in ("fp32", "bf16"):
        s = results[name]["summary"]
        lines.append(f"| {name} | {s['best_eval_success']:.1f} | {s['wall_time_s']:.0f} |")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{args.mode}_bf16_learning.json").write_text(json.dumps(results, indent=2))
    (out / f"{args.mode}_bf16_learning.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
