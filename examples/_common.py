"""Shared command line of the examples: a preset, a few shortcuts, then ``section.field=value`` overrides."""
from __future__ import annotations

import argparse
import json

from torchrl_mpail2.trainers import MPAIL2Trainer, apply_overrides, preset


def run(default_preset: str, description: str, env: str | None = None, argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--preset", default=default_preset)
    parser.add_argument("--env", default=env, help="environment name (see torchrl_mpail2.envs.ENV_NAMES)")
    parser.add_argument("--obs", default=None, help="state | pixels | external_pixels (robosuite)")
    parser.add_argument("--resume", metavar="RUN_DIR", help="continue a run from its last checkpoint")
    parser.add_argument("--init-from", metavar="CKPT", help="start from another run's checkpoint folder")
    parser.add_argument("--transfer", default="all", choices=["all", "world-model"])
    args, overrides = parser.parse_known_args(argv)

    if args.resume:
        trainer = MPAIL2Trainer.resume(args.resume)
    else:
        cfg = preset(args.preset)
        if args.env:
            cfg.train.env = args.env
        if args.obs:
            cfg.train.obs = args.obs
            if args.obs != "state":
                cfg.model.latent_dim = 512  # Table 4: image latents are 512 wide
        cfg = apply_overrides(cfg, overrides)
        print(cfg.to_json())
        trainer = MPAIL2Trainer(cfg)
        if args.init_from:
            trainer.init_from(args.init_from, args.transfer)
    print(f"run folder: {trainer.run_dir}")
    summary = trainer.train()
    print(json.dumps(summary, indent=2))
    return summary
