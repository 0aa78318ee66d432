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
from pathlib import Path

import numpy as np
import torch

from torchrl_mpail2.diagnostics.state_maps import draw_reward_value_maps, report_map, staying_reward_and_value

__all__ = ["cube_map"]

#: Half widths (m) of the grid around the spawn centre: x across the table, y along the push (beyond the line).
HALF_X, REACH_Y = 0.08, 0.20


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
    positions = [[[float(x), float(y)] for x in xs] for y in ys]
    cube_qpos = np.arange(*address)[:3]
    observed = []
    for x, y in (p for row in positions for p in row):
        state = start.copy()
        state[1 + cube_qpos] = (x, y, cube[2])  # flattened: time, qpos, qvel
        observed.append(base.observe_state(state).select(*agent.modules.observation_shapes))
    sim.set_state_from_flattened(start)
    sim.forward()
    read = staying_reward_and_value(agent.modules, torch.stack(observed))  # one encode for the whole grid
    rewards, values = (read[k].reshape(grid, grid).tolist() for k in ("reward", "value"))
    r = np.array(rewards)
    past = (ys - line_y) * sign > 0
    return {"grid": grid, "line_y": line_y, "push_sign": sign, "positions": positions, "reward_of_staying": rewards,
            "value": values,
            "reward_past_line_minus_spawn": float(r[past].mean() - r[along <= 0.04].mean()) if past.any() else None}


def draw_cube_map(result: dict, path: Path, title: str = "") -> Path:
    """The reward and value over cube positions (the first row, the spawn side, at the top), the line dashed."""
    p = np.array(result["positions"])
    extent = (p[..., 0].min(), p[..., 0].max(), p[-1, 0, 1], p[0, 0, 1])

    def decorate(axes) -> None:
        for ax in axes:
            ax.axhline(result["line_y"], color="red", linestyle="--", linewidth=1)

    return draw_reward_value_maps(result, path, extent, title, labels=("cube x (m)", "cube y (m); red: the line"),
                                  decorate=decorate)


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
    return report_map(result, args.out, args.plot, draw_cube_map)
