"""Writing a benchmark's record: ``<name>.json`` (with the commit, the machine and a note) and ``<name>.md``.
Torch-free, so that a parent process that only starts and waits for children stays small."""
from __future__ import annotations

import json
import platform
import subprocess
from pathlib import Path


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
