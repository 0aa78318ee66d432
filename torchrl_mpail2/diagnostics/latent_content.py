r"""What the latent :math:`z = e_\omega(o)` of a robosuite checkpoint knows about the scene: how well a small probe
reads the cube's and the hand's positions off it, and how much the latent varies at all.

    python -m torchrl_mpail2.diagnostics latent_content CKPT [--resets 200] [--episodes 3] [--out FILE]

An encoder trained only by the latent prediction loss (Eq. 2) can collapse: a latent that hardly changes predicts
itself well. From camera frames the hand's position is in the proprioception as well, but the cube's only in the
pictures, so a camera run whose latent cannot tell where the cube is cannot plan a push. Two sets of states:
``--resets`` initial states (evaluation seeds from the held-out range: the cube is placed anew each time, the arm
starts about the same), and the states of ``--episodes`` episodes of the run's evaluation set played by the
checkpoint's agent (the plan's mean). Each observation is encoded and paired with the simulator's cube and hand
positions; a :class:`~torchrl_mpail2.diagnostics.latent_probe.LatentProbe` is fitted to each (from the latent
standardised per dimension) on 80% of the pairs of a set and scored on the rest (``held_out_r2``: 1 reads it exactly, 0 no better than the mean). Also reported per set:
the latent's spread (the mean over dimensions of its std over the states) and, per observation key, the spread of
that key's coder output relative to its mean magnitude, and for a compartmentalised latent
(``model.fuse_latent=false``) each key's block probed alone (``blocks``: its spread and the probes' ``held_out_r2``):
the video-only setting's reward reads the table camera's block only, so that block must hold the cube.

``--bf16`` also encodes the same observations under bfloat16 autocast, as ``train.update_precision=bf16`` does in
every stage of an update, and reports (``bf16``) the rounding's size beside the latent's spread and what the probes
read from the rounded latents. bf16 keeps 8 significant bits: a LayerNorm'd latent of magnitude about 1 is rounded
by up to about 0.004, more than a cube a few pixels wide moves it early in training.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch
from tensordict import TensorDictBase
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

from torchrl_mpail2.diagnostics.latent_probe import fit_latent_probe

#: Simulator positions the probes read, from ``RobosuiteEnv.privileged_state``.
TARGETS = ("cube_pos", "eef_pos")


def visited_states(agent, env, seeds: list[int], play: bool = True) -> tuple[TensorDictBase, dict[str, torch.Tensor]]:
    """The observations ``[N]`` of ``len(seeds)`` episodes played by ``agent`` (deterministic), or of their initial
    states alone (``play=False``), and the simulator's :data:`TARGETS` ``[N, 3]`` at each."""
    from torchrl_mpail2.envs.robosuite_env import robosuite_base

    base = robosuite_base(env)
    if base is None:
        raise ValueError("latent_content reads the simulator's cube and hand positions: it needs a robosuite env")
    observations, targets = [], {key: [] for key in TARGETS}

    def record(td):
        observations.append(td.select(*agent.modules.encoder.in_keys).clone())
        state = base.privileged_state()
        for key in TARGETS:
            targets[key].append(torch.as_tensor(state[key], dtype=torch.float32))

    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        for seed in seeds:
            env.set_seed(seed)
            if agent.planner is not None:
                agent.planner.reset()
            td = env.reset()
            record(td)
            while play:
                td = env.step(agent.policy(td))
                done = bool(td["next", "done"].any())
                td = step_mdp(td)
                record(td)
                if done:
                    break
    return torch.stack(observations), {key: torch.stack(v) for key, v in targets.items()}


def _standardised(z: torch.Tensor, like: torch.Tensor | None = None) -> torch.Tensor:
    """``z`` standardised per dimension by the statistics of ``like`` (default: its own) over the states: what a
    probe reads, however small the variations."""
    like = z if like is None else like
    return (z - like.mean(0)) / like.std(0).clamp_min(1e-12)


def _probe(z_std: torch.Tensor, y: torch.Tensor, seed: int) -> dict:
    stats = fit_latent_probe(z_std, y.clone(), seed=seed)[1]
    return {"held_out_r2": stats["held_out_r2"], "held_out_mae_m": stats["held_out_mae"]}


def latent_content(agent, observations: TensorDictBase, targets: dict[str, torch.Tensor], seed: int = 0,
                   bf16: bool = False) -> dict:
    """Probe scores and spreads of the latents of ``observations`` (see the module docstring); with ``bf16``, also
    the bf16 autocast rounding of the latents against their spread and the probes on the rounded latents."""
    net = agent.modules.encoder.net
    with torch.no_grad():
        z = agent.modules.encoder.encode(observations)
        coders = {key: net.encode_key(key, observations[key]) for key in net.keys}
    out = {"states": int(z.shape[0]), "latent_spread": float(z.std(0).mean()),
           "coder_relative_spread": {key: float(f.std(0).mean() / f.abs().mean().clamp_min(1e-12))
                                     for key, f in coders.items()}}
    # the probe reads the latent standardised per dimension: what it holds, however small its variations (which the
    # spread above reports, since the reward and the dynamics see them unscaled)
    z_std = _standardised(z)
    for key, y in targets.items():
        out[key] = {**_probe(z_std, y, seed), "std_m": float(y.std(0).mean())}
    if bf16:
        device_type = next(agent.modules.encoder.parameters()).device.type
        with torch.no_grad(), torch.autocast(device_type, dtype=torch.bfloat16):
            z16 = agent.modules.encoder.encode(observations).float()
        rounding = float((z16 - z).abs().mean())
        # the rounded latents standardised by the exact latents' statistics: the rounding counts as the noise it is
        z16_std = _standardised(z16, like=z)
        out["bf16"] = {"rounding": rounding, "rounding_to_spread": rounding / max(out["latent_spread"], 1e-12),
                       **{key: _probe(z16_std, y, seed) for key, y in targets.items()}}
    if not agent.modules.cfg.fuse_latent:  # a compartmentalised latent: what each key's block holds on its own
        out["blocks"] = {}
        for block, where in net.latent_slices.items():
            zb = z_std[:, where]
            out["blocks"][block] = {"spread": float(z[:, where].std(0).mean()), **{
                key: fit_latent_probe(zb, y.clone(), seed=seed)[1]["held_out_r2"] for key, y in targets.items()}}
    return out


def add_state_set_arguments(p: argparse.ArgumentParser, resets: int, episodes: int) -> None:
    """The checkpoint, ``--resets``, ``--episodes`` and ``--out`` arguments of a diagnostic over :func:`state_sets`."""
    p.add_argument("checkpoint", type=Path)
    p.add_argument("--resets", type=int, default=resets, help="initial states of held-out evaluation seeds")
    p.add_argument("--episodes", type=int, default=episodes, help="episodes played by the checkpoint's agent")
    p.add_argument("--out", type=Path, default=None, help="also write the result to this JSON file")


def state_sets(agent, resets: int, episodes: int) -> tuple[tuple | None, list[tuple]]:
    """In the checkpoint's own evaluation env: the initial states of ``resets`` held-out evaluation seeds (one
    :func:`visited_states` set, None for 0), and each of its first ``episodes`` fixed evaluation episodes played by
    the agent (one set per episode).

    Raises:
        SystemExit: a negative count, or both 0.
    """
    from torchrl_mpail2.trainers.evaluation import (
        HELD_OUT_SEED_OFFSET, evaluation_env, evaluation_seeds, run_eval_seed,
    )

    if min(episodes, resets) < 0 or episodes + resets == 0:
        raise SystemExit("--episodes and --resets must be >= 0, one of them > 0")
    train = agent.run_config["train"]
    env = evaluation_env(train)
    try:
        at_reset = None
        if resets:
            seeds = evaluation_seeds(run_eval_seed(train) + HELD_OUT_SEED_OFFSET, resets)
            at_reset = visited_states(agent, env, seeds, play=False)
        played = [visited_states(agent, env, [seed]) for seed in evaluation_seeds(run_eval_seed(train), episodes)]
    finally:
        env.close()
    return at_reset, played


def write_result(result: dict, out: Path | None) -> dict:
    """Prints ``result`` as JSON, and writes it to ``out`` when given."""
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(result, indent=2))
    print(json.dumps(result, indent=2))
    return result


def main(argv: list[str] | None = None) -> dict:
    from torchrl_mpail2.agents import MPAIL2Agent

    p = argparse.ArgumentParser(prog="python -m torchrl_mpail2.diagnostics latent_content", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_state_set_arguments(p, resets=200, episodes=3)
    p.add_argument("--bf16", action="store_true", help="also encode under bf16 autocast (train.update_precision=bf16): "
                   "the rounding beside the latent's spread, and the probes on the rounded latents")
    p.add_argument("--untrained", action="store_true",
                   help="re-initialise the encoder's weights first (its observation normalisation kept): what the "
                        "same architecture reads before training, to compare with")
    args = p.parse_args(argv)
    agent = MPAIL2Agent.from_checkpoint(args.checkpoint)
    if args.untrained:
        torch.manual_seed(0)
        for module in agent.modules.encoder.modules():
            if hasattr(module, "reset_parameters"):
                module.reset_parameters()
    at_reset, played = state_sets(agent, args.resets, args.episodes)
    result = {"checkpoint": str(args.checkpoint), "untrained_encoder": args.untrained, "episodes": args.episodes,
              "resets": args.resets}
    if at_reset is not None:
        result["at_reset"] = latent_content(agent, *at_reset, bf16=args.bf16)
    if played:
        result["played"] = latent_content(agent, torch.cat([o for o, _ in played]),
                                          {key: torch.cat([t[key] for _, t in played]) for key in TARGETS}, bf16=args.bf16)
    return write_result(result, args.out)
