"""Command line: ``python -m torchrl_mpail2.train --preset point_mass [section.field=value ...]``.

Also ``--env X`` / ``--obs Y``, shorthand for the overrides ``train.env=X`` / ``train.obs=Y`` (nothing else
changes: the ``lift_pixels`` preset has the image-sized latent), ``--resume RUN_DIR`` to continue a run (with overrides of
``train.total_episodes``, ``train.max_wall_s``, ``train.progress`` or ``train.threads`` only, e.g. to extend
it), ``--overwrite`` to replace the run in an existing run folder, ``--init-from CKPT --transfer
all|world-model`` to start from another run's weights, and ``--print-config`` to show the resolved config.
"""
from __future__ import annotations

import argparse
import json
import sys

from torchrl_mpail2.config import ConfigError
from torchrl_mpail2.trainers.config import RESUME_FIELDS, apply_overrides
from torchrl_mpail2.trainers.presets import PRESETS, preset


def build_parser(default_preset: str, description: str | None) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=description or __doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--preset", default=default_preset, choices=sorted(PRESETS))
    p.add_argument("--env", help="shorthand for train.env=ENV (see torchrl_mpail2.envs.ENV_NAMES)")
    p.add_argument("--obs", help="shorthand for train.obs=OBS: state | pixels | external_pixels (robosuite)")
    p.add_argument("--resume", metavar="RUN_DIR",
                   help=f"continue the run in RUN_DIR from its newest complete checkpoint (overrides: {', '.join(RESUME_FIELDS)})")
    p.add_argument("--overwrite", action="store_true", help="replace the run already in train.run_dir")
    p.add_argument("--init-from", metavar="CKPT", help="initialise weights from another run's checkpoint folder")
    p.add_argument("--transfer", default="all", choices=["all", "world-model"])
    p.add_argument("--print-config", action="store_true", help="print the resolved config and exit")
    return p


def main(argv: list[str] | None = None, default_preset: str = "lift_state", description: str | None = None) -> dict | None:
    """Parses arguments, builds (or resumes) a :class:`MPAIL2Trainer`, trains, prints the summary."""
    args, overrides = build_parser(default_preset, description).parse_known_args(argv)
    from torchrl_mpail2.trainers.trainer import MPAIL2Trainer

    if args.resume:
        try:
            trainer = MPAIL2Trainer.resume(args.resume, overrides)
        except ConfigError as error:
            sys.exit(f"--resume {args.resume}: {error}")
    else:
        shorthand = [f"train.{name}={value}" for name, value in (("env", args.env), ("obs", args.obs)) if value]
        cfg = apply_overrides(preset(args.preset), [*shorthand, *overrides])
        print(cfg.to_json())
        if args.print_config:
            return None
        trainer = MPAIL2Trainer(cfg, if_exists="overwrite" if args.overwrite else "refuse")
        if args.init_from:
            trainer.init_from(args.init_from, args.transfer)
    print(f"run folder: {trainer.run_dir}")
    summary = trainer.train()
    print(json.dumps(summary, indent=2))
    return summary


if __name__ == "__main__":
    main()
