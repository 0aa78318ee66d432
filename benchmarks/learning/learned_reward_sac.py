"""TorchRL's own SAC trained on MPAIL2's learned reward alone (no task reward), on the point mass.

    python -m benchmarks.learning.learned_reward_sac [--checkpoint RUN/checkpoints/best] [--seeds 0 1 2] [--frames 6000]

Without ``--checkpoint`` it first trains MPAIL2 on the point mass (preset ``point_mass``, about two minutes) in a
scratch folder. Then, per seed, ``SACLoss`` learns from ``("next", "learned_reward")`` written by
:class:`~torchrl_mpail2.agents.LearnedRewardTransform`; the task reward is only logged. Each SAC actor (its mean),
SAC on the same networks untrained (the control, for the first ``--controls`` seeds) and a uniform random policy
play the same 20 fixed evaluation episodes (env seeds ``2_000_000 + i``). Writes
``docs/results/diagnostics/learned_reward_sac.json``: success at any step and at the last step per seed, their means, the
MPAIL2 checkpoint's own evaluation, and wall times.
"""
from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from pathlib import Path

import torch
from torchrl.envs import TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type

from benchmarks.records import ROOT
from torchrl_mpail2.agents import LearnedRewardTransform
from torchrl_mpail2.envs import make_env
from torchrl_mpail2.experts.sac import fit_sac
from torchrl_mpail2.modules import make_mpail2_modules
from torchrl_mpail2.trainers import MPAIL2Trainer, TrainConfig, apply_overrides, preset
from torchrl_mpail2.trainers.evaluation import evaluate_episodes, evaluation_seeds, summarize_outcomes

RESULTS = ROOT / "docs" / "results" / "diagnostics"
EVAL_SEED = TrainConfig().eval_seed  # the fixed evaluation episodes of every run


def train_mpail2(run_dir: Path, episodes: int, seed: int = 0) -> Path:
    """A point-mass MPAIL2 run; returns its ``best`` checkpoint."""
    cfg = apply_overrides(preset("point_mass"), {"train.progress": False, "train.logger": "none", "train.seed": seed,
                                                 "train.total_episodes": episodes, "train.run_dir": str(run_dir)})
    MPAIL2Trainer(cfg).train()
    return run_dir / "checkpoints" / "best"


def success(env, actor, episodes: int) -> dict:
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        return summarize_outcomes(evaluate_episodes(env, actor, evaluation_seeds(EVAL_SEED, episodes)))


def untrained_reward(seed: int) -> LearnedRewardTransform:
    """The control: the same encoder and reward networks at their initialisation (nothing learned)."""
    torch.manual_seed(seed)
    env = make_env("point_mass")
    modules = make_mpail2_modules(env.observation_spec, env.action_spec, preset("point_mass").model)
    return LearnedRewardTransform(modules.encoder, modules.reward)


def sac_on_learned_reward(checkpoint: Path | None, seed: int, frames: int, warmup: int, episodes: int) -> dict:
    """SAC on the checkpoint's reward (``checkpoint=None``: on an untrained one, the control)."""
    transform = LearnedRewardTransform.from_checkpoint(checkpoint) if checkpoint else untrained_reward(seed)
    torch.manual_seed(seed)
    env = TransformedEnv(make_env("point_mass", seed=seed), transform)
    start = time.perf_counter()
    actor = fit_sac(env, frames, reward_key="learned_reward", warmup=warmup, progress=False)
    return {"seed": seed, "frames": frames, "train_seconds": time.perf_counter() - start,
            **success(make_env("point_mass"), actor, episodes)}


def run(checkpoint: Path, seeds: list[int], frames: int, warmup: int, episodes: int, controls: int = 0) -> dict:
    rows, control_rows = [], []
    for index, seed in enumerate(seeds):
        rows.append(sac_on_learned_reward(checkpoint, seed, frames, warmup, episodes))
        print(json.dumps({k: v for k, v in rows[-1].items() if k != "success_any_step_per_episode"}), flush=True)
        if index < controls:
            control_rows.append(sac_on_learned_reward(None, seed, frames, warmup, episodes))
            print("control", json.dumps({k: v for k, v in control_rows[-1].items()
                                         if k != "success_any_step_per_episode"}), flush=True)
    random_policy = success(make_env("point_mass"), None, episodes)
    mean = lambda key: sum(r[key] for r in rows) / len(rows)  # noqa: E731
    return {"task": "point_mass", "reward_key": "learned_reward",
            "eval_episodes": episodes, "first_eval_seed": EVAL_SEED, "seeds": seeds, "sac": rows,
            "sac_success_any_step_mean": mean("success_rate_any_step"), "sac_success_last_step_mean": mean("success_rate"),
            "random_policy_success_any_step": random_policy["success_rate_any_step"],
            "untrained_reward_control": control_rows,
            "machine": {"cpu": platform.processor() or platform.machine(), "threads": torch.get_num_threads()}}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--checkpoint", type=Path, help="an MPAIL2 point-mass checkpoint (default: train one first)")
    p.add_argument("--mpail2-episodes", type=int, default=40)
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--frames", type=int, default=6000)
    p.add_argument("--warmup", type=int, default=1000)
    p.add_argument("--episodes", type=int, default=20, help="evaluation episodes")
    p.add_argument("--controls", type=int, default=1,
                   help="also train SAC on an untrained reward network for the first N seeds (the control)")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--out", type=Path, default=Path("runs") / "benchmarks" / "learned_reward_sac.json",
                   help=f"where the record goes (the docs' copy: {RESULTS.relative_to(RESULTS.parents[2])}/"
                        "learned_reward_sac.json)")
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    with tempfile.TemporaryDirectory() as scratch:
        start = time.perf_counter()
        checkpoint = args.checkpoint or train_mpail2(Path(scratch) / "mpail2", args.mpail2_episodes)
        mpail2_seconds = time.perf_counter() - start
        state = torch.load(checkpoint / "state.pt", weights_only=False)
        result = run(checkpoint, args.seeds, args.frames, args.warmup, args.episodes, args.controls)
    # the checkpoint as given, never a temporary folder of this machine
    result["checkpoint"] = str(args.checkpoint) if args.checkpoint else "trained afresh (point_mass preset)"
    result["mpail2_train_seconds"] = None if args.checkpoint else mpail2_seconds
    result["mpail2_best_eval"] = {"success_any_step": state["best_eval"][0], "success_last_step": state["best_eval"][1]}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2))
    print(json.dumps({k: v for k, v in result.items() if k != "sac"}, indent=2))


if __name__ == "__main__":
    main()
