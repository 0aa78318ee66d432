"""Command line: ``python -m torchrl_mpail2.train --preset point_mass [section.field=value ...]``.

Also ``--env X`` / ``--obs Y``, shorthand for the overrides ``train.env=X`` / ``train.obs=Y`` (nothing else
changes), ``--resume RUN_DIR`` to continue a run (with overrides of
``train.total_episodes``, ``train.max_wall_s``, ``train.progress`` or ``train.threads`` only, e.g. to extend
it), ``--overwrite`` to replace the run in an existing run folder, ``--init-from CKPT --transfer
all|world-model`` to start from another run's weights, ``--print-config`` to show the resolved config and
``--help-config [SECTION]`` to list every field (type, the preset's value, what it does). A bad field or value is one
line on stderr and exit status 2, as argparse reports a bad flag.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import textwrap

from torchrl_mpail2.config import (PRESETS, RESUME_FIELDS, ConfigError, ExperimentConfig, apply_overrides, field_docs,
                                   field_kind, preset)
from torchrl_mpail2.data.checkpoint import CheckpointError
from torchrl_mpail2.trainers.run_folder import RunFolderError


def build_parser(default_preset: str, description: str | None) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=description or __doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--preset", default=default_preset, choices=sorted(PRESETS))
    p.add_argument("--env", help="shorthand for train.env=ENV (see torchrl_mpail2.envs.ENV_NAMES)")
    p.add_argument("--obs", help="shorthand for train.obs=OBS: state | pixels | external_pixels (robosuite)")
    p.add_argument("--resume", metavar="RUN_DIR",
                   help=f"continue the run in RUN_DIR from its newest complete checkpoint (overrides: {', '.join(RESUME_FIELDS)})")
    p.add_argument("--allow-other-demos", action="store_true",
                   help="with --resume: go on although the demonstrations differ from those the run was trained on")
    p.add_argument("--overwrite", action="store_true", help="replace the run already in train.run_dir")
    p.add_argument("--init-from", metavar="CKPT", help="initialise weights from another run's checkpoint folder")
    p.add_argument("--transfer", default="all", choices=["all", "world-model"])
    p.add_argument("--print-config", action="store_true", help="print the resolved config and exit")
    p.add_argument("--help-config", nargs="?", const="all", metavar="SECTION",
                   choices=["all", *(f.name for f in dataclasses.fields(ExperimentConfig))],
                   help="list every config field (or one section's: train, model, loss, planner) with its type, the "
                        "preset's value and what it does, then exit")
    return p


def describe_config(cfg: ExperimentConfig, section: str = "all", width: int = 100) -> str:
    """Every field of ``cfg`` (or of one ``section``) as ``section.field (type) = value`` and its docstring."""
    lines = []
    for part in dataclasses.fields(cfg):
        if section not in ("all", part.name):
            continue
        values = getattr(cfg, part.name)
        cls = type(values)
        lines.append(f"{part.name}: {inspect_doc(cls)}")
        for name, doc in field_docs(cls).items():
            value = json.dumps(getattr(values, name), default=str)
            lines.append(f"  {part.name}.{name} ({field_kind(cls, name).describe()}) = {value}")
            lines += textwrap.wrap(" ".join(doc.split()), width, initial_indent=" " * 6, subsequent_indent=" " * 6)
        lines.append("")
    return "\n".join(lines)


def inspect_doc(cls: type) -> str:
    return (cls.__doc__ or "").strip().splitlines()[0]


def main(argv: list[str] | None = None, default_preset: str = "lift_state", description: str | None = None) -> dict | None:
    """Parses arguments, builds (or resumes) a :class:`MPAIL2Trainer`, trains, prints the summary."""
    parser = build_parser(default_preset, description)
    args, overrides = parser.parse_known_args(argv)
    try:
        return _run(args, overrides)
    except (ConfigError, RunFolderError) as error:  # a bad field, value or run folder: the message names it
        parser.exit(2, f"{parser.prog}: error: {error}\n")
    except CheckpointError as error:  # a damaged or unfitting checkpoint, or a full disk: named in the message
        parser.exit(1, f"{parser.prog}: error: {error}\n")


def _run(args, overrides: list[str]) -> dict | None:
    from torchrl_mpail2.trainers.trainer import MPAIL2Trainer

    if args.resume:
        if args.init_from:
            raise ConfigError(f"--init-from {args.init_from} with --resume {args.resume}: a resumed run keeps its own "
                              "weights; transfer into a new run instead")
        try:
            trainer = MPAIL2Trainer.resume(args.resume, overrides, allow_other_demos=args.allow_other_demos)
        except (ConfigError, FileNotFoundError) as error:
            raise ConfigError(f"--resume {args.resume}: {error}") from error
    else:
        shorthand = [f"train.{name}={value}" for name, value in (("env", args.env), ("obs", args.obs)) if value]
        cfg = apply_overrides(preset(args.preset), [*shorthand, *overrides])
        if args.help_config:
            print(f"Config fields (values of --preset {args.preset} with the overrides given):\n")
            print(describe_config(cfg, args.help_config))
            return None
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
