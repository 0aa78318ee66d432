"""Milliseconds per robosuite env step with cameras against the state step, with each renderer.

    python -m benchmarks.speed.camera_step [--task Push] [--steps 50] [--rounds 3] [--name camera_step]

Every (observation mode, renderer) pair is one env in one process (one torch thread), built and warmed up first;
the pairs then take turns, ``--steps`` random-action steps each per round (an episode reset whenever the horizon
ends it), so that whatever else runs on the machine slows them alike. Reports the median over rounds of the
milliseconds per step and each pair's ratio to the state step. Writes ``docs/results/speed/<name>.json`` and
``<name>.md``.
"""
from __future__ import annotations

import argparse
import statistics
import time

from benchmarks.records import ROOT, write_record

RESULTS = ROOT / "docs" / "results" / "speed"
PAIRS = (("state", "light"), ("pixels", "light"), ("external_pixels", "light"), ("pixels", "full"),
         ("external_pixels", "full"))
WARMUP_STEPS = 20


def timed_steps(env, td, steps: int):
    """``steps`` random-action steps from ``td`` (resetting at episode ends); returns (ms per step, last td)."""
    start = time.perf_counter()
    for _ in range(steps):
        td = env.rand_step(td)
        td = env.reset() if bool(td["next", "done"]) else td["next"].clone()
    return (time.perf_counter() - start) / steps * 1e3, td


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", default="Push", choices=("Lift", "Push", "PushMirrored"))
    p.add_argument("--steps", type=int, default=50)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--name", default="camera_step")
    p.add_argument("--note", default="", help="what else ran on the machine")
    args = p.parse_args()

    import torch

    from torchrl_mpail2.envs.robosuite_env import make_robosuite_env

    torch.set_num_threads(1)
    envs = {}
    for obs, renderer in PAIRS:
        env = make_robosuite_env(args.task, obs=obs, seed=0, renderer=renderer)
        _, td = timed_steps(env, env.reset(), WARMUP_STEPS)
        envs[(obs, renderer)] = [env, td, []]
    for _ in range(args.rounds):
        for entry in envs.values():
            ms, entry[1] = timed_steps(entry[0], entry[1], args.steps)
            entry[2].append(ms)
    state_ms = statistics.median(envs[("state", "light")][2])
    rows = [{"obs": obs, "renderer": renderer if obs != "state" else "-", "ms_per_step": statistics.median(e[2]),
             "ms_per_round": e[2], "ratio_to_state": statistics.median(e[2]) / state_ms}
            for (obs, renderer), e in envs.items()]

    def markdown(commit) -> str:
        lines = [f"# robosuite {args.task}: env step with cameras (commit {commit})", "",
                 f"{args.rounds} rounds of {args.steps} random steps per pair, pairs interleaved, one torch thread. "
                 f"{args.note}", "", "| observations | renderer | ms per step | x state step |", "|---|---|---:|---:|"]
        lines += [f"| {r['obs']} | {r['renderer']} | {r['ms_per_step']:.1f} | {r['ratio_to_state']:.1f} |" for r in rows]
        return "\n".join(lines) + "\n"

    write_record(RESULTS, args.name, {"task": args.task, "steps": args.steps, "rounds": args.rounds, "rows": rows},
                 args.note, ROOT, markdown)
    print(markdown(None))


if __name__ == "__main__":
    main()
