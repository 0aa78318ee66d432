"""What one ``checkpoints/last`` costs when it carries the replay: seconds and bytes on disk.

    python -m benchmarks.speed.checkpoint_cost [--capacity 50000] [--filled 30000] [--obs pixels|state]

Fills a memory-mapped replay like the trainer's (``LazyMemmapStorage``, preallocated to the run's capacity) with
``--filled`` random transitions shaped like robosuite Lift's (``pixels``: one 64 x 64 RGB camera and the 26
proprioception values, for the observation and the next one; ``state``: the 36 state values), then times
``write_checkpoint`` (the copy of the replay, the sha256 manifest, the renames). The trainer writes one every
``train.last_every`` episodes (5). Writes ``docs/results/speed/<name>.json`` (``--name``, default ``checkpoint_cost``).
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import torch
from tensordict import TensorDict
from torchrl.data import LazyMemmapStorage, TensorDictReplayBuffer

from benchmarks.records import ROOT, write_record
from torchrl_mpail2.data.checkpoint import write_checkpoint

CHUNK = 1000


def transitions(n: int, obs: str) -> TensorDict:
    """``n`` random transitions shaped like robosuite Lift's in the ``obs`` mode."""
    def observation():
        if obs == "pixels":
            return {"pixels": torch.randint(0, 256, (n, 3, 64, 64), dtype=torch.uint8), "proprio": torch.randn(n, 26)}
        return {"proprio": torch.randn(n, 26), "object": torch.randn(n, 10)}
    return TensorDict({**observation(), "action": torch.randn(n, 4), "next": observation()}, [n])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--capacity", type=int, default=50_000, help="replay capacity (lift presets: 500 episodes x 100)")
    p.add_argument("--filled", type=int, default=30_000, help="transitions stored (300 episodes x 100)")
    p.add_argument("--obs", choices=("pixels", "state"), default="pixels")
    p.add_argument("--name", default="checkpoint_cost")
    p.add_argument("--note", default="", help="what else was running")
    p.add_argument("--out", type=Path, default=ROOT / "docs" / "results" / "speed")
    args = p.parse_args()
    if not 0 < args.filled <= args.capacity:
        raise SystemExit(f"--filled ({args.filled}) must be in 1..--capacity ({args.capacity})")
    with tempfile.TemporaryDirectory(dir=Path.cwd()) as scratch:
        replay = TensorDictReplayBuffer(storage=LazyMemmapStorage(args.capacity, scratch_dir=Path(scratch) / "live"))
        for start in range(0, args.filled, CHUNK):
            replay.extend(transitions(min(CHUNK, args.filled - start), args.obs))
        tick = time.perf_counter()
        folder = write_checkpoint(Path(scratch) / "last", {"counters": {"episodes": args.filled // 100}}, replay)
        seconds = time.perf_counter() - tick
        size = sum(f.stat().st_size for f in folder.rglob("*") if f.is_file())
    row = {"obs": args.obs, "capacity": args.capacity, "filled": args.filled, "seconds": seconds, "bytes": size}
    print(json.dumps(row))
    write_record(args.out, args.name, row, args.note, ROOT,
                 lambda commit: f"# One checkpoint with the replay\n\n{args.obs} observations, {args.filled} of "
                                f"{args.capacity} transitions: {seconds:.1f} s, {size / 1e9:.2f} GB on disk. Commit "
                                f"{commit}. {args.note}\n")


if __name__ == "__main__":
    main()
