"""Does a Lift run's learned objective prefer to keep a grasped cube? One number per saved checkpoint.

    python -m torchrl_mpail2.diagnostics grasp_preference RUN_DIR [--states 64] [--out F.json]

From the run's replay buffer it draws ``--states`` observations where the cube is grasped but not lifted (Lift's
shaped task reward, scaled to [0, 1] by robosuite: reach alone is at most 1/2.25, grasping adds 0.25/2.25, a
lifted cube gives 1). At each numbered checkpoint it takes the deterministic planner's plan from those states and
scores two copies with the planner's own return (learned reward over H steps plus the Q terminal value): one with
the gripper command held at +1 (close) and one at -1 (open) for all H steps. Robosuite's Panda gripper moves by
the sign of the command, so a planner whose return prefers -1 here lets the cube go.

Writes ``RUN_DIR/grasp_preference.json`` and, with ``--out``, a copy to that file:
per checkpoint, the mean return difference (close minus open) split into its learned-reward part (H discounted
steps) and its terminal-value part, the fraction of states that prefer closing, the
quartiles of the planned first gripper command, and the evaluation success from ``checkpoint_evals.json`` if
``benchmarks/learning/evaluate_checkpoints.py`` has run.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchrl_mpail2.agents import MPAIL2Agent
from torchrl_mpail2.data.checkpoint import numbered_checkpoints
from torchrl_mpail2.modules.value import HEADS_PER_ESTIMATE
from torchrl_mpail2.trainers.evaluation import run_evaluation_env

GRASPED, LIFTED = 0.45, 0.99  # task-reward bounds of "grasped, not lifted" (see the module docstring)
GRIPPER = -1  # the gripper command is the last action dimension


def grasped_states(run_dir: Path, keys: list[str], count: int, seed: int = 0) -> TensorDict:
    replay = TensorDict.load_memmap(run_dir / "replay_storage")
    reward = replay["next", "task_reward"].reshape(-1)  # rows not written yet hold zeros: never selected
    index = torch.nonzero((reward >= GRASPED) & (reward < LIFTED)).squeeze(-1)
    if index.numel() == 0:
        raise SystemExit(f"no grasped-but-not-lifted states in {run_dir / 'replay_storage'}")
    index = index[torch.randperm(index.numel(), generator=torch.Generator().manual_seed(seed))[:count]]
    return replay[index].select(*keys).clone()


@torch.no_grad()
def preference(agent: MPAIL2Agent, states: TensorDict) -> dict:
    planner, heads = agent.planner, torch.arange(HEADS_PER_ESTIMATE)
    planner.reset()  # no warm start: each state is planned from a zero mean, whatever ran before
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        plan = planner(states.clone())["plan"]
    z = agent.modules.encoder.encode(states)
    returns, rewards = {}, {}
    for command in (1.0, -1.0):
        held = plan.clone()
        held[..., GRIPPER] = command
        reward_part, terminal_part = planner.score_parts(z, held.unsqueeze(1), heads)
        returns[command], rewards[command] = (reward_part + terminal_part).squeeze(1), reward_part.squeeze(1)
    difference = returns[1.0] - returns[-1.0]
    reward_difference = rewards[1.0] - rewards[-1.0]
    quartiles = torch.quantile(plan[:, 0, GRIPPER], torch.tensor([0.25, 0.5, 0.75]))
    return {"close_minus_open": difference.mean().item(), "fraction_prefer_close": (difference > 0).float().mean().item(),
            "reward_part": reward_difference.mean().item(),
            "terminal_value_part": (difference - reward_difference).mean().item(),
            "planned_gripper_quartiles": [round(q, 3) for q in quartiles.tolist()]}


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_dir", type=Path)
    p.add_argument("--states", type=int, default=64)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--out", type=Path, help="also write the result to this JSON file")
    args = p.parse_args(argv)
    evals_path = args.run_dir / "checkpoint_evals.json"
    evals = {r["checkpoint"]: r for r in json.loads(evals_path.read_text())["checkpoints"]} if evals_path.exists() else {}
    rows = []
    torch.set_num_threads(args.threads)
    env, _ = run_evaluation_env(args.run_dir)
    checkpoints = numbered_checkpoints(args.run_dir)
    if not checkpoints:
        raise SystemExit(f"no numbered checkpoints under {args.run_dir / 'checkpoints'}")
    states = None
    for episode, path in checkpoints:
        agent = MPAIL2Agent.from_checkpoint(path, env)
        if agent.planner is None:
            raise SystemExit("this run has no planner (a model-free ablation)")
        if states is None:
            states = grasped_states(args.run_dir, list(agent.modules.encoder.in_keys), args.states)
        torch.manual_seed(0)
        row = {"episode": episode, **preference(agent, states)}
        if path.name in evals:
            row.update({k: evals[path.name][k] for k in ("success_rate", "success_rate_any_step")})
        rows.append(row)
        print(json.dumps(row))
    env.close()
    result = {"run": args.run_dir.name, "states": int(states.shape[0]), "checkpoints": rows}
    (args.run_dir / "grasp_preference.json").write_text(json.dumps(result, indent=2))
    if args.out:
        args.out.write_text(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
