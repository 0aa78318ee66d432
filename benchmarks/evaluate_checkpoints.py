"""Evaluate every saved checkpoint of a run, the paper's protocol for its Best figures (Appendix: "Best
checkpoints are selected by evaluating all automatically saved checkpoints").

    python benchmarks/evaluate_checkpoints.py RUN_DIR [--episodes 10] [--name lift_state_tpw1] [--acting random]

Loads each numbered checkpoint's agent on its own (:meth:`MPAIL2Agent.from_checkpoint`: no trainer, no replay;
the run folder is only read) and plays ``--episodes`` deterministic episodes of the fixed evaluation set
(``train.eval_seed + i``, the planner's noise seeded per episode: the same episodes as the run's own evaluations).
``--acting random`` plays the action sampled around the plan's mean, as in training (same episodes, same seeded noise
generator). Writes ``RUN_DIR/checkpoint_evals.json`` (``checkpoint_evals_random.json``) and, with ``--name``, ``docs/results/diary/<name>_checkpoints.json``: success
at the last step, success at any step (the paper's definition) and the task return per checkpoint.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch
from tqdm import tqdm

from torchrl_mpail2.agents import MPAIL2Agent
from torchrl_mpail2.trainers.evaluation import (ACTING, evaluate_episodes, evaluation_env, evaluation_seeds,
                                                run_eval_seed, summarize_outcomes)

RESULTS = Path(__file__).resolve().parents[1] / "docs" / "results" / "diary"


def numbered_checkpoints(run_dir: Path) -> list[tuple[int, Path]]:
    """The trainer's ``checkpoints/episode_N`` folders, by episode (temporary ``.episode_N.tmp`` ones excluded)."""
    return sorted((int(path.name.removeprefix("episode_")), path)
                  for path in (run_dir / "checkpoints").glob("episode_*") if path.is_dir())


def run_env(run_dir: Path):
    """The run's evaluation environment, rebuilt from ``run_dir/config.json`` (:func:`evaluation_env`)."""
    train = json.loads((run_dir / "config.json").read_text())["train"]
    return evaluation_env(train), train


def evaluate_run(run_dir: Path, episodes: int, threads: int | None = None, acting: str = "deterministic") -> dict:
    checkpoints = numbered_checkpoints(run_dir)
    if not checkpoints:
        raise SystemExit(f"no numbered checkpoints under {run_dir / 'checkpoints'}")
    if threads:
        torch.set_num_threads(threads)
    env, train = run_env(run_dir)
    seeds = evaluation_seeds(run_eval_seed(train), episodes)
    rows = []
    for episode, path in tqdm(checkpoints, desc="checkpoints"):
        agent = MPAIL2Agent.from_checkpoint(path, env)
        start = time.perf_counter()
        outcomes = evaluate_episodes(env, agent.policy, seeds, agent.planner, acting=acting)
        rows.append({"episode": episode, "checkpoint": path.name, **summarize_outcomes(outcomes),
                     "seconds": time.perf_counter() - start})
        tqdm.write(json.dumps(rows[-1]))
    env.close()
    best = max(rows, key=lambda r: (r["success_rate_any_step"], r["success_rate"]))
    return {"run": run_dir.name, "acting": acting, "episodes_per_checkpoint": episodes, "first_eval_seed": seeds[0], "checkpoints": rows,
            "best_success_rate": max(r["success_rate"] for r in rows),
            "best_success_rate_any_step": best["success_rate_any_step"], "best_checkpoint": best["checkpoint"]}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_dir", type=Path)
    p.add_argument("--episodes", type=int, default=10)
    p.add_argument("--threads", type=int, default=None)
    p.add_argument("--name", help="also write docs/results/diary/<name>_checkpoints.json")
    p.add_argument("--acting", choices=sorted(ACTING), default="deterministic",
                   help="the plan's mean (the runs' own evaluations) or the action sampled around it as in training")
    args = p.parse_args()
    if args.episodes <= 0:
        raise SystemExit("--episodes must be > 0")
    result = evaluate_run(args.run_dir, args.episodes, args.threads, args.acting)
    suffix = "" if args.acting == "deterministic" else f"_{args.acting}"
    (args.run_dir / f"checkpoint_evals{suffix}.json").write_text(json.dumps(result, indent=2))
    if args.name:
        (RESULTS / f"{args.name}_checkpoints{suffix}.json").write_text(json.dumps(result, indent=2))
    print(json.dumps({k: v for k, v in result.items() if k != "checkpoints"}, indent=2))


if __name__ == "__main__":
    main()
