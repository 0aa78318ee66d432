r"""Pictures of planning, after the paper's figure of predicted plans: at a few steps of each evaluation episode,
the planner's elite plans and its chosen plan are rolled out through the latent dynamics :math:`f_\psi` from
:math:`z_t = e_\omega(o_t)` and decoded by a :class:`~torchrl_mpail2.diagnostics.LatentProbe` (fitted on the side
to the episodes' own latents) into positions in a plane, beside the path the agent actually took."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch
from tensordict import TensorDictBase

from torchrl_mpail2.diagnostics.figures import save_figure
from torchrl_mpail2.diagnostics.latent_probe import LatentProbe, fit_latent_probe
from torchrl_mpail2.trainers.evaluation import (episode_outcome, evaluate_episodes, evaluation_env, evaluation_seeds,
                                                run_eval_seed)

__all__ = ["PLANE_POSITIONS", "draw_plan_pictures", "plane_position"]

USAGE = """python -m torchrl_mpail2.diagnostics plan_pictures RUN/checkpoints/episode_N [--episodes 3] [--out DIR]

Draws the planner's elite plans and its chosen plan on the run's first fixed evaluation episodes
(``train.eval_seed + i``); default output folder: the checkpoint's ``plan_pictures/``."""

#: Where positions are read from the observations: ``(key, {plane: (column, column)})``. robosuite: the
#: end-effector's x, y, z, the first entries of ``"proprio"`` (``xy`` is the table plane, ``xz`` shows lifting);
#: the point mass: its x, y.
PLANE_POSITIONS = {"robosuite": ("proprio", {"xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}),
                   "point_mass": ("observation", {"xy": (0, 1)})}


def plane_position(env_name: str, plane: str = "xy") -> tuple[str, tuple[int, int]]:
    """``(key, (column, column))`` of :data:`PLANE_POSITIONS` for an env name of
    :data:`~torchrl_mpail2.envs.ENV_NAMES` and a plane (``xy``, ``xz`` or ``yz``)."""
    family = "robosuite" if env_name.startswith("robosuite/") else env_name
    if family not in PLANE_POSITIONS:
        raise ValueError(f"no plane position is known for {env_name!r} (known: robosuite/*, point_mass); "
                         "pass position_key and position_columns")
    key, planes = PLANE_POSITIONS[family]
    if plane not in planes:
        raise ValueError(f"plane {plane!r} is not known for {env_name!r}; choose from {sorted(planes)}")
    return key, planes[plane]


@torch.no_grad()
def decoded_paths(agent, probe: LatentProbe, z: torch.Tensor, plans: torch.Tensor) -> torch.Tensor:
    """``plans [K, H, A]`` from one latent ``z [Z]`` -> decoded positions ``[K, H + 1, D]`` (the start first)."""
    latents = agent.modules.imagine(z.expand(plans.shape[0], -1), plans)
    return probe(latents).transpose(0, 1)


def _draw_episode(agent, probe, episode: TensorDictBase, latents: torch.Tensor, key: str, cols: tuple[int, int],
                  panels: int, title: str, path: Path, min_half_width: float, labels: tuple[str, str]) -> None:
    """``latents [T, Z]``: the episode's observations encoded once by the caller."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = episode.shape[0]
    actual = torch.cat([episode[key], episode["next", key][-1:]])[:, list(cols)]
    chosen_steps = sorted({round(i * (steps - 1) / max(panels - 1, 1)) for i in range(panels)})
    fig, axes = plt.subplots(1, len(chosen_steps), figsize=(3.2 * len(chosen_steps), 3.4), squeeze=False)
    for ax, t in zip(axes[0], chosen_steps):
        z = latents[t]
        elites, weights = episode["elite_plans"][t], episode["elite_weights"][t]
        paths = decoded_paths(agent, probe, z, elites)
        chosen = decoded_paths(agent, probe, z, episode["plan"][t][None])[0]
        ax.plot(actual[:, 0], actual[:, 1], color="0.85", lw=1)
        for k in weights.argsort().tolist():  # heaviest drawn last, on top
            ax.plot(paths[k, :, 0], paths[k, :, 1], color="tab:blue", lw=0.8,
                    alpha=float(0.1 + 0.8 * weights[k] / weights.max()))
        horizon = chosen.shape[0] - 1
        ax.plot(actual[t:t + horizon + 1, 0], actual[t:t + horizon + 1, 1], "k--", lw=1.2)
        ax.plot(chosen[:, 0], chosen[:, 1], color="tab:red", lw=2)
        ax.plot(actual[t, 0], actual[t, 1], "ko", ms=4)
        ax.set_title(f"step {t}", fontsize=9)
        # each panel frames its own plans (the whole path in grey runs off where it is far larger)
        shown = torch.cat([paths.reshape(-1, paths.shape[-1]), chosen, actual[t:t + horizon + 1]])
        low, high = shown.min(0).values, shown.max(0).values
        half = ((high - low).max() * 0.6).clamp_min(min_half_width)
        centre = (low + high) / 2
        ax.set_xlim(float(centre[0] - half), float(centre[0] + half))
        ax.set_ylim(float(centre[1] - half), float(centre[1] + half))
        ax.set_aspect("equal", adjustable="box")
        ax.tick_params(labelsize=7)
    axes[0][0].set_xlabel(labels[0])
    axes[0][0].set_ylabel(labels[1])
    fig.suptitle(title, fontsize=9)
    save_figure(fig, path)


def draw_plan_pictures(agent, env, seeds: list[int], out_dir: str | Path, *, position_key: str,
                       position_columns: tuple[int, int], panels: int = 6, probe_steps: int = 1000,
                       labels: tuple[str, str] = ("x", "y")) -> dict:
    """Plays one evaluation episode per seed (deterministic, planner noise seeded per episode, as the run's own
    evaluations), fits a probe from the latents of every visited observation to two columns of ``position_key``
    (``position_columns``, drawn as the horizontal and vertical axes), and writes
    ``out_dir/plans_episode_<i>.png`` (``panels`` steps each) and ``out_dir/plan_pictures.json``.

    Returns:
        dict: ``seeds``, per-episode ``success_any_step``, the probe's ``train_mae`` / ``held_out_mae`` /
        ``held_out_r2`` (how far the pictures can be trusted), ``num_elites`` K and ``elite_ess_mean`` (the effective
        number of elites, averaged over the steps) and the ``files`` written.
    """
    planner = agent.planner
    if planner is None or agent.policy is not planner:
        raise ValueError("the agent does not act with the latent planner (a [-P] or model-free ablation): "
                         "there are no plans to draw")
    if not seeds:
        raise ValueError("no evaluation seeds: nothing to draw")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rollouts: list[TensorDictBase] = []
    planner.record_elites = True
    try:
        evaluate_episodes(env, planner, seeds, planner, rollouts=rollouts)
    finally:
        planner.record_elites = False
    cols = list(position_columns)
    with torch.no_grad():
        latents = [agent.modules.encoder.encode(ep) for ep in rollouts]
    y = torch.cat([ep[position_key][..., cols] for ep in rollouts])
    probe, stats = fit_latent_probe(torch.cat(latents), y, steps=probe_steps)
    files, successes = [], []
    for i, (seed, episode, z) in enumerate(zip(seeds, rollouts, latents)):
        success = episode_outcome(episode)["success_any_step"]
        successes.append(success)
        path = out_dir / f"plans_episode_{i:02d}.png"
        title = (f"episode {i} (env seed {seed}, success {success:.0f}): elite plans (blue, darker = heavier), chosen "
                 f"plan (red), what happened next (black dashed); probe held-out error {stats['held_out_mae']:.3g}")
        _draw_episode(agent, probe, episode, z, position_key, tuple(cols), panels, title, path,
                      min_half_width=float(4 * stats["held_out_mae"]) + 1e-3, labels=labels)
        files.append(path.name)
    weights = torch.cat([ep["elite_weights"] for ep in rollouts])
    summary = {"seeds": list(seeds), "success_any_step": successes, "position": f"{position_key}[{cols[0]}, {cols[1]}]",
               **{f"probe_{k}": v for k, v in stats.items()}, "num_elites": weights.shape[-1],
               # effective number of elites 1 / sum w^2 (K when the weights are flat, 1 when one plan wins)
               "elite_ess_mean": float(weights.pow(2).sum(-1).reciprocal().mean()), "files": files}
    (out_dir / "plan_pictures.json").write_text(json.dumps(summary, indent=2))
    return summary


def main(argv: list[str] | None = None) -> dict:
    from torchrl_mpail2.agents import MPAIL2Agent

    p = argparse.ArgumentParser(prog="python -m torchrl_mpail2.diagnostics plan_pictures", description=USAGE, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("checkpoint", type=Path)
    p.add_argument("--episodes", type=int, default=3)
    p.add_argument("--panels", type=int, default=6, help="steps drawn per episode")
    p.add_argument("--plane", default="xy", help="xy (the table plane), xz or yz for robosuite; xy for the point mass")
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args(argv)
    if args.episodes < 1 or args.panels < 1:
        raise SystemExit("--episodes and --panels must be >= 1")
    agent = MPAIL2Agent.from_checkpoint(args.checkpoint)
    train = agent.run_config["train"]
    env = evaluation_env(train)  # the run's own evaluation env (robosuite: the same cube as its evaluations)
    key, cols = plane_position(train["env"], args.plane)
    try:
        summary = draw_plan_pictures(agent, env, evaluation_seeds(run_eval_seed(train), args.episodes),
                                     args.out or args.checkpoint / "plan_pictures", position_key=key,
                                     position_columns=cols, panels=args.panels, labels=tuple(args.plane))
    finally:
        env.close()
    print(json.dumps(summary, indent=2))
    return summary

