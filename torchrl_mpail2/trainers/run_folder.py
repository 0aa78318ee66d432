"""A run folder held by one training at a time: an ``fcntl`` lock, and no silent reuse of a previous run's files."""
from __future__ import annotations

import fcntl
import os
import shutil
from pathlib import Path

LOCK_FILE = ".lock"
#: What a training writes into its run folder (``overwrite`` removes exactly these).
RUN_ENTRIES = ("config.json", "metrics.jsonl", "eval.jsonl", "summary.json", "curves.png", "checkpoints",
               "replay_storage", "logs", "tensorboard", "wandb")
#: How a new training treats a run folder that already holds files.
IF_EXISTS = ("refuse", "overwrite", "resume")


class RunFolderError(RuntimeError):
    """A run folder is in use by another training, or holds a previous run that was not asked to be resumed."""


class RunFolder:
    """Takes the lock of ``path`` (created if missing) for one training and checks what the folder holds.

    Args:
        path (Path): the run folder.
        if_exists (str): ``"refuse"`` a folder holding anything, ``"overwrite"`` (delete the previous run's
            :data:`RUN_ENTRIES` first) or ``"resume"`` (keep them).

    Raises:
        RunFolderError: another process (or another trainer of this one) holds the folder, or it holds files
            and ``if_exists="refuse"``.
    """

    def __init__(self, path: Path, if_exists: str = "refuse"):
        if if_exists not in IF_EXISTS:
            raise ValueError(f"if_exists must be one of {IF_EXISTS}, got {if_exists!r}")
        self.path, self.if_exists = Path(path), if_exists
        self.created = not self.path.exists()
        self.path.mkdir(parents=True, exist_ok=True)
        self._handle = None
        self.acquire()
        found = sorted(p.name for p in self.path.iterdir() if p.name != LOCK_FILE)
        if found and if_exists == "refuse":
            self.release()
            raise RunFolderError(f"run folder {self.path} already holds a run ({', '.join(found[:6])}"
                                 f"{', ...' if len(found) > 6 else ''}): resume it (--resume {self.path}), "
                                 "pick another train.run_dir, or pass --overwrite to replace it")
        if if_exists == "overwrite":
            self.remove_run_entries()

    def acquire(self) -> None:
        """Takes the folder's lock (no-op when held); refuses when another training holds it."""
        if self._handle is not None:
            return
        handle = open(self.path / LOCK_FILE, "a+")
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.seek(0)
            holder = handle.read().strip() or "unknown"
            handle.close()
            raise RunFolderError(f"run folder {self.path} is in use by another training (pid {holder}); "
                                 "wait for it to end or pick another train.run_dir") from None
        handle.seek(0)
        handle.truncate()
        handle.write(str(os.getpid()))
        handle.flush()
        self._handle = handle

    def release(self) -> None:
        if self._handle is not None:
            fcntl.flock(self._handle, fcntl.LOCK_UN)
            self._handle.close()
            self._handle = None

    def remove_run_entries(self) -> None:
        for name in RUN_ENTRIES:
            entry = self.path / name
            if entry.is_dir():
                shutil.rmtree(entry)
            elif entry.exists():
                entry.unlink()

    def discard(self) -> None:
        """After a failed start: releases the lock and removes what the training wrote (the folder, if it made it).

        A run being resumed keeps all its files.
        """
        self.release()
        if self.if_exists == "resume":
            return
        if self.created:
            shutil.rmtree(self.path, ignore_errors=True)
        else:
            self.remove_run_entries()
            (self.path / LOCK_FILE).unlink(missing_ok=True)
