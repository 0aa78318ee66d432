"""Diagnostic: how good are the policy's plans by the planner's own score, next to the plans MPPI finds?

    python -m torchrl_mpail2.diagnostics actor_vs_planner RUN_DIR [--checkpoint last] [--steps 500] [--out F.json]

Loads a run's checkpoint, collects start states from random-action rollouts of the run's environment, and
scores plans with :meth:`LatentMPPIPlanner.score` (the planner's return, two Q heads): the policy's mean plan
and MPPI's final mean. Then, with dynamics, reward and Q frozen, it re-trains
a freshly initialised policy for ``--steps`` Adam steps under three objectives and scores its mean plan again:
``actor`` (the package's actor loss: stochastic plans, lambda-return, entropy), ``deterministic_lambda`` (the mean
plan's lambda-return) and ``deterministic_planner`` (the mean plan's planner return). Prints the scores; ``--out``
writes them, with the re-training curves, to a JSON file.
"""
from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import torch

from torchrl_mpail2.objectives.imagination import ensemble_estimate, frozen, imagined_lambda_return
from torchrl_mpail2.trainers import MPAIL2Trainer
from torchrl_mpail2.data import checkpoint as ckpt
from torchrl_mpail2.config import ExperimentConfig

OBJECTIVES = ("actor", "deterministic_lambda", "deterministic_planner")


def _reinit(module: torch.nn.Module) -> None:
    for sub in module.modules():
        if sub is not module and hasattr(sub, "reset_parameters"):
            sub.reset_parameters()


def _objective(name: str, trainer: MPAIL2Trainer, z: torch.Tensor, heads: torch.Tensor) -> torch.Tensor:
    m, loss = trainer.agent.modules, trainer.agent.loss
    if name == "actor":
        return loss.actor_loss(None, latents=(z, None))["loss_actor"]
    plan = m.policy.net(z, deterministic=True)[0]
    with frozen(m.dynamics, m.reward, m.value):
        if name == "deterministic_lambda":
            return -imagined_lambda_return(z, plan, m.dynamics.module, m.reward.module, ensemble_estimate(m.value.net, "mean"),
                                           m.policy.net, loss.cfg.gamma, loss.cfg.lmbda).mean()
        return -trainer.agent.planner.score(z, plan.unsqueeze(1), heads).mean()


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_dir", type=Path)
    p.add_argument("--checkpoint", default="last")
    p.add_argument("--steps", type=int, default=500)
    p.add_argument("--rollouts", type=int, default=3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, help="write the result to this JSON file")
    args = p.parse_args(argv)
    if not (args.run_dir / "checkpoints" / args.checkpoint).is_dir():
        raise SystemExit(f"no checkpoint {args.run_dir / 'checkpoints' / args.checkpoint}")
    with tempfile.TemporaryDirectory() as scratch:  # the rebuilt trainer's own run folder, not kept
        result = compare(args, Path(scratch))
    if args.out:
        args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps({k: v for k, v in result.items() if k != "retrained"}, indent=2))


def compare(args: argparse.Namespace, scratch: Path) -> dict:
    """Scores the policy's and MPPI's mean plans, then re-trains the policy under each of :data:`OBJECTIVES`."""
    torch.manual_seed(args.seed)
    cfg = ExperimentConfig.from_dict(json.loads((args.run_dir / "config.json").read_text()))
    cfg.train.run_dir = str(scratch)
    trainer = MPAIL2Trainer(cfg)
    state = ckpt.read_checkpoint(args.run_dir / "checkpoints" / args.checkpoint)
    trainer.agent.modules.load_state_dict(state["modules"])
    trainer.agent.loss.load_state_dict(state["loss"])
    m, planner = trainer.agent.modules, trainer.agent.planner
    keys = m.encoder.in_keys
    starts = torch.cat([trainer.env.rollout(cfg.train.eval_episodes * 10).select(*keys) for _ in range(args.rollouts)], 0)
    heads = torch.arange(2)
    with torch.no_grad():
        z = m.encoder.encode(starts)

    def policy_score() -> float:
        with torch.no_grad():
            return float(planner.score(z, m.policy.net(z, deterministic=True)[0].unsqueeze(1), heads).mean())

    with torch.no_grad():
        planner.reset()
        mean, _, influence = planner._optimise(starts)
        mppi_mean = float(planner.score(z, mean.unsqueeze(1), heads).mean())
    result = {"run": str(args.run_dir), "checkpoint": args.checkpoint, "start_states": int(z.shape[0]),
              "score": "planner return: sum_k gamma^k r(z_k, z_k+1) + gamma^H Q(z_H, pi(z_H)), mean over start states",
              "policy_mean_plan": policy_score(), "mppi_final_mean_plan": mppi_mean,
              "mppi_policy_influence": float(influence.mean()), "retrained": {}}
    for name in OBJECTIVES:
        _reinit(m.policy)
        opt = torch.optim.Adam(m.policy.parameters(), lr=cfg.loss.lr)
        curve = [policy_score()]
        for step in range(args.steps):
            batch = z[torch.randint(len(z), (cfg.train.batch_size,))]
            loss = _objective(name, trainer, batch, heads)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(m.policy.parameters(), cfg.loss.policy_grad_clip)
            opt.step()
            if (step + 1) % max(1, args.steps // 5) == 0:
                curve.append(policy_score())
        result["retrained"][name] = {"policy_mean_plan": curve[-1], "curve": curve}
        print(name, [round(c, 3) for c in curve], flush=True)
    trainer.env.close()
    return result


if __name__ == "__main__":
    main()
