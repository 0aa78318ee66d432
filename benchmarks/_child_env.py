"""The environment of a benchmark's child process (torch-free, so that a parent that only launches and waits
does not hold torch in memory for hours)."""
from __future__ import annotations

import os

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def child_env(threads: int | None = None) -> dict:
    """``os.environ`` for a benchmark's child process: this checkout first on ``PYTHONPATH``, then whatever the
    caller's ``PYTHONPATH`` held (packages installed outside the environment, as on a borrowed GPU machine), and
    ``OMP_NUM_THREADS`` where ``threads`` is given."""
    path = os.pathsep.join(p for p in (ROOT, os.environ.get("PYTHONPATH", "")) if p)
    env = {**os.environ, "PYTHONPATH": path}
    if threads is not None:
        env["OMP_NUM_THREADS"] = str(threads)
    return env
