"""Evaluate every saved checkpoint of a run, the paper's protocol for its Best figures (Appendix: "Best
checkpoints are selected by evaluating all automatically saved checkpoints (every 10 episodes) beyond where the
learner generally begins to exhibit successes").

    python -m benchmarks.learning.evaluate_checkpoints RUN_DIR [--episodes N] [--from-episode 100] [--held-out 50]
        [--name lift_state_tpw1] [--acting random]

Loads each numbered checkpoint's agent on its own (:meth:`MPAIL2Agent.from_checkpoint`: no trainer, no replay;
the run folder is only read) and plays ``--episodes`` (default: the run's ``train.eval_episodes``) deterministic
episodes of the fixed evaluation set (``train.eval_seed + i``, the planner's noise seeded per episode: the same
episodes as the run's own evaluations, in the env the run evaluated in). A checkpoint the run evaluated itself on
the same episodes, acting as asked now (``train.eval_acting``), is not played again: its row is read from
``eval.jsonl`` (``"source": "run"``).

The Best of many checkpoints scored on the same 20 episodes is the maximum of many noisy figures, so it is biased
upwards (16 independent 20-episode scores of a true 0.6 have an expected maximum of 0.79, and reach 0.8 in 57% of
draws; 6 of them 0.74). ``--held-out N`` scores the chosen
checkpoint once more on ``N`` other episodes (seeds ``train.eval_seed + HELD_OUT_SEED_OFFSET + i``), which it was
not chosen on: an unbiased figure for the Best checkpoint; the last checkpoint, chosen by nothing, is scored there too
(``held_out_last``), which shows how far the held-out episodes and the fixed ones differ without a choice.

Writes ``RUN_DIR/checkpoint_evals.json`` (``checkpoint_evals_random.json``) after every checkpoint, and resumes from
it (a row, or a held-out score of the same checkpoint on as many episodes, is reused when the episodes, acting,
first seed and ``--from-episode`` match). Every held-out score ever played for that header stays in the file
(``held_out_scores``), a call without ``--held-out`` included, which then reports the earlier scores of its Best and
last checkpoints; with ``--name`` also
``docs/results/diary/<name>_checkpoints.json``: success at the last step, success at any step (the paper's
definition) and the task return per checkpoint.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch
from tqdm import tqdm

from benchmarks.records import ROOT
from torchrl_mpail2.agents import MPAIL2Agent
from torchrl_mpail2.data.checkpoint import numbered_checkpoints
from torchrl_mpail2.trainers.evaluation import (ACTING, HELD_OUT_SEED_OFFSET, evaluate_episodes,
                                                evaluation_seeds, run_eval_seed, run_evaluation_env, summarize_outcomes)
from torchrl_mpail2.trainers.plots import EVAL_FILE, read_jsonl

RESULTS = ROOT / "docs" / "results" / "diary"


def _runs_own_rows(run_dir: Path, episodes: int) -> dict[int, dict]:
    """The run's own evaluations (``eval.jsonl``) of ``episodes`` episodes, by training episode: the fixed set,
    played as the run's ``train.eval_acting`` says."""
    return {row["episode"]: row for row in read_jsonl(run_dir / EVAL_FILE)
            if row.get("episodes") == episodes and "success_any_step_per_episode" in row}


def _play(path: Path, env, seeds: list[int], acting: str) -> dict:
    """The checkpoint at ``path`` playing one episode per seed: :func:`summarize_outcomes` and the seconds taken."""
    agent = MPAIL2Agent.from_checkpoint(path, env)
    start = time.perf_counter()
    outcomes = evaluate_episodes(env, agent.policy, seeds, agent.planner, acting=acting)
    return {**summarize_outcomes(outcomes), "seconds": time.perf_counter() - start}


def _earlier_result(out: Path, header: dict) -> dict:
    """An earlier (possibly interrupted) evaluation written to ``out`` with the same ``header``, or ``{}``."""
    if not out.exists():
        return {}
    try:
        earlier = json.loads(out.read_text())
    except json.JSONDecodeError:
        return {}
    return earlier if all(earlier.get(key) == value for key, value in header.items()) else {}


def _write_atomically(out: Path, result: dict) -> None:
    """``out`` holds either the previous result or this one, never a torn file."""
    tmp = out.with_name(f".{out.name}.tmp")
    tmp.write_text(json.dumps(result, indent=2))
    tmp.replace(out)


def _summary(header: dict, rows: list[dict]) -> dict:
    best = max(rows, key=lambda r: (r["success_rate_any_step"], r["success_rate"]))
    return {**header, "checkpoints": rows, "best_success_rate": max(r["success_rate"] for r in rows),
            "best_success_rate_any_step": best["success_rate_any_step"], "best_checkpoint": best["checkpoint"],
            "best_episode": best["episode"]}


def evaluate_run(run_dir: Path, episodes: int | None = None, threads: int | None = None,
                 acting: str = "deterministic", from_episode: int = 0, held_out: int = 0,
                 out: Path | None = None, reuse_run_evals: bool = True, only_evaluated: bool = False) -> dict:
    """Scores every numbered checkpoint from ``from_episode`` on (see the module's docstring); with ``out``, writes
    the result there after each checkpoint and reuses the rows of an interrupted evaluation found there;
    ``reuse_run_evals=False`` plays the checkpoints the run evaluated itself again too; ``only_evaluated`` keeps only
    those (nothing is replayed on the fixed episodes: the Best is the run's own, and only ``held_out`` plays)."""
    checkpoints = [(e, path) for e, path in numbered_checkpoints(run_dir) if e >= from_episode]
    if not checkpoints:
        raise SystemExit(f"no numbered checkpoints from episode {from_episode} under {run_dir / 'checkpoints'}")
    if threads:
        torch.set_num_threads(threads)
    env, train = run_evaluation_env(run_dir)
    episodes = episodes or train["eval_episodes"]
    seeds = evaluation_seeds(run_eval_seed(train), episodes)
    header = {"run": run_dir.name, "acting": acting, "episodes_per_checkpoint": episodes, "first_eval_seed": seeds[0],
              "from_episode": from_episode, **({"only_evaluated": True} if only_evaluated else {})}
    earlier = _earlier_result(out, header) if out is not None else {}
    known = {row["episode"]: row for row in earlier.get("checkpoints", [])}
    # held-out scores of earlier calls, by (checkpoint, episodes): played once, however often this is called, and
    # kept in the file whatever this call asks for
    scored = {(h["checkpoint"], h["episodes"]): h
              for h in [*earlier.get("held_out_scores", []), earlier.get("held_out"), earlier.get("held_out_last")] if h}
    # the run's own evaluations count only if they acted as asked now (``train.eval_acting``)
    own = _runs_own_rows(run_dir, episodes) if reuse_run_evals and train.get("eval_acting", "deterministic") == acting else {}
    if only_evaluated:
        checkpoints = [(e, path) for e, path in checkpoints if e in own]
        if not checkpoints:
            raise SystemExit(f"{run_dir}: no checkpoint from episode {from_episode} that the run evaluated itself on "
                             f"{episodes} episodes acting {acting!r}")
    rows = []
    try:
        for episode, path in tqdm(checkpoints, desc="checkpoints"):
            if episode in known:
                rows.append(known[episode])
                continue
            if episode in own:
                rows.append({"episode": episode, "checkpoint": path.name, "source": "run",
                             **{k: own[episode][k] for k in ("success_rate_any_step", "success_rate", "return",
                                                              "episodes", "success_any_step_per_episode")}})
            else:
                rows.append({"episode": episode, "checkpoint": path.name, "source": "re-evaluated",
                             **_play(path, env, seeds, acting)})
            tqdm.write(json.dumps({k: v for k, v in rows[-1].items() if k != "success_any_step_per_episode"}))
            if out is not None:
                _write_atomically(out, _summary(header, rows))
        result = _summary(header, rows)

        def held_out_score(checkpoint: str) -> dict | None:
            """Played on ``held_out`` episodes if asked for; without ``--held-out``, the score of an earlier call on
            the most episodes, if any."""
            if held_out:
                if (checkpoint, held_out) not in scored:
                    scored[checkpoint, held_out] = score_held_out(run_dir, checkpoint, env, train, held_out, acting)
                return scored[checkpoint, held_out]
            earlier_scores = [h for (c, _), h in scored.items() if c == checkpoint]
            return max(earlier_scores, key=lambda h: h["episodes"]) if earlier_scores else None

        # the Best checkpoint, and the last one, chosen by nothing: how far the fixed episodes and held-out ones differ
        # without a choice
        for key, checkpoint in (("held_out", result["best_checkpoint"]), ("held_out_last", rows[-1]["checkpoint"])):
            if (score := held_out_score(checkpoint)) is not None:
                result[key] = score
        if scored:
            result["held_out_scores"] = sorted(scored.values(), key=lambda h: (h["checkpoint"], h["episodes"]))
    finally:
        env.close()
    if out is not None:
        _write_atomically(out, result)
    return result


def score_held_out(run_dir: Path, checkpoint: str, env, train: dict, episodes: int, acting: str) -> dict:
    """``checkpoint`` scored on ``episodes`` held-out episodes (seeds from ``eval_seed + HELD_OUT_SEED_OFFSET``)."""
    seeds = evaluation_seeds(run_eval_seed(train) + HELD_OUT_SEED_OFFSET, episodes)
    return {"checkpoint": checkpoint, "first_seed": seeds[0],
            **_play(run_dir / "checkpoints" / checkpoint, env, seeds, acting)}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_dir", type=Path)
    p.add_argument("--episodes", type=int, default=None, help="episodes per checkpoint (default: the run's own)")
    p.add_argument("--from-episode", type=int, default=0,
                   help="leave out checkpoints before this training episode (the paper's 'beyond where the learner "
                        "begins to exhibit successes')")
    p.add_argument("--held-out", type=int, default=0, metavar="N",
                   help="score the Best checkpoint once more on N episodes it was not chosen on")
    p.add_argument("--only-evaluated", action="store_true",
                   help="only the checkpoints the run evaluated itself (nothing replayed on the fixed episodes)")
    p.add_argument("--threads", type=int, default=None)
    p.add_argument("--name", help="also write docs/results/diary/<name>_checkpoints.json")
    p.add_argument("--acting", choices=sorted(ACTING), default="deterministic",
                   help="the plan's mean (the runs' own evaluations) or the action sampled around it as in training")
    args = p.parse_args()
    for flag in ("episodes", "held_out", "from_episode"):
        value = getattr(args, flag)
        if value is not None and value < (1 if flag == "episodes" else 0):
            raise SystemExit(f"--{flag.replace('_', '-')} must be {'> 0' if flag == 'episodes' else '>= 0'}, got {value}")
    if not (args.run_dir / "config.json").exists():
        raise SystemExit(f"{args.run_dir} is not a run folder: it has no config.json")
    suffix = "" if args.acting == "deterministic" else f"_{args.acting}"
    out = args.run_dir / f"checkpoint_evals{suffix}.json"
    result = evaluate_run(args.run_dir, args.episodes, args.threads, args.acting, args.from_episode, args.held_out,
                          out=out, only_evaluated=args.only_evaluated)
    if args.name:
        (RESULTS / f"{args.name}_checkpoints{suffix}.json").write_text(json.dumps(result, indent=2))
    print(json.dumps({k: v for k, v in result.items() if k != "checkpoints"}, indent=2))


if __name__ == "__main__":
    main()
