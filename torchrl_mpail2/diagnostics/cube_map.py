r"""What a Push agent's reward says about where the cube is: with the arm at its starting pose, the cube is placed on
a grid over the table (the spawn region, the line and beyond), the scene observed as the run observes it (state or
cameras), and the reward of staying :math:`r_\theta(z, z)` and the value :math:`Q_\zeta(z, \pi_\phi(z)_0)` (the
mean over all heads) read at :math:`z = e_\omega(o)`. A reward that learned the task rises as the cube crosses the
line (``y`` past ``line_y`` in the push direction); one that reads only the arm is flat across the grid.

The point-mass counterpart is :mod:`~torchrl_mpail2.diagnostics.arena_map`.

    python -m torchrl_mpail2.diagnostics cube_map CKPT [--grid 9] [--out FILE.json] [--plot FILE.png]
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

__all__ = ["cube_map"]

#: Half widths (m) of the grid around the spawn centre: x across the table, y along the push (beyond the line).
HALF_X, REACH_Y = 0.08, 0.20


@torch.no_grad()
def cube_map(agent, env, grid: int = 9) -> dict:
    """The maps of the module docstring over ``grid`` x ``grid`` cube positions (rows: the push direction, from the
    spawn side to beyond the line; columns: x), each as nested lists, with the positions, the line and the
    summary ``reward_past_line_minus_spawn`` (the mean reward of cubes past the line minus that of cubes on the
    spawn side: positive where the reward pays for crossing).

    Raises:
        ValueError: ``env`` is not a robosuite Push task.
    """
    base = env
    while hasattr(base, "base_env"):
        base = base.base_env
    if not getattr(base, "is_push", False):
        raise ValueError(f"cube_map reads Push tasks (robosuite/Push, robosuite/PushMirrored); got {type(base).__name__}")
    env.reset()
    sim_env = base.sim_env
    sim = sim_env.sim
    joint = sim_env.cube.joints[0]
    address = sim.model.get_joint_qpos_addr(joint)
    start = sim.get_state().flatten()
    sign, line_y = float(sim_env.push_sign), float(sim_env.line_y)
    cube = base.privileged_state()["cube_pos"]
    along = np.linspace(-0.04, REACH_Y, grid)  # metres travelled from the spawn centre in the push direction
    xs = cube[0] + np.linspace(-HALF_X, HALF_X, grid)
    ys = float(sim_env.spawn_center_y) + sign * along
    rewards, values, positions = [], [], []
    qpos_start = np.arange(address[0], address[1])
    for y in ys:
        row_r, row_q, row_p = [], [], []
        for x in xs:
            state = start.copy()
            qpos = state[1:1 + sim.model.nq]  # flattened: time, qpos, qvel, ...
            qpos[qpos_start[:3]] = (x, y, cube[2])
            td = base.observe_state(state)
            obs = td.select(*agent.modules.observation_shapes).unsqueeze(0)
            z = agent.modules.encode(obs)
            action = agent.modules.pi(z, deterministic=True)[0][:, 0]
            row_r.append(float(agent.modules.rewards(torch.stack([z, z]))[0, 0]))
            row_q.append(float(agent.modules.q(z, action).mean(0)[0]))
            row_p.append([float(x), float(y)])
        rewards.append(row_r), values.append(row_q), positions.append(row_p)
    sim.set_state_from_flattened(start)
    sim.forward()
    r = np.array(rewards)
    past = (ys - line_y) * sign > 0
    return {"grid": grid, "line_y": line_y, "push_sign": sign, "positions": positions, "reward_of_staying": rewards,
            "value": values,
            "reward_past_line_minus_spawn": float(r[past].mean() - r[along <= 0.04].mean()) if past.any() else None}


def draw_cube_map(result: dict, path: Path, title: str = "") -> Path:
    """The reward and value over cube positions, the line dashed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    p = np.array(result["positions"])
    extent = (p[..., 0].min(), p[..., 0].max(), p[..., 1].min(), p[..., 1].max())
    fig, axes = plt.subplots(1, 2, figsize=(9, 4))
    for ax, key, label in zip(axes, ("reward_of_staying", "value"), ("reward of staying r(z, z)", "Q(z, pi(z))")):
        grid = np.array(result[key])
        im = ax.imshow(grid if p[0, 0, 1] > p[-1, 0, 1] else grid[::-1], extent=extent, cmap="viridis", aspect="auto")
        fig.colorbar(im, ax=ax, shrink=0.8)
        ax.axhline(result["line_y"], color="red", linestyle="--", linewidth=1)
        ax.set_xlabel("cube x (m)")
        ax.set_ylabel("cube y (m); red: the line")
        ax.set_title(label, fontsize=9)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> dict:
    from torchrl_mpail2.agents import MPAIL2Agent
    from torchrl_mpail2.trainers.evaluation import evaluation_env

    p = argparse.ArgumentParser(prog="python -m torchrl_mpail2.diagnostics cube_map", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("checkpoint", type=Path)
    p.add_argument("--grid", type=int, default=9, help="cube positions per side")
    p.add_argument("--out", type=Path, help="write the maps to this JSON file")
    p.add_argument("--plot", type=Path, help="draw the maps to this PNG file")
    args = p.parse_args(argv)
    if args.grid < 2:
        p.error("--grid must be at least 2")
    agent = MPAIL2Agent.from_checkpoint(args.checkpoint)
    env = evaluation_env(agent.run_config["train"])
    try:
        result = {"checkpoint": str(args.checkpoint), **cube_map(agent, env, args.grid)}
    finally:
        env.close()
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=1))
    if args.plot is not None:
        print(f"wrote {draw_cube_map(result, args.plot, str(args.checkpoint))}")
    print(json.dumps({k: v for k, v in result.items() if not isinstance(v, list)}, indent=2))
    return result
