"""Is the value low after a lift whatever the action, or only for the policy's action? Q at held Lift states and
at the states a plan reaches from them in the simulator.

    python -m torchrl_mpail2.diagnostics held_value_probe CKPT [--episodes 8] [--outcome succeeded|failed] [--out F.json]

Plays the run's first ``--episodes`` fixed evaluation episodes with the checkpoint (as
``python -m torchrl_mpail2.diagnostics held_plans``), keeps those of ``--outcome``, and from every 10th held state
replays the episode to that state and holds one of three actions for H steps with the gripper closing: straight up,
still, straight down. At the held state and at each plan's end state it reports, over the tested states, the mean
of the five heads of Q for the policy's mean first action and for four fixed actions (hold still, up, down, open),
and the spread of the heads for the policy's action (std, highest and lowest head). A value that is low after a
straight lift for every action and on every head rates the state itself low, not the policy's choice there.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from torchrl_mpail2.diagnostics.held_replays import GRIPPER_CLOSING, episode_outcome, played_paths, tested_steps
from torchrl_mpail2.diagnostics.lift_phases import play_lift_episodes
from torchrl_mpail2.trainers.evaluation import evaluation_env, evaluation_seeds, run_eval_seed

FIXED = {"hold": (0.0, 0.0, 0.0, GRIPPER_CLOSING), "up": (0.0, 0.0, 1.0, GRIPPER_CLOSING),
         "down": (0.0, 0.0, -1.0, GRIPPER_CLOSING), "open": (0.0, 0.0, 0.0, -GRIPPER_CLOSING)}
PLANS = {"after_up": "up", "after_still": "hold", "after_down": "down"}


def values_at(agent, z: torch.Tensor) -> dict:
    """Q of the policy's action (mean, std, highest and lowest of the heads) and of each :data:`FIXED` action."""
    m = agent.modules
    with torch.inference_mode():
        heads = m.value.net(z, m.policy.net(z, deterministic=True)[0][:, 0]).squeeze(-1)[:, 0]
        row = {"pi": heads.mean().item(), "pi_head_std": heads.std().item(), "pi_head_max": heads.max().item(),
               "pi_head_min": heads.min().item()}
        for name, action in FIXED.items():
            row[name] = m.value.net(z, torch.tensor([action])).squeeze(-1).mean().item()
    return row


def probe(path: str, episodes: int, outcome: str) -> dict:
    agent, rollouts = play_lift_episodes(path, episodes)
    train = agent.run_config["train"]
    env = evaluation_env(train)
    encoder, horizon = agent.modules.encoder, agent.planner.horizon
    rows: dict[str, list[dict]] = {"start": [], **{key: [] for key in PLANS}}
    actions = torch.tensor([FIXED[action] for action in PLANS.values()])
    for seed, rollout in zip(evaluation_seeds(run_eval_seed(train), episodes), rollouts):
        if (episode_outcome(rollout) == "succeeded") != (outcome == "succeeded"):
            continue
        for t in tested_steps(rollout, 10):
            with torch.inference_mode():  # the held state as recorded (the replay reaches it exactly)
                z = encoder.encode(rollout["next"][t : t + 1].select(*encoder.in_keys))
            rows["start"].append(values_at(agent, z))
            paths = played_paths(env, seed, rollout, t, actions, horizon, encoder.in_keys)
            for key, played in zip(PLANS, paths or []):
                with torch.inference_mode():
                    z = encoder.encode(played[-1:])
                rows[key].append(values_at(agent, z))
    env.close()
    return {"checkpoint": path, "episodes": episodes, "outcome": outcome, "horizon": horizon,
            **{key: {"states": len(r), **{k: round(float(np.mean([x[k] for x in r])), 2) for k in r[0]}} if r
               else {"states": 0} for key, r in rows.items()}}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("checkpoint")
    parser.add_argument("--episodes", type=int, default=8)
    parser.add_argument("--outcome", choices=("succeeded", "failed"), default="succeeded")
    parser.add_argument("--out", help="write the result to this JSON file")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    result = probe(args.checkpoint, args.episodes, args.outcome)
    print(json.dumps(result, indent=1))
    if args.out:
        Path(args.out).write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
