"""Command line for observation-only demonstrations.

Usage::

    python -m torchrl_mpail2.demos record --env point_mass --obs state --episodes 20 --seed 0 --out demos/point_mass
    python -m torchrl_mpail2.demos record --env robosuite/Lift --episodes 10 --lift-speed 0.005 --out demos/lift_slow
    python -m torchrl_mpail2.demos import robosuite_hdf5 demo.hdf5 --env robosuite/Lift --obs state --out demos/lift_teleop
    python -m torchrl_mpail2.demos info demos/point_mass
"""
from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from torchrl_mpail2.data import DEMO_SOURCES, load_demo_source, load_demos, record_demos, save_demos
from torchrl_mpail2.envs.factory import ENV_NAMES, make_env


def _record(args: argparse.Namespace) -> None:
    from torchrl_mpail2.experts import get_expert

    if args.lift_speed is not None and args.env != "robosuite/Lift":
        raise SystemExit(f"--lift-speed applies to robosuite/Lift only, not {args.env}.")
    if args.human_like and not args.env.startswith("robosuite/"):
        raise SystemExit(f"--human-like applies to the scripted robosuite experts only, not {args.env}.")
    env = make_env(args.env, obs=args.obs, seed=args.seed)
    options = {} if args.lift_speed is None else {"max_lift_speed": args.lift_speed}
    if args.human_like:
        options.update(human_like=True, seed=args.seed)
    expert = get_expert(args.env, env, **options)
    demos = record_demos(
        env,
        expert,
        episodes=args.episodes,
        out=args.out,
        seed=args.seed,
        progress=not args.no_progress,
        env_id=args.env,
        env_kwargs={"obs": args.obs},
        overwrite=args.overwrite,
        steps_after_success=args.steps_after_success,
    )
    print(f"wrote {args.out}")
    print(demos.summary())


def _import(args: argparse.Namespace) -> None:
    env = make_env(args.env, obs=args.obs)
    demos = load_demo_source(f"{args.format}:{args.path}", env, progress=not args.no_progress)
    demos.header["env_kwargs"] = {"obs": args.obs}
    if demos.env_id == "custom":  # formats that do not name the env: the one the observations were checked against
        demos.header["env_id"] = args.env
    save_demos(demos, args.out, overwrite=args.overwrite)
    print(f"wrote {args.out}")
    print(demos.summary())


def _info(args: argparse.Namespace) -> None:
    print(load_demos(args.path, verify=not args.no_verify).summary())


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m torchrl_mpail2.demos", description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)

    record = commands.add_parser("record", help="roll the env's expert out and save its observations")
    record.add_argument("--env", required=True, choices=ENV_NAMES)
    record.add_argument("--obs", default="state", help="observation mode (non-state modes: robosuite only)")
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
    imports.add_argument("--env", required=True, choices=ENV_NAMES, help="the env the recording is replayed through")
    imports.add_argument("--obs", default="state", help="observation mode of the imported demos")
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
