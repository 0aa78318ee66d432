"""What every benchmark shares, torch-free so that a parent process that only starts and waits for children stays
small: the checkout's root, a child process's environment, the commit, and writing a record (``<name>.json`` with
the commit, the machine and a note, and ``<name>.md``)."""
from __future__ import annotations

import json
import os
import platform
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
"""The checkout these benchmarks belong to (children run there, results default under its ``docs/results``)."""


def child_env(threads: int | None = None, root: Path = ROOT) -> dict:
    """``os.environ`` for a benchmark's child process: the checkout ``root`` first on ``PYTHONPATH`` (once: a caller
    that already put it there is not repeated), then whatever the caller's ``PYTHONPATH`` held (packages installed
    outside the environment, as on a borrowed GPU machine), and ``OMP_NUM_THREADS`` where ``threads`` is given."""
    caller = [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p and p != str(root)]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(root), *caller])}
    if threads is not None:
        env["OMP_NUM_THREADS"] = str(threads)
    return env


def start_logged(cmd: list[str], log_path: Path, cwd: Path, env: dict) -> tuple[subprocess.Popen, object]:
    """``cmd`` started in ``cwd`` with its output appended to ``log_path``; returns the process and the open log (the
    caller closes it when the process ends; it is closed here if the process cannot start)."""
    log = open(log_path, "a")
    try:
        return subprocess.Popen(cmd, cwd=cwd, env=env, stdout=log, stderr=subprocess.STDOUT), log
    except BaseException:
        log.close()
        raise


def git_commit(where: Path, short: bool = True) -> str | None:
    """Hash of the commit checked out at ``where`` (a worktree may differ from this script's); None outside git."""
    try:
        return subprocess.run(["git", "rev-parse", *(["--short"] if short else []), "HEAD"], cwd=where,
                              capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None


def write_record(out: Path, name: str, fields: dict, note: str, root: Path, markdown) -> dict:
    """Writes ``out/name.json`` (``fields`` with ``commit``, ``note`` and ``machine`` added) and ``out/name.md``
    (``markdown(commit)``, ending with a link to the JSON); returns the record."""
    commit = git_commit(root)
    record = {**fields, "commit": commit, "note": note, "machine": {"cpu": platform.processor() or platform.machine()}}
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{name}.json").write_text(json.dumps(record, indent=2))
    (out / f"{name}.md").write_text(markdown(commit).rstrip("\n") + f"\n\nData: [{name}.json]({name}.json)\n")
    return record
