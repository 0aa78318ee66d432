"""Writing a benchmark's record: ``<name>.json`` (with the commit, the machine and a note) and ``<name>.md``.
Torch-free, so that a parent process that only starts and waits for children stays small."""
from __future__ import annotations

import json
import platform
import subprocess
from pathlib import Path


def git_commit(root: Path) -> str:
    """Short hash of the checkout's HEAD (empty outside a git checkout)."""
    return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=root).stdout.strip()


def write_record(out: Path, name: str, fields: dict, note: str, root: Path, markdown) -> dict:
    """Writes ``out/name.json`` (``fields`` with ``commit``, ``note`` and ``machine`` added) and ``out/name.md``
    (``markdown(commit)``); returns the record."""
    commit = git_commit(root)
    record = {**fields, "commit": commit, "note": note, "machine": {"cpu": platform.processor() or platform.machine()}}
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{name}.json").write_text(json.dumps(record, indent=2))
    (out / f"{name}.md").write_text(markdown(commit))
    return record
