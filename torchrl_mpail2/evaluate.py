"""Command line: score a trained agent on held-out episodes, or export it as a small agent-only checkpoint.

    python -m torchrl_mpail2.evaluate CHECKPOINT [--episodes 50] [--fixed] [--acting deterministic] [--out FILE]
    python -m torchrl_mpail2.evaluate CHECKPOINT --export DIR

``CHECKPOINT`` is a checkpoint folder: a run's ``RUN/checkpoints/last`` (``best``, ``episode_N``) or a shipped agent
(``shipped/push_state``, see ``shipped/README.md``). The agent is loaded on its own
(:meth:`~torchrl_mpail2.agents.MPAIL2Agent.from_checkpoint`: no trainer, no replay, no demonstrations) and plays
``--episodes`` deterministic episodes in the environment its run was trained in, rebuilt from the config the
checkpoint holds. By default those are the held-out episodes (seeds ``train.eval_seed + HELD_OUT_SEED_OFFSET + i``),
on which nothing was ever chosen, the same episodes as the learning summaries' held-out scores; ``--fixed`` plays
the run's fixed evaluation episodes instead (``train.eval_seed + i``, what its own evaluations played). It prints
the any-step success (the paper's metric) with a 95% bootstrap interval over the episodes, and writes them as
JSON with ``--out``.

``--export DIR`` writes the agent alone (networks, loss state, planner state, config; no optimisers, replay or
random states) as a checkpoint folder with a sha256 manifest: what ``shipped/`` holds.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch

from torchrl_mpail2.agents import MPAIL2Agent
from torchrl_mpail2.agents.mpail2 import run_config_of
from torchrl_mpail2.data import checkpoint as ckpt
from torchrl_mpail2.trainers.evaluation import (ACTING, HELD_OUT_SEED_OFFSET, evaluate_episodes, evaluation_env,
                                                evaluation_seeds, run_eval_seed, summarize_outcomes)
from torchrl_mpail2.trainers.intervals import bootstrap_ci

__all__ = ["AGENT_KEYS", "LOCAL_PATHS", "evaluate_checkpoint", "export_agent"]

#: What an agent-only checkpoint keeps of a training checkpoint: all :meth:`MPAIL2Agent.from_checkpoint` reads,
#: and what the run had done when it was written.
AGENT_KEYS = ("modules", "loss", "planner", "observation_keys", "config", "counters", "best_eval", "run_wall_s",
              "demos_sha256")


#: Fields of the ``train`` section an exported agent leaves empty: folders of the machine it was trained on.
LOCAL_PATHS = ("run_dir", "demos")


def evaluate_checkpoint(path: str | Path, episodes: int = 50, *, held_out: bool = True,
                        acting: str = "deterministic", threads: int | None = None, progress: bool = False) -> dict:
    """Plays the agent of the checkpoint at ``path`` for ``episodes`` episodes of its run's environment.

    Args:
        path: a checkpoint folder (a run's, or an agent-only one of :func:`export_agent`).
        episodes (int): episodes to play. Defaults to 50 (the paper's trials).
        held_out (bool): the held-out episodes (default) or the run's fixed evaluation episodes.
        acting (str): ``deterministic`` (the plan's mean, as every evaluation here) or ``random`` (sampled around it).
        threads (int, optional): torch threads.
        progress (bool): a progress bar over the episodes. Defaults to False.

    Returns:
        dict: ``success_rate_any_step`` with its 95% bootstrap interval ``success_any_step_ci``, ``success_rate``
        (at the last step), ``return``, the per-episode successes, the seeds, the checkpoint's training episodes and
        the seconds taken.

    Raises:
        CheckpointError: the checkpoint is missing or damaged (the message names the file).
        ValueError: ``episodes`` < 1.
    """
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    if threads:
        torch.set_num_threads(threads)
    path = Path(path)
    state = ckpt.read_checkpoint(path)  # read once: the run's config builds the env, the agent takes its specs from it
    train = run_config_of(state, path)["train"]
    first_seed = run_eval_seed(train) + (HELD_OUT_SEED_OFFSET if held_out else 0)
    seeds = evaluation_seeds(first_seed, episodes)
    env = evaluation_env(train)
    try:
        agent = MPAIL2Agent.from_state(state, env, source=path)
        start = time.perf_counter()
        outcomes = evaluate_episodes(env, agent.policy, seeds, agent.planner, acting=acting, progress=progress)
    finally:
        env.close()
    summary = summarize_outcomes(outcomes)
    low, high = bootstrap_ci([summary["success_any_step_per_episode"]])
    return {"checkpoint": str(path), "env": train["env"], "obs": train["obs"],
            "trained_episodes": ckpt.checkpoint_episodes(path), "episodes_set": "held_out" if held_out else "fixed",
            "first_seed": first_seed, "acting": acting, **summary, "success_any_step_ci": [low, high],
            "seconds": time.perf_counter() - start}


def export_agent(source: str | Path, out: str | Path) -> Path:
    """Writes the agent of the checkpoint ``source`` alone (:data:`AGENT_KEYS`) as the checkpoint folder ``out``,
    its config without the training machine's folders (:data:`LOCAL_PATHS`).

    Raises:
        CheckpointError: ``source`` is missing or damaged, or holds no agent (the message names what it lacks).
        FileExistsError: ``out`` already holds files.
    """
    out = Path(out)
    if out.exists() and any(out.iterdir()):
        raise FileExistsError(f"{out} already holds files: export into a new folder")
    state = ckpt.read_checkpoint(Path(source))
    missing = [key for key in ("modules", "loss", "config") if key not in state]
    if missing:
        raise ckpt.CheckpointError(f"{source} holds no agent: it lacks {missing}")
    agent = {key: state[key] for key in AGENT_KEYS if key in state}
    # this machine's folders mean nothing elsewhere (the demonstrations stay identified by their sha256)
    agent["config"] = {**agent["config"], "train": {**agent["config"]["train"], **dict.fromkeys(LOCAL_PATHS)}}
    return ckpt.write_checkpoint(out, agent)


def _describe(result: dict) -> str:
    low, high = result["success_any_step_ci"]
    return (f"{result['env']} ({result['obs']}), checkpoint at {result['trained_episodes']} episodes, "
            f"{result['episodes']} {result['episodes_set'].replace('_', '-')} episodes: any-step success "
            f"{result['success_rate_any_step']:.2f} (95% interval {low:.2f}-{high:.2f}), last-step "
            f"{result['success_rate']:.2f}, return {result['return']:.1f}, {result['seconds']:.0f} s")


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("checkpoint", type=Path, help="a checkpoint folder (RUN/checkpoints/last, shipped/NAME)")
    p.add_argument("--episodes", type=int, default=50, help="episodes to play (default 50)")
    p.add_argument("--fixed", action="store_true", help="the run's fixed evaluation episodes, not the held-out ones")
    p.add_argument("--acting", choices=sorted(ACTING), default="deterministic")
    p.add_argument("--threads", type=int, default=None)
    p.add_argument("--out", type=Path, help="also write the result as JSON to this file")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--export", type=Path, metavar="DIR", help="write the agent alone to DIR instead of playing")
    args = p.parse_args(argv)
    if args.episodes < 1:
        p.error(f"--episodes must be >= 1, got {args.episodes}")
    try:
        if args.export:
            out = export_agent(args.checkpoint, args.export)
            size = sum(f.stat().st_size for f in out.iterdir())
            print(f"wrote {out} ({size / 1e6:.2f} MB)")
            return
        result = evaluate_checkpoint(args.checkpoint, args.episodes, held_out=not args.fixed, acting=args.acting,
                                     threads=args.threads, progress=not args.quiet)
    except (ckpt.CheckpointError, FileExistsError) as error:
        print(f"error: {error}", file=sys.stderr)
        raise SystemExit(2) from None
    print(_describe(result))
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
