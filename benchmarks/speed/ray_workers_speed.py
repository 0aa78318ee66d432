"""Collection speed with Ray workers: environment steps per second of ``train.collector=ray`` on the point mass.

    python -m benchmarks.speed.ray_workers_speed [--workers 1 2 4] [--batches 3] [--out PATH] [--note TEXT]

For each worker count, a :class:`~torchrl_mpail2.trainers.ray_collection.RayEpisodeCollector` of the
``point_mass`` preset's agent (untrained networks; the planner acts, as after the warm-up) collects one batch to
start its workers, then ``--batches`` timed batches of one 50-step episode per worker, the weights sent to every
worker before each batch as in training. No learner update runs in between, so the figure is the collection's
ceiling. The same is measured in this process without Ray (``make_collector``, one env) for reference. Each Ray
worker acts on one thread. All counts share one local Ray of ``max(--workers)`` CPUs.

Writes JSON to ``--out`` (default: a scratch folder under the system's temporary directory). Anything else running
on the machine slows every figure: say what was (``--note``); the record keeps the load average.
"""
from __future__ import annotations

import argparse
import functools
import json
import os
import tempfile
import time
from pathlib import Path

import torch

from benchmarks.records import ROOT, git_commit
from benchmarks.speed.common import machine
from torchrl_mpail2.agents import MPAIL2Agent
from torchrl_mpail2.envs import make_env
from torchrl_mpail2.trainers import preset
from torchrl_mpail2.trainers.collection import make_collector
from torchrl_mpail2.trainers.ray_collection import RayEpisodeCollector, ray_init_kwargs, require_ray

DEFAULT_OUT = Path(tempfile.gettempdir()) / "torchrl_mpail2_bench" / "ray_workers_speed.json"
point_mass = functools.partial(make_env, "point_mass")


def timed_batches(collector, batches: int) -> dict:
    """Steps per second over ``batches`` batches after a first one (workers starting, first weights)."""
    iterator = iter(collector)
    tick = time.perf_counter()
    next(iterator)
    start_s = time.perf_counter() - tick
    steps, tick = 0, time.perf_counter()
    for _ in range(batches):
        steps += int(next(iterator)[("collector", "mask")].sum())
    seconds = time.perf_counter() - tick
    return {"env_steps": steps, "seconds": seconds, "env_steps_per_s": steps / seconds, "first_batch_s": start_s}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2, 4])
    parser.add_argument("--batches", type=int, default=3)
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    parser.add_argument("--note", default="")
    args = parser.parse_args()
    ray = require_ray("benchmarks/speed/ray_workers_speed.py")
    torch.set_num_threads(1)
    os.environ.setdefault("OMP_NUM_THREADS", "1")  # inherited by the Ray workers

    cfg = preset("point_mass")
    env = point_mass()
    torch.manual_seed(0)
    agent = MPAIL2Agent(env.observation_spec, env.action_spec, cfg.model, cfg.loss, cfg.planner)
    agent.actor.random_actions = False
    primer = agent.planner.make_tensordict_primer

    local = make_collector(point_mass, agent.actor, 0, state=primer())
    rows = [{"collector": "local (no Ray)", "workers": 0, **timed_batches(local, args.batches)}]
    local.shutdown()
    print(rows[-1], flush=True)

    ray.init(**ray_init_kwargs(None, max(args.workers)), log_to_driver=False)
    try:
        for workers in args.workers:
            collector = RayEpisodeCollector(point_mass, agent.actor, agent.modules, first_seed=0, workers=workers,
                                            state=primer())
            try:
                rows.append({"collector": "ray", "workers": workers, **timed_batches(collector, args.batches)})
            finally:
                collector.shutdown()
            print(rows[-1], flush=True)
    finally:
        ray.shutdown()

    record = {"benchmark": "ray_workers_speed", "env": "point_mass", "preset": "point_mass", "batches": args.batches,
              "rows": rows, "note": args.note, "commit": git_commit(ROOT), "machine": machine()}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(record, indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
