"""Does the WGAN critic learn what makes a demonstration expert-like, or memorise the demonstrations?

    python -m torchrl_mpail2.diagnostics critic_generalisation [--train 10] [--heldout 20] [--agent 20]
        [--steps 2000] [--gp-coefs 0.1 10] [--out F.json]

For each demonstration style (the noiseless scripted Lift expert as recorded today; the human-like one:
per-episode speed, approach path, drift and pauses, recordings ending 10 steps after success), a critic is
trained as in MPAIL2 (the package's reward network and loss, beta = 0.1 or each of ``--gp-coefs``, on latents of
the package's encoder at initialisation, frozen, normalised by the training demos) on ``--train`` demonstrations
against a noisy copy of the scripted expert (Gaussian action noise, std 0.3; the same agent set for every style).
It is then scored on ``--heldout`` unseen expert episodes of the same style. Reported per style and beta: the mean
critic gap (expert minus agent) on the training demos and on the held-out episodes, the held-out AUC (the chance
that a held-out expert transition outscores an agent transition; 0.5 is chance), the critic's input-gradient norm
on the agent and held-out expert pairs (the gradient penalty pulls it towards 1), and the held-out gap in units of
the agent scores' standard deviation. Prints one line per style and beta; ``--out`` writes the result to a JSON file.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch

from torchrl_mpail2.config import ModelConfig
from torchrl_mpail2.data import DemoBuffer, record_demos
from torchrl_mpail2.envs import make_env
from torchrl_mpail2.experts import get_expert
from torchrl_mpail2.modules import MPAIL2Modules
from torchrl_mpail2.objectives.reward import AdversarialRewardLoss

ENV = "robosuite/Lift"
STYLES = {"scripted": ({}, None), "human_like": ({"human_like": True}, 10)}
TRAIN_SEED, HELDOUT_SEED, AGENT_SEED = 1_000_000, 3_000_000, 4_000_000
AGENT_NOISE_STD = 0.3


def record(style: str | None, episodes: int, seed: int):
    env = make_env(ENV, seed=seed)
    if style is None:
        expert, stop = get_expert(ENV, env, noise_std=AGENT_NOISE_STD, seed=seed), None
    else:
        options, stop = STYLES[style]
        expert = get_expert(ENV, env, **({"seed": seed, **options} if options else {}))
    return record_demos(env, expert, episodes, seed=seed, progress=False, env_id=ENV, steps_after_success=stop)


def all_pairs(demos, keys):
    """Every transition ``(o, o')`` of a demonstration set, as a flat TensorDict."""
    episodes = [demos.episode(i).select(*keys) for i in range(demos.num_episodes)]
    pairs = torch.cat([e[:-1] for e in episodes])
    pairs.set("next", torch.cat([e[1:] for e in episodes]))
    return pairs


def auc(expert: torch.Tensor, agent: torch.Tensor) -> float:
    return float((expert[:, None] > agent[None, :]).float().mean())


def gradient_norm(critic, z: torch.Tensor, z_next: torch.Tensor) -> float:
    """Mean norm of the critic's gradient with respect to its input pair ``(z, z')``."""
    z, z_next = z.detach().requires_grad_(True), z_next.detach().requires_grad_(True)
    grads = torch.autograd.grad(critic(z, z_next).sum(), (z, z_next))
    return float(torch.cat(grads, dim=-1).norm(dim=-1).mean())


def run_style(style: str, agent_demos, args, gp_coef: float = 0.1) -> dict:
    torch.manual_seed(0)
    train = record(style, args.train, TRAIN_SEED)
    heldout = record(style, args.heldout, HELDOUT_SEED)
    shapes = {k: list(v.shape[1:]) for k, v in train.observations.items() if v.is_floating_point()}
    modules = MPAIL2Modules(shapes, 4, ModelConfig(latent_dim=128, hidden_dims=(256, 256), vector_coder_hidden=128,
                                                   coder_dim=256))
    generator = torch.Generator().manual_seed(0)
    train_buf, agent_buf = DemoBuffer(train, generator=generator), DemoBuffer(agent_demos, generator=generator)
    modules.normalize_from_demos(train)
    loss = AdversarialRewardLoss(modules.encoder, modules.reward, gp_coef=gp_coef)
    opt = torch.optim.Adam(modules.reward.parameters(), lr=3e-4)
    encode = modules.encoder.encode
    start = time.perf_counter()
    for _ in range(args.steps):
        agent, expert = agent_buf.sample_pairs(args.batch), train_buf.sample_pairs(args.batch)
        with torch.no_grad():
            latents = (encode(agent), encode(agent, ("next",)))
            expert_latents = (encode(expert), encode(expert, ("next",)))
        out = loss(agent, latents=latents, expert_latents=expert_latents)
        opt.zero_grad()
        out["loss_reward"].backward()
        opt.step()

    critic = modules.reward.module.critic

    def latents(demos):
        pairs = all_pairs(demos, modules.encoder.in_keys)
        with torch.no_grad():
            return encode(pairs), encode(pairs, ("next",))

    z_train, z_held, z_agent = latents(train), latents(heldout), latents(agent_demos)
    with torch.no_grad():
        s_train, s_held, s_agent = (critic(*z).flatten() for z in (z_train, z_held, z_agent))
    return {"style": style, "gp_coef": gp_coef, "train_demos": args.train, "heldout_episodes": args.heldout,
            "train_success": train.success_rate, "heldout_success": heldout.success_rate,
            "train_lengths": train.episode_lengths, "heldout_lengths": heldout.episode_lengths,
            "train_gap": float(s_train.mean() - s_agent.mean()), "heldout_gap": float(s_held.mean() - s_agent.mean()),
            "train_auc": auc(s_train, s_agent), "heldout_auc": auc(s_held, s_agent),
            "grad_norm_agent": gradient_norm(critic, *z_agent), "grad_norm_heldout": gradient_norm(critic, *z_held),
            "heldout_gap_over_agent_std": float((s_held.mean() - s_agent.mean()) / s_agent.std()),
            "critic_train_s": time.perf_counter() - start}


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--train", type=int, default=10)
    p.add_argument("--heldout", type=int, default=20)
    p.add_argument("--agent", type=int, default=20)
    p.add_argument("--steps", type=int, default=2000)
    p.add_argument("--batch", type=int, default=256)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--styles", nargs="+", default=list(STYLES), choices=list(STYLES))
    p.add_argument("--gp-coefs", nargs="+", type=float, default=[0.1], help="gradient-penalty coefficients beta")
    p.add_argument("--out", type=Path, help="write the result to this JSON file")
    args = p.parse_args(argv)
    if any(b < 0 for b in args.gp_coefs):
        p.error(f"--gp-coefs must be non-negative, got {args.gp_coefs}")
    torch.set_num_threads(args.threads)
    agent_demos = record(None, args.agent, AGENT_SEED)
    rows = [run_style(style, agent_demos, args, beta) for style in args.styles for beta in args.gp_coefs]
    result = {"env": ENV, "agent": f"scripted expert with Gaussian action noise std {AGENT_NOISE_STD}",
              "agent_success": agent_demos.success_rate, "critic_steps": args.steps, "batch": args.batch,
              "critic": "package reward network and loss on frozen initial-encoder latents", "gp_coefs": args.gp_coefs,
              "styles": rows}
    if args.out:
        args.out.write_text(json.dumps(result, indent=2) + "\n")
    for r in rows:
        print(f"{r['style']:11s} beta {r['gp_coef']:6g} |grad| {r['grad_norm_agent']:7.2f}  "
              f"train gap {r['train_gap']:8.1f}  held-out gap {r['heldout_gap']:8.1f}  "
              f"train AUC {r['train_auc']:.3f}  held-out AUC {r['heldout_auc']:.3f}  "
              f"(demo success {r['train_success']:.2f} / {r['heldout_success']:.2f})")


if __name__ == "__main__":
    main()
