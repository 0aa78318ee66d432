"""Learning benchmark: MPAIL2 on robosuite Lift from state with scripted observation-only demonstrations.

    python benchmarks/learning.py --budget-min 90 [section.field=value ...]

Trains the ``lift_state`` preset under a wall-clock budget, then writes ``docs/results/diary/<name>.json`` (episodes,
env steps, wall time, best/last evaluation success, the config) and ``docs/results/diary/<name>_curves.png``.
Re-running with ``--summarize RUN_DIR`` rewrites the results from a run folder (e.g. one still going);
``--resume RUN_DIR --budget-min M --name NAME`` continues a run for M more minutes and writes NAME.
"""
from __future__ import annotations

import argparse
import json
import platform
import shutil
import time
from pathlib import Path

import torch

from torchrl_mpail2.trainers import MPAIL2Trainer, apply_overrides, preset
from torchrl_mpail2.trainers.plots import EVAL_FILE, METRICS_FILE, plot_run, read_jsonl

RESULTS = Path(__file__).resolve().parents[1] / "docs" / "results" / "diary"


def summarize(run_dir: Path, name: str, extra: dict | None = None) -> dict:
    episodes = read_jsonl(run_dir / METRICS_FILE)
    evals = read_jsonl(run_dir / EVAL_FILE)
    config = json.loads((run_dir / "config.json").read_text())
    result = {
        "task": config["train"]["env"], "obs": config["train"]["obs"], "demos": config["train"]["num_demos"],
        "episodes": len(episodes), "env_steps": sum(e["length"] for e in episodes),
        "train_success_last_25": sum(e["success"] for e in episodes[-25:]) / max(1, len(episodes[-25:])),
        "evaluations": [{k: e[k] for k in ("episode", "success_rate", "success_rate_any_step", "return") if k in e}
                        for e in evals],
        "best_eval_success": max((e["success_rate"] for e in evals), default=None),
        "last_eval_success": evals[-1]["success_rate"] if evals else None,
        "best_eval_success_any_step": max((e["success_rate_any_step"] for e in evals if "success_rate_any_step" in e),
                                          default=None),
        "curve": {k: [e.get(k) for e in episodes]
                  for k in ("episode", "success", "success_any_step", "task_return", "reward_gap")},
        "mean_update_ms": sum(e.get("update_ms", 0) for e in episodes) / max(1, sum("update_ms" in e for e in episodes)),
        "machine": {"torch_threads": config["train"]["threads"] or torch.get_num_threads(), "platform": platform.platform()},
        "config": config, **(extra or {}),
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f"{name}.json").write_text(json.dumps(result, indent=2))
    shutil.copy(plot_run(run_dir), RESULTS / f"{name}_curves.png")
    return result


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--preset", default="lift_state")
    p.add_argument("--budget-min", type=float, default=90.0)
    p.add_argument("--name", default="lift_state_learning")
    p.add_argument("--run-dir", default="runs/benchmark_lift_state")
    p.add_argument("--summarize", metavar="RUN_DIR", help="only rewrite the results from an existing run folder")
    p.add_argument("--resume", metavar="RUN_DIR",
                   help="continue a run stopped at its budget (or by a crash) from its last checkpoint "
                        "for --budget-min more minutes")
    args, overrides = p.parse_known_args()
    if args.summarize:
        print(json.dumps(summarize(Path(args.summarize), args.name), indent=2)[:2000])
        return
    start = time.perf_counter()
    if args.resume:
        if overrides:
            raise SystemExit(f"--resume continues a run with its saved config; drop the overrides {overrides}")
        # the budget counts from this call; the saved config.json records it
        trainer = MPAIL2Trainer.resume(args.resume, {"train.max_wall_s": args.budget_min * 60.0})
        prefix = "resumed_"
    else:
        cfg = apply_overrides(preset(args.preset), {"train.max_wall_s": args.budget_min * 60.0,
                                                    "train.run_dir": str(args.run_dir)})
        trainer = MPAIL2Trainer(apply_overrides(cfg, overrides))  # the command line's overrides come last
        prefix = ""
    summary = trainer.train()
    result = summarize(trainer.run_dir, args.name, {f"{prefix}wall_time_s": time.perf_counter() - start,
                                                    f"{prefix}budget_s": args.budget_min * 60,
                                                    "trainer_summary": summary})
    print(json.dumps({k: v for k, v in result.items() if k != "config"}, indent=2))


if __name__ == "__main__":
    main()
