"""A queue of learning benchmarks that keeps a number of cores busy: each job is a ``learning_seeds`` command run
from its own checkout (a worktree at a fixed commit), started as soon as enough cores are free.

    python -m benchmarks.learning.campaign QUEUE.json [--slots 2] [--dry-run]

``QUEUE.json``::

    {"jobs": [
      {"checkout": "/scratch/exp67", "slots": 1,
       "args": "push_video_only_glfix_s0 --preset push_video_only --seeds 0 --episodes 200 --parallel 1"},
      {"checkout": "/scratch/exp68", "slots": 2,
       "args": "lift_pixels_glfix --preset lift_pixels --seeds 0 1 --episodes 300 --parallel 2"}
    ]}

A job takes ``slots`` cores (default 1; give ``--parallel``'s value), runs ``python -m
benchmarks.learning.learning_seeds ARGS`` in ``checkout`` (default: this checkout; a relative path is read from the
queue file's folder) with one torch thread per process, and appends its output to
``CHECKOUT/runs/learning/campaign_<first argument>.log``. Jobs start in the file's order; a job that does not fit the
free cores lets a later one that does start first, so no core waits while one fits. Running the same queue again
resumes it: a finished ``learning_seeds`` job ends at once (its held-out scores reused), an interrupted one resumes
from its newest checkpoint. ``--dry-run`` prints the commands and starts nothing.
"""
from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from benchmarks.records import ROOT, child_env, start_logged

JOB_FIELDS = {"checkout", "args", "slots"}


@dataclass
class Job:
    """One ``learning_seeds`` command: its arguments, the checkout it runs from and the cores it takes."""
    args: list[str]
    checkout: Path
    slots: int = 1

    @property
    def name(self) -> str:
        return self.args[0]

    @property
    def log(self) -> Path:
        return self.checkout / "runs" / "learning" / f"campaign_{self.name}.log"

    def command(self) -> list[str]:
        return [sys.executable, "-m", "benchmarks.learning.learning_seeds", *self.args]

    def env(self) -> dict:
        """The caller's environment with the job's checkout first on ``PYTHONPATH`` and one torch thread."""
        return child_env(threads=1, root=self.checkout)


def read_queue(path: Path, slots: int) -> list[Job]:
    """The jobs of ``path``, checked: every mistake is refused naming the job (by its place) and the field."""
    try:
        data = json.loads(path.read_text())
    except OSError as error:
        raise SystemExit(f"campaign: cannot read the queue {path}: {error}") from None
    except json.JSONDecodeError as error:
        raise SystemExit(f"campaign: {path} is not valid JSON ({error})") from None
    if not isinstance(data, dict) or not isinstance(data.get("jobs"), list) or not data["jobs"]:
        raise SystemExit(f"campaign: {path} must hold {{\"jobs\": [...]}} with at least one job")
    jobs = []
    for place, entry in enumerate(data["jobs"]):
        where = f"{path}: jobs[{place}]"
        if not isinstance(entry, dict):
            raise SystemExit(f"campaign: {where} must be an object with 'args' (and 'checkout', 'slots')")
        unknown = set(entry) - JOB_FIELDS
        if unknown:
            raise SystemExit(f"campaign: {where} has unknown field(s) {sorted(unknown)}; known: {sorted(JOB_FIELDS)}")
        args = entry.get("args")
        args = shlex.split(args) if isinstance(args, str) else args
        if not isinstance(args, list) or not args or not all(isinstance(a, str) for a in args):
            raise SystemExit(f"campaign: {where}.args must be the learning_seeds arguments, NAME first")
        if args[0].startswith("-"):
            raise SystemExit(f"campaign: {where}.args must begin with the run's NAME, not {args[0]!r}")
        if not isinstance(entry.get("checkout", ""), str):
            raise SystemExit(f"campaign: {where}.checkout must be a folder's path, not {entry['checkout']!r}")
        checkout = Path(entry.get("checkout", ROOT))
        checkout = checkout if checkout.is_absolute() else (path.parent / checkout).resolve()
        if not (checkout / "benchmarks" / "learning" / "learning_seeds.py").exists():
            raise SystemExit(f"campaign: {where}.checkout {checkout} holds no benchmarks/learning/learning_seeds.py")
        cores = entry.get("slots", 1)
        if not isinstance(cores, int) or isinstance(cores, bool) or not 1 <= cores <= slots:
            raise SystemExit(f"campaign: {where}.slots={cores!r}: expected an integer from 1 to --slots ({slots})")
        jobs.append(Job(args, checkout, cores))
    names = [j.name for j in jobs]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise SystemExit(f"campaign: {path} names {repeated} twice: each job needs its own NAME (its run folder, log "
                         "and exit code go by it)")
    return jobs


def run_campaign(jobs: list[Job], slots: int, poll_s: float = 10.0) -> dict[str, int]:
    """Runs ``jobs`` keeping up to ``slots`` cores busy (see the module docstring); returns each job's exit code."""
    pending, running, codes = list(jobs), [], {}
    while pending or running:
        free = slots - sum(job.slots for job, _, _ in running)
        for job in list(pending):
            if job.slots <= free:
                pending.remove(job)
                job.log.parent.mkdir(parents=True, exist_ok=True)
                running.append((job, *start_logged(job.command(), job.log, job.checkout, job.env())))
                free -= job.slots
                print(f"{time.strftime('%H:%M:%S')} started {job.name} ({job.slots} core(s), {job.checkout}); "
                      f"log {job.log}", flush=True)
        time.sleep(poll_s)
        for entry in list(running):
            job, proc, log = entry
            if proc.poll() is not None:
                running.remove(entry)
                log.close()
                codes[job.name] = proc.returncode
                print(f"{time.strftime('%H:%M:%S')} {job.name} exited with {proc.returncode}", flush=True)
    return codes


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("queue", type=Path)
    p.add_argument("--slots", type=int, default=2, help="cores to keep busy (default 2)")
    p.add_argument("--dry-run", action="store_true", help="print the commands and start nothing")
    args = p.parse_args(argv)
    if args.slots < 1:
        p.error(f"--slots={args.slots}: expected at least 1")
    jobs = read_queue(args.queue, args.slots)
    if args.dry_run:
        for job in jobs:
            print(f"[{job.slots} core(s)] cd {job.checkout} && {shlex.join(job.command())}")
        return
    codes = run_campaign(jobs, args.slots)
    failed = {name: code for name, code in codes.items() if code != 0}
    if failed:
        raise SystemExit(f"campaign: {len(failed)} job(s) failed: {failed} (their logs say why)")


if __name__ == "__main__":
    main()
