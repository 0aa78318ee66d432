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

Whether lifting would in fact have worked is measured too (``straight_lift``): every ``--every``-th held state of
each episode is reached again by replaying the episode's actions from its seeded reset in the run's evaluation env
(``replay_exact``: the share whose replayed observation equals the recorded one), then the hand is commanded
straight up with the gripper closing for ``--lift-steps`` steps; ``lifted`` is the share of those that reach the
task's success. A model that scores down above up where a straight lift succeeds is wrong there.

Which part of the model is wrong is split three ways: each plan's return is reported as its discounted reward sum
and its discounted terminal value apart (``mean_reward_sum``, ``mean_terminal``, and ``up_beats_down`` of each);
and the latent dynamics' own forecast of the straight lift is read back with a :class:`~torchrl_mpail2.diagnostics.
latent_probe.LatentProbe` fitted from encoded latents to the cube's and the hand's heights on the played episodes
(``imagined``: the decoded rise, in cm, after each of the H imagined steps of the z = +1 plan, from the same
states the straight lift starts from, next to the rise the simulator gave). Dynamics whose imagined hand rises
while their imagined cube stays on the table cannot value a lift, whatever the reward. And the reward and value are
read on what really happens (``simulated``): z = -1, 0 and +1 played in the simulator for H steps from those states,
their encoded observations scored as the planner scores an imagined path. Up beating down there but not in
imagination points at the dynamics; down beating up on the simulator's own outcome points at the reward or value.
``value_by_rise`` gives the value and the reward at the held states of the played episodes by the cube's height: what
the value rates on the agent's own path, next to what it rates after a straight lift.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from torchrl_mpail2.diagnostics.held_replays import (GRIPPER_CLOSING, check_replay_args, cube_and_hand_heights,
                                                     episode_outcome, played_paths, straight_lift_from_held_states,
                                                     tested_steps)
from torchrl_mpail2.diagnostics.lift_phases import cube_rise_m, held_states, play_lift_episodes

__all__ = ["VERTICAL", "constant_vertical_plans", "fit_height_probe", "imagined_straight_lift", "score_held_states",
           "simulated_plan_returns", "value_by_rise"]

#: Vertical commands scored (fractions of a full step; robosuite's z points up).
VERTICAL = (-1.0, -0.5, 0.0, 0.5, 1.0)


def constant_vertical_plans(horizon: int, action_dim: int, vertical=VERTICAL) -> torch.Tensor:
    """``[len(vertical), H, A]`` plans holding one action each: no horizontal motion, the vertical command, and the
    gripper (the last entry) closing. Needs ``action_dim == 4`` (robosuite's position control plus gripper)."""
    if action_dim != 4:
        raise ValueError(f"held_plans scores robosuite position actions [x, y, z, gripper]; action_dim is {action_dim}")
    plans = torch.zeros(len(vertical), horizon, action_dim)
    plans[:, :, 2] = torch.tensor(vertical).unsqueeze(-1)
    plans[:, :, 3] = GRIPPER_CLOSING
    return plans


def _group_rows(rewards: np.ndarray, terminal: np.ndarray, vertical, taken_z: np.ndarray | None = None) -> dict:
    up, down = vertical.index(1.0), vertical.index(-1.0)

    def by_z(values):
        return {str(v): round(float(values[:, i].mean()), 3) for i, v in enumerate(vertical)}

    def up_wins(values):
        return round(float((values[:, up] > values[:, down]).mean()), 3)

    returns = rewards + terminal
    return {"states": int(len(returns)), "mean_return": by_z(returns), "up_beats_down": up_wins(returns),
            "mean_reward_sum": by_z(rewards), "up_beats_down_reward_sum": up_wins(rewards),
            "mean_terminal": by_z(terminal), "up_beats_down_terminal": up_wins(terminal),
            **({} if taken_z is None else {"taken_z_mean": round(float(taken_z.mean()), 3)})}


def score_held_states(agent, rollouts: list, vertical=VERTICAL) -> dict:
    """The planner's returns of :func:`constant_vertical_plans` at the held states of ``rollouts`` (each the
    ``[T]`` rollout of one Lift episode in ``"state"`` mode), over every Q head, grouped by the episode's outcome
    -> ``{"succeeded": row, "grasped_without_success": row}`` (a group without held states is left out); each row
    gives the return, and its reward sum and terminal value apart, per vertical command."""
    planner, encoder = agent.planner, agent.modules.encoder
    plans = constant_vertical_plans(planner.horizon, planner.action_dim, vertical)
    heads = torch.arange(agent.modules.value.net.num_q)
    groups: dict[str, tuple[list, list, list]] = {"succeeded": ([], [], []), "grasped_without_success": ([], [], [])}
    with torch.inference_mode():
        for rollout in rollouts:
            held = held_states(rollout)[:-1]  # the last state has no action taken in it
            if not held.any():
                continue
            states = rollout["next"][:-1][torch.as_tensor(held)].select(*encoder.in_keys)
            z = encoder.encode(states)
            rewards, terminal = planner.score_parts(
                z, plans.unsqueeze(0).expand(len(z), *plans.shape).to(z.dtype), heads)
            taken_z = rollout["action"][1:][torch.as_tensor(held)][:, 2]
            bucket = groups[episode_outcome(rollout)]
            bucket[0].append(rewards.float().numpy())
            bucket[1].append(terminal.float().numpy())
            bucket[2].append(taken_z.float().numpy())
    return {name: _group_rows(np.concatenate(r), np.concatenate(q), list(vertical), np.concatenate(z))
            for name, (r, q, z) in groups.items() if r}


#: Bins of the cube's rise above its settled height (cm) for :func:`value_by_rise`.
RISE_BINS_CM = (0.5, 1.0, 2.0, 4.0, 8.0)


def value_by_rise(agent, rollouts: list) -> dict:
    r"""The value of the policy's mean first action, :math:`Q(z, \pi(z))` (mean of every head), and the learned
    reward of the step taken there, at the held states of ``rollouts``, by outcome group and by the cube's rise
    above its settled height (bins :data:`RISE_BINS_CM`) -> ``{group: {"<a..b cm": {"states", "q", "reward"}}}``.
    Which heights the value already rates well, on the agent's own path."""
    m, encoder = agent.modules, agent.modules.encoder
    edges = (-np.inf, *RISE_BINS_CM, np.inf)
    groups: dict[str, dict[str, list]] = {}
    with torch.inference_mode():
        for rollout in rollouts:
            held = held_states(rollout)[:-1]  # the last state has no step taken from it
            if not held.any():
                continue
            rise_cm = cube_rise_m(rollout["next", "object"].numpy())[:-1][held] * 100
            z = encoder.encode(rollout["next"].select(*encoder.in_keys)).float()
            q = m.q(z, m.pi(z, deterministic=True)[0][:, 0]).mean(0)[:-1]
            reward = m.rewards(z)
            bins = np.digitize(rise_cm, RISE_BINS_CM)
            rows = groups.setdefault(episode_outcome(rollout), {})
            for b, q_b, r_b in zip(bins, q[torch.as_tensor(held)].numpy(), reward[torch.as_tensor(held)].numpy()):
                rows.setdefault(int(b), []).append((q_b, r_b))
    return {name: {f"{edges[b]:g}..{edges[b + 1]:g} cm": {
                "states": len(rows[b]), "q": round(float(np.mean([x[0] for x in rows[b]])), 2),
                "reward": round(float(np.mean([x[1] for x in rows[b]])), 3)} for b in sorted(rows)}
            for name, rows in groups.items()}


def fit_height_probe(agent, rollouts: list, seed: int = 0) -> tuple:
    """A :class:`~torchrl_mpail2.diagnostics.latent_probe.LatentProbe` from the encoder's latents of every
    ``("next", ...)`` state of ``rollouts`` to the cube's and the hand's heights -> ``(probe, stats)`` (stats in cm)."""
    from torchrl_mpail2.diagnostics.latent_probe import fit_latent_probe

    encoder = agent.modules.encoder
    states = torch.cat([rollout["next"].select(*encoder.in_keys) for rollout in rollouts])
    with torch.inference_mode():
        z = encoder.encode(states).float()
    heights = torch.cat([cube_and_hand_heights(rollout["next", "object"].float()) for rollout in rollouts])
    probe, stats = fit_latent_probe(z.clone(), heights.clone(), seed=seed)  # clones: trainable, not inference
    return probe, {"pairs": int(len(z)), "held_out_r2": round(stats["held_out_r2"], 3),
                   "held_out_mae_cm": round(stats["held_out_mae"] * 100, 2)}


def imagined_straight_lift(agent, probe, rollouts: list, every: int = 10) -> dict:
    """The latent dynamics' forecast of the straight lift (the ``z = +1`` plan of :func:`constant_vertical_plans`,
    H steps, float32 networks) from the states :func:`straight_lift_from_held_states` starts from, read back by
    ``probe`` (:func:`fit_height_probe`) -> per outcome group ``{"tested", "cube_rise_cm", "hand_rise_cm"}``: the
    mean decoded rise after each imagined step, relative to the decoded start."""
    encoder, dynamics = agent.modules.encoder, agent.modules.dynamics.module
    plan = constant_vertical_plans(agent.planner.horizon, agent.planner.action_dim, (1.0,))[0]
    groups: dict[str, list[torch.Tensor]] = {}
    with torch.inference_mode():
        for rollout in rollouts:
            steps = tested_steps(rollout, every)
            if not len(steps):
                continue
            zk = encoder.encode(rollout["next"][torch.as_tensor(steps)].select(*encoder.in_keys)).float()
            start, rises = probe(zk), []
            for action in plan:
                zk = dynamics(zk, action.expand(len(zk), -1))
                rises.append(probe(zk) - start)
            groups.setdefault(episode_outcome(rollout), []).append(torch.stack(rises, dim=1))  # [N, H, 2]
    result = {}
    for name, parts in groups.items():
        mean_cm = torch.cat(parts).mean(0) * 100
        result[name] = {"tested": int(sum(len(p) for p in parts)),
                        "cube_rise_cm": [round(float(v), 2) for v in mean_cm[:, 0]],
                        "hand_rise_cm": [round(float(v), 2) for v in mean_cm[:, 1]]}
    return result


def simulated_plan_returns(env, agent, seeds: list[int], rollouts: list, every: int = 10,
                           vertical=(-1.0, 0.0, 1.0)) -> dict:
    """The learned reward and value on what the simulator does: from the same held states as
    :func:`straight_lift_from_held_states`, each constant plan of :func:`constant_vertical_plans` is played in
    ``env`` for H steps, the observations are encoded, and the planner's return of that latent path
    (:meth:`~torchrl_mpail2.planners.LatentMPPIPlanner.path_return_parts`, every Q head) is taken in place of the
    imagined one -> per outcome group a row as :func:`score_held_states` gives (``taken_z_mean`` left out; a plan
    cut short by the episode's end is left out of every command at that state)."""
    planner, encoder = agent.planner, agent.modules.encoder
    check_replay_args(seeds, rollouts, every, planner.horizon)
    plans = constant_vertical_plans(planner.horizon, planner.action_dim, vertical)
    heads = torch.arange(agent.modules.value.net.num_q)
    groups: dict[str, tuple[list, list]] = {}
    for seed, rollout in zip(seeds, rollouts):
        for t in tested_steps(rollout, every):
            paths = played_paths(env, seed, rollout, t, plans[:, 0], planner.horizon, encoder.in_keys)
            if paths is None:
                continue
            with torch.inference_mode():
                latents = encoder.encode(torch.stack(paths)).float()  # [len(vertical), H + 1, Z]
                rewards, terminal = planner.path_return_parts(latents, plans, heads)
            bucket = groups.setdefault(episode_outcome(rollout), ([], []))
            bucket[0].append(rewards.numpy())
            bucket[1].append(terminal.numpy())
    return {name: _group_rows(np.stack(rewards), np.stack(terminal), list(vertical))
            for name, (rewards, terminal) in groups.items()}


def _print_parts(row: dict) -> None:
    for part, wins in (("return", "up_beats_down"), ("reward_sum", "up_beats_down_reward_sum"),
                       ("terminal", "up_beats_down_terminal")):
        by_z = " ".join(f"{v}: {r:.2f}" for v, r in row[f"mean_{part}"].items())
        print(f"    {part:10s} by z [{by_z}]  up beats down {row[wins]:.2f}", flush=True)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m torchrl_mpail2.diagnostics held_plans",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("checkpoints", nargs="+", help="checkpoint folders of robosuite/Lift state runs")
    parser.add_argument("--episodes", type=int, default=20, help="the run's first N fixed evaluation episodes")
    parser.add_argument("--out", help="write the results to this JSON file")
    parser.add_argument("--every", type=int, default=10, help="lift straight up from every N-th held state")
    parser.add_argument("--lift-steps", type=int, default=20, help="steps of the straight lift")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    from torchrl_mpail2.trainers.evaluation import evaluation_env, evaluation_seeds, run_eval_seed

    results = []
    for path in args.checkpoints:
        agent, rollouts = play_lift_episodes(path, args.episodes)
        train = agent.run_config["train"]
        env = evaluation_env(train)
        seeds = evaluation_seeds(run_eval_seed(train), args.episodes)
        lifts = straight_lift_from_held_states(env, seeds, rollouts, args.every, args.lift_steps)
        simulated = simulated_plan_returns(env, agent, seeds, rollouts, args.every)
        env.close()
        probe, probe_stats = fit_height_probe(agent, rollouts)
        result = {"checkpoint": str(path), "episodes": args.episodes, "vertical": list(VERTICAL),
                  "every": args.every, "lift_steps": args.lift_steps,
                  "groups": score_held_states(agent, rollouts), "straight_lift": lifts,
                  "height_probe": probe_stats, "imagined": imagined_straight_lift(agent, probe, rollouts, args.every),
                  "simulated": simulated, "value_by_rise": value_by_rise(agent, rollouts)}
        results.append(result)
        print(path)
        for name, row in result["groups"].items():
            print(f"  {name:24s} {row['states']:4d} held states, z taken {row['taken_z_mean']:+.2f}", flush=True)
            _print_parts(row)
        for name, row in result["simulated"].items():
            print(f"  {name:24s} the same plans played in the simulator from {row['states']} held states:")
            _print_parts(row)
        for name, rows in result["value_by_rise"].items():
            print(f"  {name:24s} Q(z, pi(z)) / reward at held states by the cube's rise: " + "  ".join(
                f"{bin_}: {row['q']:.1f} / {row['reward']:.2f} ({row['states']})" for bin_, row in rows.items()))
        horizon = min(agent.planner.horizon, args.lift_steps)  # compare after as many steps as both have
        print(f"  height probe: {result['height_probe']}")
        for name, row in result["straight_lift"].items():
            imagined = result["imagined"][name]
            print(f"  {name:24s} straight lift from {row['tested']} held states: lifted {row['lifted']:.2f} "
                  f"(replayed exactly: {row['replay_exact']:.2f}); after {horizon} steps cube / hand rose "
                  f"{row['cube_rise_cm'][horizon - 1]:.1f} / {row['hand_rise_cm'][horizon - 1]:.1f} cm, imagined "
                  f"{imagined['cube_rise_cm'][horizon - 1]:.1f} / {imagined['hand_rise_cm'][horizon - 1]:.1f} cm",
                  flush=True)
    if args.out:
        Path(args.out).write_text(json.dumps(results, indent=1) + "\n")
        print(f"wrote {args.out}")
