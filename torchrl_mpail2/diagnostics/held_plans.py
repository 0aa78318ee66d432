r"""At a held cube, does the learned model prefer lifting it? The planner's own return of a plan (Algorithm 2's
score: :math:`\sum_{k<H} \gamma^k r(\hat z_k, \hat z_{k+1}) + \gamma^H Q(\hat z_H, \pi(\hat z_H))` on imagined latents)
for constant plans that keep the gripper closing and move the hand straight up or down, at every state of an
evaluation episode where the fingers hold the cube (:func:`~torchrl_mpail2.diagnostics.lift_phases.held_states`).

    python -m torchrl_mpail2.diagnostics held_plans CKPT [CKPT ...] --episodes 20 [--out F.json]

The held states are split by their episode's outcome (succeeded / grasped without success). Per group: the mean
return of each vertical command, the share of held states where straight up (z = +1) outscores straight down
(z = -1), and the mean vertical action the agent took there. A model that scores "down" higher where the agent got
stuck pressing a held cube onto the table is wrong about the task there; one that scores "up" higher while the
agent still pushed down points at the search or its policy prior instead.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

__all__ = ["VERTICAL", "constant_vertical_plans", "score_held_states"]

#: Vertical commands scored (fractions of a full step; robosuite's z points up).
VERTICAL = (-1.0, -0.5, 0.0, 0.5, 1.0)
#: The gripper command of every scored plan: closing (robosuite's Panda gripper closes for positive commands).
GRIPPER_CLOSING = 1.0


def constant_vertical_plans(horizon: int, action_dim: int, vertical=VERTICAL) -> torch.Tensor:
    """``[len(vertical), H, A]`` plans holding one action each: no horizontal motion, the vertical command, and the
    gripper (the last entry) closing. Needs ``action_dim == 4`` (robosuite's position control plus gripper)."""
    if action_dim != 4:
        raise ValueError(f"held_plans scores robosuite position actions [x, y, z, gripper]; action_dim is {action_dim}")
    plans = torch.zeros(len(vertical), horizon, action_dim)
    plans[:, :, 2] = torch.tensor(vertical).unsqueeze(-1)
    plans[:, :, 3] = GRIPPER_CLOSING
    return plans


def _group_rows(returns: np.ndarray, taken_z: np.ndarray, vertical) -> dict:
    up, down = vertical.index(1.0), vertical.index(-1.0)
    return {"states": int(len(returns)),
            "mean_return": {str(v): round(float(returns[:, i].mean()), 3) for i, v in enumerate(vertical)},
            "up_beats_down": round(float((returns[:, up] > returns[:, down]).mean()), 3),
            "taken_z_mean": round(float(taken_z.mean()), 3)}


def score_held_states(agent, rollouts: list, vertical=VERTICAL) -> dict:
    """The planner's returns of :func:`constant_vertical_plans` at the held states of ``rollouts`` (each the
    ``[T]`` rollout of one Lift episode in ``"state"`` mode), over every Q head, grouped by the episode's outcome
    -> ``{"succeeded": row, "grasped_without_success": row}`` (a group without held states is left out)."""
    from torchrl_mpail2.diagnostics.lift_phases import held_states

    planner, encoder = agent.planner, agent.modules.encoder
    plans = constant_vertical_plans(planner.horizon, planner.action_dim, vertical)
    heads = torch.arange(agent.modules.value.net.num_q)
    groups: dict[str, tuple[list, list]] = {"succeeded": ([], []), "grasped_without_success": ([], [])}
    with torch.inference_mode():
        for rollout in rollouts:
            held = held_states(rollout)[:-1]  # the last state has no action taken in it
            if not held.any():
                continue
            states = rollout["next"][:-1][torch.as_tensor(held)].select(*encoder.in_keys)
            z = encoder.encode(states)
            returns = planner.score(z, plans.unsqueeze(0).expand(len(z), *plans.shape).to(z.dtype), heads)
            taken_z = rollout["action"][1:][torch.as_tensor(held)][:, 2]
            succeeded = bool(rollout["next", "success"].any()) if ("next", "success") in rollout.keys(True) else False
            bucket = groups["succeeded" if succeeded else "grasped_without_success"]
            bucket[0].append(returns.float().numpy())
            bucket[1].append(taken_z.float().numpy())
    return {name: _group_rows(np.concatenate(r), np.concatenate(z), list(vertical))
            for name, (r, z) in groups.items() if r}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m torchrl_mpail2.diagnostics held_plans",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("checkpoints", nargs="+", help="checkpoint folders of robosuite/Lift state runs")
    parser.add_argument("--episodes", type=int, default=20, help="the run's first N fixed evaluation episodes")
    parser.add_argument("--out", help="write the results to this JSON file")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    from torchrl_mpail2.diagnostics.lift_phases import play_lift_episodes

    results = []
    for path in args.checkpoints:
        agent, rollouts = play_lift_episodes(path, args.episodes)
        result = {"checkpoint": str(path), "episodes": args.episodes, "vertical": list(VERTICAL),
                  "groups": score_held_states(agent, rollouts)}
        results.append(result)
        print(path)
        for name, row in result["groups"].items():
            returns = " ".join(f"{v}: {r:.2f}" for v, r in row["mean_return"].items())
            print(f"  {name:24s} {row['states']:4d} held states  return by z [{returns}]  up beats down "
                  f"{row['up_beats_down']:.2f}  z taken {row['taken_z_mean']:+.2f}", flush=True)
    if args.out:
        Path(args.out).write_text(json.dumps(results, indent=1) + "\n")
        print(f"wrote {args.out}")
