"""Command line for observation-only demonstrations.

Usage::

    python -m torchrl_mpail2.demos record --env point_mass --obs state --episodes 20 --seed 0 --out demos/point_mass
    python -m torchrl_mpail2.demos record --env robosuite/Lift --episodes 10 --lift-speed 0.005 --out demos/lift_slow
    python -m torchrl_mpail2.demos import robosuite_hdf5 demo.hdf5 --env robosuite/Lift --obs state --out demos/lift_teleop
    python -m torchrl_mpail2.demos import robosuite_hdf5 demo.hdf5 --preset lift_state --out demos/lift_teleop_cmd
    python -m torchrl_mpail2.demos import robomimic low_dim.hdf5 --env robosuite/Lift --filter-key train --out demos/rm
    python -m torchrl_mpail2.demos info demos/point_mass

``--preset NAME`` builds the env as that training preset does (its ``train.env``, ``train.obs`` and
``train.env_kwargs``), so that the demonstrations match the env they train; ``--env``, ``--obs`` and ``--env-kwargs``
override its choices.
"""
from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence

from torchrl_mpail2.data import DEMO_SOURCES, load_demo_source, load_demos, record_demos, save_demos
from torchrl_mpail2.envs.factory import ENV_NAMES, make_env
from torchrl_mpail2.config import PRESETS, ExperimentConfig, TrainConfig, preset
from torchrl_mpail2.trainers.run_demos import env_options


def _json_object(text: str) -> dict:
    """``--env-kwargs``: a JSON object of ``make_env`` keyword arguments."""
    try:
        value = json.loads(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(f"not JSON ({error}): {text!r}") from error
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError(f"expected a JSON object such as '{{\"observe_gripper_command\": true}}', "
                                         f"got {text!r}")
    if "obs" in value:
        raise argparse.ArgumentTypeError("give the observation mode with --obs, not in --env-kwargs")
    return value


def _env_options(args: argparse.Namespace) -> tuple[str, dict]:
    """``(env name, env options)`` as a run of ``--preset`` would build its env, with ``--env``, ``--obs`` and
    ``--env-kwargs`` (key by key) over the preset's choices; the options are those headers record."""
    if args.env is None and args.preset is None:
        raise SystemExit("give the env with --env, or a training preset with --preset")
    cfg = preset(args.preset) if args.preset else ExperimentConfig()
    t = cfg.train
    t.env, t.obs = args.env or t.env, args.obs or t.obs
    t.env_kwargs = {**(t.env_kwargs or {}), **(args.env_kwargs or {})}
    return t.env, env_options(cfg)


def _add_env_arguments(parser: argparse.ArgumentParser, env_help: str) -> None:
    """The arguments that choose the env, shared by ``record`` and ``import``."""
    parser.add_argument("--env", choices=ENV_NAMES, help=f"{env_help} (default: the preset's)")
    parser.add_argument("--obs", default=None,
                        help=f"observation mode (default: the preset's, else {TrainConfig.obs}; non-state modes: "
                             "robosuite and point_mass)")
    parser.add_argument("--preset", choices=sorted(PRESETS),
                        help="build the env as this training preset does (train.env, train.obs, train.env_kwargs)")
    parser.add_argument("--env-kwargs", type=_json_object, default=None, metavar="JSON",
                        help="make_env options as a JSON object, over the preset's "
                             "(e.g. '{\"observe_gripper_command\": true}')")


def _record(args: argparse.Namespace) -> None:
    from torchrl_mpail2.experts import get_expert

    name, options = _env_options(args)
    if args.lift_speed is not None and name != "robosuite/Lift":
        raise SystemExit(f"--lift-speed applies to robosuite/Lift only, not {name}.")
    if args.human_like and not name.startswith("robosuite/"):
        raise SystemExit(f"--human-like applies to the scripted robosuite experts only, not {name}.")
    env = make_env(name, seed=args.seed, **options)
    expert_options = {} if args.lift_speed is None else {"max_lift_speed": args.lift_speed}
    if args.human_like:
        expert_options.update(human_like=True, seed=args.seed)
    expert = get_expert(name, env, **expert_options)
    demos = record_demos(
        env,
        expert,
        episodes=args.episodes,
        out=args.out,
        seed=args.seed,
        progress=not args.no_progress,
        env_id=name,
        env_kwargs=options,
        overwrite=args.overwrite,
        steps_after_success=args.steps_after_success,
    )
    print(f"wrote {args.out}")
    print(demos.summary())


def _import(args: argparse.Namespace) -> None:
    if args.filter_key is not None and args.format != "robomimic":
        raise SystemExit(f"--filter-key applies to robomimic files only, not {args.format}")
    name, options = _env_options(args)
    env = make_env(name, **options)
    importer_kwargs = {} if args.filter_key is None else {"filter_key": args.filter_key}
    demos = load_demo_source(f"{args.format}:{args.path}", env, progress=not args.no_progress, env_kwargs=options,
                             importer_kwargs=importer_kwargs)
    if demos.env_id == "custom":  # formats that do not name the env: the one the observations were checked against
        demos.header["env_id"] = name
    save_demos(demos, args.out, overwrite=args.overwrite)
    print(f"wrote {args.out}")
    print(demos.summary())


def _info(args: argparse.Namespace) -> None:
    print(load_demos(args.path, verify=not args.no_verify).summary())


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m torchrl_mpail2.demos", description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)

    record = commands.add_parser("record", help="roll the env's expert out and save its observations")
    _add_env_arguments(record, "the env whose scripted expert is recorded")
    record.add_argument("--episodes", type=int, default=20)
    record.add_argument("--seed", type=int, default=0, help="episode i is seeded with seed + i")
    record.add_argument("--out", required=True, help="output directory (must not exist unless --overwrite)")
    record.add_argument("--lift-speed", type=float, default=None,
                        help="robosuite/Lift only: the scripted expert lifts at most this many metres per step")
    record.add_argument("--human-like", action="store_true",
                        help="scripted robosuite experts: vary speed, approach path, drift and pauses per episode")
    record.add_argument("--steps-after-success", type=int, default=None,
                        help="end each recording this many steps after its first success")
    record.add_argument("--overwrite", action="store_true")
    record.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    record.set_defaults(run=_record)

    imports = commands.add_parser("import", help="convert another format's recordings (observations only)")
    imports.add_argument("format", choices=sorted(DEMO_SOURCES))
    imports.add_argument("path", help="what to import (robosuite_hdf5: robosuite's demo.hdf5; ted: a folder of "
                         "td.memmap(PATH) holding TorchRL TED transitions; minari: a local Minari dataset folder; "
                         "robomimic: a robomimic low-dim or image .hdf5)")
    _add_env_arguments(imports, "the env the recording is replayed through or checked against")
    imports.add_argument("--filter-key", default=None,
                         help="robomimic only: import the demos of this split of the file's mask (e.g. train)")
    imports.add_argument("--out", required=True, help="output directory (must not exist unless --overwrite)")
    imports.add_argument("--overwrite", action="store_true")
    imports.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    imports.set_defaults(run=_import)

    info = commands.add_parser("info", help="validate a demo directory and print its header summary")
    info.add_argument("path")
    info.add_argument("--no-verify", action="store_true", help="skip sha256 checks (sizes are still checked)")
    info.set_defaults(run=_info)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    args.run(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
