"""Learning on the point mass without and with a speed setting that changes numerics (same preset, same seeds).

``--mode planner`` (default) compares ``planner.bf16=false|true``; ``--mode update`` compares
``train.update_precision=float32|bf16`` (mixed-precision learner updates); ``--mode both`` turns both bf16 settings
on at once; ``--mode compile`` compares the eager planner with ``planner.compile=true``. Runs
``python -m torchrl_mpail2.train --preset point_mass ...`` for each seed, the two arms side by side (one thread
each), or reads finished runs, and writes ``docs/results/speed/<mode>_<setting>_learning.{json,md}``.

    python -m benchmarks.learning.setting_learning                          # one seed, both arms (about 8 minutes on 2 cores)
    python -m benchmarks.learning.setting_learning --mode compile --seeds 0 1 2
    python -m benchmarks.learning.setting_learning --mode update --runs-root DIR   # summarise finished runs
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from benchmarks.records import ROOT

#: Per mode: the overrides that turn the setting on, the two arms' labels, and the results' file stem.
MODES = {
    "planner": (["planner.bf16=true"], ("fp32", "bf16"), "planner_bf16_learning"),
    "update": (["train.update_precision=bf16"], ("fp32", "bf16"), "update_bf16_learning"),
    "both": (["planner.bf16=true", "train.update_precision=bf16"], ("fp32", "bf16"), "both_bf16_learning"),
    "compile": (["planner.compile=true"], ("eager", "compiled"), "planner_compile_learning"),
}


def run_dir(root: Path, seed: int, arm: str) -> Path:
    return root / f"seed{seed}_{arm}"


def launch(folder: Path, overrides: list[str], seed: int) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "torchrl_mpail2.train", "--preset", "point_mass", *overrides,
           f"train.seed={seed}", f"train.run_dir={folder}", "train.progress=false", "train.threads=1"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def read_run(folder: Path) -> dict:
    for name in ("summary.json", "eval.jsonl"):
        if not (folder / name).is_file():
            raise SystemExit(f"{folder / name} is missing: run the arm first (or point --runs-root elsewhere)")
    summary = json.loads((folder / "summary.json").read_text())
    evals = [json.loads(line) for line in (folder / "eval.jsonl").read_text().splitlines() if line.strip()]
    return {"summary": {k: v for k, v in summary.items() if not isinstance(v, (dict, list))},
            "time_split_s": summary.get("time_split_s", {}), "evals": evals}


def markdown(mode: str, results: dict) -> str:
    overrides, arms, _ = MODES[mode]
    lines = [f"# Point mass learning without and with `{' '.join(overrides)}`", "",
             f"`python -m benchmarks.learning.setting_learning --mode {mode} --seeds {' '.join(map(str, results['seeds']))}`: "
             "`python -m torchrl_mpail2.train --preset point_mass` per seed, the two arms side by side at one thread "
             "each. Any-step success of the deterministic-planner evaluations (10 episodes each) after episodes "
             + " / ".join(str(e["episode"]) for e in results["runs"][0][arms[0]]["evals"]) + ":", "",
             f"| seed | {arms[0]} | {arms[1]} | {arms[0]} wall (s) | {arms[1]} wall (s) | "
             f"{arms[0]} acting + evaluation (s) | {arms[1]} acting + evaluation (s) |", "|---:|---|---|---:|---:|---:|---:|"]
    for seed, runs in zip(results["seeds"], results["runs"]):
        curves = [" / ".join(f"{e.get('success_rate_any_step', e['success_rate']):.1f}" for e in runs[a]["evals"])
                  for a in arms]
        walls = [f"{runs[a]['summary']['wall_time_s']:.0f}" for a in arms]
        plan = [f"{runs[a]['time_split_s'].get('act', 0) + runs[a]['time_split_s'].get('evaluate', 0):.0f}"
                for a in arms]
        lines.append(f"| {seed} | {curves[0]} | {curves[1]} | {walls[0]} | {walls[1]} | {plan[0]} | {plan[1]} |")
    if results.get("note"):
        lines += ["", results["note"]]
    return "\n".join(lines) + "\n"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--mode", choices=sorted(MODES), default="planner")
    p.add_argument("--seeds", type=int, nargs="+", default=[0])
    p.add_argument("--runs-root", type=Path, help="read finished runs from DIR/seed<S>_<arm> instead of running")
    p.add_argument("--note", default="", help="what else ran on the machine (written with the results)")
    p.add_argument("--out", type=Path, default=ROOT / "docs" / "results" / "speed")
    args = p.parse_args()
    overrides, arms, stem = MODES[args.mode]
    root = args.runs_root
    if root is None:
        root = Path(tempfile.mkdtemp(prefix=f"{stem}_"))
        for seed in args.seeds:
            procs = [launch(run_dir(root, seed, arm), arm_overrides, seed)
                     for arm, arm_overrides in zip(arms, ([], overrides))]
            if any(proc.wait() != 0 for proc in procs):
                sys.exit(f"a training run of seed {seed} failed (run folders under {root})")
    results = {"mode": args.mode, "overrides": overrides, "seeds": args.seeds, "note": args.note,
               "runs": [{arm: read_run(run_dir(root, seed, arm)) for arm in arms} for seed in args.seeds]}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / f"{stem}.json").write_text(json.dumps(results, indent=2))
    text = markdown(args.mode, results)
    (args.out / f"{stem}.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
