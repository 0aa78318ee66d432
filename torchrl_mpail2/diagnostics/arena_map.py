r"""What a point-mass agent has learned, position by position: over a grid of the arena, the reward of staying
:math:`r_\theta(z, z)`, the value of the policy's plan :math:`Q_\zeta(z, \pi_\phi(z)_0)` (the mean over all heads)
and the policy mean's first action, with :math:`z = e_\omega(o)` of the observation at that position at rest
(``[x, y, 0, 0]`` from state, :func:`~torchrl_mpail2.envs.point_mass.draw_arena`'s picture from pixels).

An agent that learned the task rates the goal (the origin) highest and points its actions towards it from every
side; one whose latent geometry does not follow the positions (from pixels, pictures of far-apart positions all
differ about equally) can rate the goal's surroundings below the arena's edges and drive there.

    python -m torchrl_mpail2.diagnostics arena_map CKPT [--grid 13] [--out FILE.json] [--plot FILE.png] [--glow S]
"""
from __future__ import annotations

import argparse
from pathlib import Path

import torch
from tensordict import TensorDict

from torchrl_mpail2.diagnostics.state_maps import draw_reward_value_maps, report_map, staying_reward_and_value

__all__ = ["arena_map"]


def arena_map(agent, grid: int = 13, extent: float = 1.4, glow: float | None = None) -> dict:
    """The maps of the module docstring on a ``grid`` x ``grid`` lattice over ``[-extent, extent]^2`` (rows from
    the top: y falls, x rises; ``glow``: the pictures' glow, by default the one the agent's run drew with, from its
    ``train.env_kwargs``, else :data:`~torchrl_mpail2.envs.point_mass.GLOW_SIGMA`), each ``[grid, grid]`` as nested lists, with ``first_action`` ``[grid, grid, 2]``;
    and two summaries: ``value_near_goal_minus_edge`` (the mean value within 0.6 of the goal minus that beyond 1.0
    on either axis: positive where the value leads to the goal) and ``actions_towards_goal`` (the share of positions
    more than 0.2 from the goal whose first action has a component towards it).

    Raises:
        ValueError: the agent does not observe the point mass (neither ``"observation"`` of width 4 nor
            ``"external_image"``).
    """
    from torchrl_mpail2.envs.point_mass import GLOW_SIGMA, IMAGE_KEY, OBSERVATION_DIM, draw_arena

    m = agent.modules
    shapes = m.observation_shapes
    xs = torch.linspace(-extent, extent, grid)
    position = torch.stack(torch.meshgrid(xs, xs.flip(0), indexing="xy"), -1).reshape(-1, 2)
    if list(shapes) == [IMAGE_KEY]:
        if glow is None:
            run = (getattr(agent, "run_config", None) or {}).get("train", {})
            glow = (run.get("env_kwargs") or {}).get("glow", GLOW_SIGMA)
        observation = {IMAGE_KEY: draw_arena(position, glow=glow)}
    elif list(shapes) == ["observation"] and tuple(shapes["observation"]) == (OBSERVATION_DIM,):
        observation = {"observation": torch.cat([position, torch.zeros_like(position)], -1)}
    else:
        raise ValueError(f"arena_map reads point-mass agents (observation keys ['observation'] of width "
                         f"{OBSERVATION_DIM} or [{IMAGE_KEY!r}]); this agent observes {dict(shapes)}")
    read = staying_reward_and_value(m, TensorDict(observation, [position.shape[0]]))
    z, reward, action, value = read["z"], read["reward"], read["action"], read["value"]

    def square(t: torch.Tensor) -> list:
        return t.reshape(grid, grid, *t.shape[1:]).tolist()

    near, edge = position.norm(dim=-1) < 0.6, position.abs().amax(-1) > 1.0
    away = position.norm(dim=-1) > 0.2
    return {"grid": grid, "extent": extent, "reward_of_staying": square(reward), "value": square(value),
            "first_action": square(action), "latent_spread": float(z.std(0).mean()),
            "value_near_goal_minus_edge": float(value[near].mean() - value[edge].mean()),
            "actions_towards_goal": float(((action * -position).sum(-1) > 0)[away].float().mean())}


def draw_arena_map(result: dict, path: Path, title: str = "") -> Path:
    """The reward and value maps side by side, the goal marked, the policy's first actions as arrows over the value."""
    e = result["extent"]

    def decorate(axes) -> None:
        for ax in axes:
            ax.plot(0, 0, "r+", markersize=10)
        xs = torch.linspace(-e, e, result["grid"])
        gx, gy = torch.meshgrid(xs, xs.flip(0), indexing="xy")
        action = torch.tensor(result["first_action"])
        axes[1].quiver(gx, gy, action[..., 0], action[..., 1], color="white", scale=25)

    return draw_reward_value_maps(result, path, (-e, e, -e, e), title, decorate=decorate)


def main(argv: list[str] | None = None) -> dict:
    from torchrl_mpail2.agents import MPAIL2Agent

    p = argparse.ArgumentParser(prog="python -m torchrl_mpail2.diagnostics arena_map", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("checkpoint", type=Path)
    p.add_argument("--grid", type=int, default=13, help="positions per side")
    p.add_argument("--out", type=Path, help="write the maps to this JSON file")
    p.add_argument("--plot", type=Path, help="draw the maps to this PNG file")
    p.add_argument("--glow", type=float, default=None,
                   help="draw the pictures with this glow (default: the run's; 0 for agents trained on the pictures "
                        "before the glow, commit e3c3189 and earlier)")
    args = p.parse_args(argv)
    if args.grid < 2:
        p.error("--grid must be at least 2")
    agent = MPAIL2Agent.from_checkpoint(args.checkpoint)
    result = {"checkpoint": str(args.checkpoint), **arena_map(agent, args.grid, glow=args.glow)}
    return report_map(result, args.out, args.plot, draw_arena_map)
