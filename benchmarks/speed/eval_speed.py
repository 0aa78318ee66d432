"""Speed of an evaluation: the fixed episodes one by one against ``train.eval_envs`` of them in lockstep.

    python -m benchmarks.speed.eval_speed [--preset lift_state] [--episodes 8] [--eval-envs 1 8] [overrides ...]
    python -m benchmarks.speed.eval_speed --preset paper_lift_state --eval-envs 1 8 train.device=cuda train.demos=DIR

For each ``--eval-envs`` value a fresh trainer of the preset (same seed, so the same untrained weights) plays one
evaluation of ``--episodes`` episodes (``MPAIL2Trainer.evaluate``) twice: the first builds the extra environments
and makes the first calls, the second is the steady figure (env steps per second count full-length episodes: the
robosuite tasks and the point mass have no early end).
Writes ``docs/results/speed/<name>.json`` and ``<name>.md`` (``--name``, default ``eval_speed``).
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import torch

from benchmarks.records import ROOT, write_record
from torchrl_mpail2.trainers import MPAIL2Trainer, apply_overrides, preset
from torchrl_mpail2.trainers.collection import episode_bound

RESULTS = ROOT / "docs" / "results" / "speed"


def time_evaluation(preset_name: str, eval_envs: int, episodes: int, overrides: list[str], scratch: Path) -> dict:
    """Two evaluations of one fresh trainer with ``train.eval_envs=eval_envs``; seconds and env steps per second."""
    cfg = apply_overrides(preset(preset_name), ["train.progress=false", "train.logger=none", "train.figures=false",
                                                f"train.eval_episodes={episodes}", f"train.eval_envs={eval_envs}",
                                                *overrides])
    trainer = MPAIL2Trainer(cfg, run_dir=scratch / f"{preset_name}-e{eval_envs}")
    row = {"preset": preset_name, "eval_envs": eval_envs, "episodes": episodes}
    for label in ("first", "second"):
        if cfg.train.device.startswith("cuda"):
            torch.cuda.synchronize()
        start = time.perf_counter()
        summary = trainer.evaluate()
        if cfg.train.device.startswith("cuda"):
            torch.cuda.synchronize()
        row[f"{label}_s"] = time.perf_counter() - start
        row[f"{label}_success_any_step"] = summary["success_rate_any_step"]
    row["env_steps_per_s"] = episodes * episode_bound(trainer.eval_env) / row["second_s"]  # fixed-length episodes
    return row


def table(rows: list[dict]) -> str:
    lines = ["| preset | eval_envs | episodes | first evaluation (s) | second evaluation (s) | env steps/s (second) | any-step success |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['preset']} | {r['eval_envs']} | {r['episodes']} | {r['first_s']:.1f} | {r['second_s']:.1f} | "
                     f"{r['env_steps_per_s']:.1f} | {r['second_success_any_step']:.2f} |")
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--preset", default="lift_state")
    p.add_argument("--episodes", type=int, default=8)
    p.add_argument("--eval-envs", type=int, nargs="+", default=[1, 8])
    p.add_argument("--threads", type=int, default=2, help="torch threads")
    p.add_argument("--name", default="eval_speed", help="results file name under --out")
    p.add_argument("--note", default="", help="what else was running, recorded with the figures")
    p.add_argument("--out", type=Path, default=RESULTS)
    p.add_argument("overrides", nargs="*", help="config overrides (section.field=value)")
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        for eval_envs in args.eval_envs:
            rows.append(time_evaluation(args.preset, eval_envs, args.episodes,
                                        [f"train.threads={args.threads}", *args.overrides], Path(scratch)))
            print(json.dumps(rows[-1]), flush=True)
    fields = {"preset": args.preset, "episodes": args.episodes, "threads": args.threads, "overrides": args.overrides,
              "runs": rows}
    write_record(args.out, args.name, fields, args.note, ROOT,
                 lambda commit: f"# Evaluation speed: one by one against lockstep\n\n{table(rows)}\n\n"
                                f"Commit {commit}; {args.threads} threads. {args.note}\n")
    print(table(rows))


if __name__ == "__main__":
    main()
