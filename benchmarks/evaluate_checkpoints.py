"""Evaluate every saved checkpoint of a run, the paper's protocol for its Best figures (Appendix: "Best
checkpoints are selected by evaluating all automatically saved checkpoints").

    python benchmarks/evaluate_checkpoints.py RUN_DIR [--episodes 10] [--name lift_state_tpw1]

Rebuilds the run from ``RUN_DIR/config.json`` in a scratch folder (the run folder is only read), loads each
numbered checkpoint's networks and planner state, and runs ``--episodes`` deterministic-planner episodes on a
fresh evaluation environment (seed ``train.seed + 10000``, the same for every checkpoint). Writes
``RUN_DIR/checkpoint_evals.json`` and, with ``--name``, ``docs/results/<name>_checkpoints.json``: success at the
last step, success at any step (the paper's definition) and the task return per checkpoint.
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import torch
from tqdm import tqdm

from torchrl_mpail2.trainers import MPAIL2Trainer, apply_overrides
from torchrl_mpail2.trainers.config import ExperimentConfig

RESULTS = Path(__file__).resolve().parents[1] / "docs" / "results"


def numbered_checkpoints(run_dir: Path) -> list[tuple[int, Path]]:
    """The trainer's ``checkpoints/episode_N`` folders, by episode (temporary ``.episode_N.tmp`` ones excluded)."""
    return sorted((int(path.name.removeprefix("episode_")), path)
                  for path in (run_dir / "checkpoints").glob("episode_*") if path.is_dir())


def trainer_for_run(run_dir: Path, scratch: str, threads: int | None = None) -> MPAIL2Trainer:
    """A trainer rebuilt from ``run_dir/config.json`` whose own files go to ``scratch`` (the run folder is only read)."""
    cfg = apply_overrides(ExperimentConfig.from_dict(json.loads((run_dir / "config.json").read_text())),
                          ["train.progress=false", "train.logger=none", f"train.run_dir={scratch}/eval",
                           *([f"train.threads={threads}"] if threads else [])])
    return MPAIL2Trainer(cfg)


def evaluate_run(run_dir: Path, episodes: int, threads: int | None = None) -> dict:
    checkpoints = numbered_checkpoints(run_dir)
    if not checkpoints:
        raise SystemExit(f"no numbered checkpoints under {run_dir / 'checkpoints'}")
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        trainer = trainer_for_run(run_dir, scratch, threads)
        cfg = trainer.cfg
        for episode, path in tqdm(checkpoints, desc="checkpoints"):
            trainer.load(path, with_replay=False)
            if getattr(trainer, "eval_env", None) is not None:  # a fresh env: the same episodes for every checkpoint
                trainer.eval_env.close()
            trainer.eval_env = None
            torch.manual_seed(cfg.train.seed + 10_000)
            start = time.perf_counter()
            rows.append({"episode": episode, "checkpoint": path.name, **trainer.evaluate(episodes),
                         "seconds": time.perf_counter() - start})
            tqdm.write(json.dumps(rows[-1]))
    best = max(rows, key=lambda r: (r["success_rate_any_step"], r["success_rate"]))
    return {"run": run_dir.name, "episodes_per_checkpoint": episodes, "checkpoints": rows,
            "best_success_rate": max(r["success_rate"] for r in rows),
            "best_success_rate_any_step": best["success_rate_any_step"], "best_checkpoint": best["checkpoint"]}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_dir", type=Path)
    p.add_argument("--episodes", type=int, default=10)
    p.add_argument("--threads", type=int, default=None)
    p.add_argument("--name", help="also write docs/results/<name>_checkpoints.json")
    args = p.parse_args()
    if args.episodes <= 0:
        raise SystemExit("--episodes must be > 0")
    result = evaluate_run(args.run_dir, args.episodes, args.threads)
    (args.run_dir / "checkpoint_evals.json").write_text(json.dumps(result, indent=2))
    if args.name:
        (RESULTS / f"{args.name}_checkpoints.json").write_text(json.dumps(result, indent=2))
    print(json.dumps({k: v for k, v in result.items() if k != "checkpoints"}, indent=2))


if __name__ == "__main__":
    main()
