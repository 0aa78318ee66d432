"""Checkpoint folders: written under a temporary name with a checksum manifest, then renamed into place.

A checkpoint folder holds ``state.pt``, optionally the replay buffer's stored steps under ``replay/``, and
``manifest.json`` (written last: the episode count and the size and sha256 of every other file, see
:mod:`torchrl_mpail2.data.checksums`). A folder whose files do not match its manifest is refused with a
message naming the file; :func:`find_resumable` picks the newest complete checkpoint of a run.
"""
from __future__ import annotations

import errno
import json
import os
import random
import shutil
import warnings
from pathlib import Path

import numpy as np
import torch
from tensordict import TensorDict

from torchrl_mpail2.data.checksums import folder_manifest, verify_manifest

STATE_FILE = "state.pt"
REPLAY_DIR = "replay"
#: Steps copied at a time when a stored replay is appended to a buffer (bounds the memory a camera run's takes).
LOAD_CHUNK_STEPS = 16384
MANIFEST_FILE = "manifest.json"
#: Config fields that shape the saved networks: a checkpoint loads only into a run that agrees on them.
NETWORK_FIELDS = ("train.env", "train.obs", "train.ablation", "model.*")


class CheckpointError(RuntimeError):
    """A checkpoint is missing, incomplete, corrupted, or does not fit the run that loads it."""


def rng_state() -> dict:
    """Python, numpy and torch RNG states."""
    return {"python": random.getstate(), "numpy": np.random.get_state(), "torch": torch.get_rng_state()}


def set_rng_state(state: dict) -> None:
    random.setstate(state["python"])
    np.random.set_state(state["numpy"])
    torch.set_rng_state(state["torch"])


def write_checkpoint(path: Path, state: dict, replay_buffer=None) -> Path:
    """Writes ``state`` (and the replay buffer, if given) to the folder ``path``, then its manifest.

    The folder is written as ``.NAME.tmp`` and renamed into place; the previous one is moved to ``.NAME.old``
    meanwhile. A crash at any point leaves a complete checkpoint under one of the three names, which
    :func:`find_resumable` finds.

    Raises:
        CheckpointError: the write failed (a full disk, most often): the message names the folder and its free
            space; the partial ``.NAME.tmp`` is removed and the previous checkpoint kept.
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    old = path.with_name(f".{path.name}.old")
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        tmp.mkdir(parents=True)
        torch.save(state, tmp / STATE_FILE)
        if replay_buffer is not None and len(replay_buffer):  # an empty buffer (before the first episode) has no rows
            dump_replay(replay_buffer, tmp / REPLAY_DIR)
        manifest = {"episodes": state.get("counters", {}).get("episodes"), "files": folder_manifest(tmp)}
        (tmp / MANIFEST_FILE).write_text(json.dumps(manifest, indent=1))
    except (OSError, RuntimeError) as error:  # torch.save reports a full disk as a RuntimeError
        shutil.rmtree(tmp, ignore_errors=True)
        raise CheckpointError(_write_failure(path, error)) from error
    shutil.rmtree(old, ignore_errors=True)
    if path.exists():
        os.replace(path, old)
    os.replace(tmp, path)
    shutil.rmtree(old, ignore_errors=True)
    return path


def _write_failure(path: Path, error: BaseException) -> str:
    """Why writing the checkpoint ``path`` failed, with the free space of its device (a full disk is the usual cause)."""
    try:
        free = f"{shutil.disk_usage(path.parent).free / 2**20:.1f} MiB free"
    except OSError:
        free = "free space unknown"
    full = getattr(error, "errno", None) == errno.ENOSPC or "unexpected pos" in str(error) or "write failed" in str(error)
    cause = "the disk is full" if full else "writing failed"
    kept = "the previous checkpoint is kept" if path.exists() else "no earlier checkpoint of this name exists"
    return (f"cannot write checkpoint {path}: {cause} ({type(error).__name__}: {error}; {path.parent} has {free}); "
            f"the partial checkpoint was removed and {kept}")


def read_manifest(path: Path) -> dict | None:
    """The manifest of a checkpoint folder; None for a folder written before checkpoints had one."""
    file = Path(path) / MANIFEST_FILE
    if not file.exists():
        return None
    try:
        manifest = json.loads(file.read_text())
        manifest["files"]
    except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError) as error:
        raise CheckpointError(f"{file} is truncated or corrupted ({type(error).__name__}: {error})") from error
    return manifest


def _verify(path: Path, prefix: str) -> None:
    """Checks the files of ``path`` whose relative name starts with ``prefix`` against the manifest."""
    manifest = read_manifest(path)
    if manifest is None:
        if not (path / STATE_FILE).exists():
            raise CheckpointError(f"no checkpoint at {path} (expected {path / STATE_FILE})")
        warnings.warn(f"{path} has no {MANIFEST_FILE} (written before checkpoints had checksums): not verified",
                      RuntimeWarning, stacklevel=3)
        return
    files = {name: entry for name, entry in manifest["files"].items() if name.startswith(prefix)}
    if not files:
        raise CheckpointError(f"{path / prefix} is not listed in {path / MANIFEST_FILE}")
    verify_manifest(path, files, CheckpointError)


def read_checkpoint(path: Path) -> dict:
    """Loads ``state.pt`` from a checkpoint folder (or a ``.pt`` file) after checking it against the manifest
    (a file inside a checkpoint folder is checked against the folder's manifest too).

    Raises:
        CheckpointError: the checkpoint is missing, truncated or corrupted (the message names the file).
    """
    path = Path(path)
    if path.is_dir():
        _verify(path, STATE_FILE)
        file = path / STATE_FILE
    else:
        file = path
        if not file.exists():
            raise CheckpointError(f"no checkpoint at {path} (expected a folder with {STATE_FILE} or a .pt file)")
        if (file.parent / MANIFEST_FILE).exists():  # a file of a checkpoint folder: checked as the folder is
            _verify(file.parent, file.name)
    try:
        return torch.load(file, map_location="cpu", weights_only=False)
    except Exception as error:  # torch.load raises EOFError, RuntimeError, UnpicklingError... on damaged files
        raise CheckpointError(f"{file} cannot be read, it is truncated or corrupted ({type(error).__name__}: {error})") from error


def has_replay(path: Path) -> bool:
    return (Path(path) / REPLAY_DIR).exists()


def dump_replay(replay_buffer, folder: Path) -> None:
    """Writes the steps ``replay_buffer`` holds to ``folder``, for :func:`load_replay`.

    The live storage (``LazyMemmapStorage``) is a memory-mapped file per key of the whole capacity, sparse on disk
    until written: 9.6 GB apparent but 19 MB on disk for a 100,000-step camera buffer holding 200 steps. TorchRL's
    ``dumps`` copies the whole capacity, holes included (9.6 GB written in 59 s, then hashed). A buffer that has not
    wrapped around holds its steps in order from row 0, and its writer's cursor is their count: those rows alone are
    written, in TorchRL's storage layout, and :func:`load_replay` appends them in order. A full buffer is dumped
    whole by ``dumps`` (its writer's cursor with it). An empty one cannot be written (:func:`write_checkpoint`
    leaves its replay out).
    """
    storage = replay_buffer._storage
    length = len(storage)
    if length == storage.max_size:
        replay_buffer.dumps(folder)
        return
    stored_dir = Path(folder) / "storage"
    storage._storage[:length].memmap(stored_dir, copy_existing=True)
    (stored_dir / "storage_metadata.json").write_text(json.dumps({"metadata": {}, "is_pytree": False, "len": length}))


def load_replay(replay_buffer, path: Path) -> None:
    """Restores the replay buffer stored in a checkpoint folder, after checking its files against the manifest.

    A buffer dumped whole with this capacity is restored by TorchRL's ``loads`` (writer and sampler state
    exactly); one written as its stored steps alone (:func:`dump_replay`), or with another capacity (a resumed run
    whose episode budget grew), is appended in order into ``replay_buffer``.
    """
    path = Path(path)
    _verify(path, REPLAY_DIR)
    stored_dir = path / REPLAY_DIR / "storage"
    stored = TensorDict.load_memmap(stored_dir)
    capacity = replay_buffer._storage.max_size
    if stored.batch_size[0] == capacity and (path / REPLAY_DIR / "writer").exists():
        replay_buffer.loads(path / REPLAY_DIR)
        return
    length = json.loads((stored_dir / "storage_metadata.json").read_text())["len"]
    if length > capacity:
        raise CheckpointError(f"{stored_dir} holds {length} transitions, more than this run's replay capacity "
                              f"{capacity} (train.replay_size)")
    replay_buffer.empty()
    for start in range(0, length, LOAD_CHUNK_STEPS):
        replay_buffer.extend(stored[start:min(start + LOAD_CHUNK_STEPS, length)].to_tensordict())


def checkpoint_episodes(path: Path) -> int:
    """Episodes done when the (verified) checkpoint folder ``path`` was written."""
    manifest = read_manifest(path)
    if manifest is not None and manifest.get("episodes") is not None:
        return int(manifest["episodes"])
    return int(read_checkpoint(path)["counters"]["episodes"])


def numbered_checkpoints(run_dir: Path) -> list[tuple[int, Path]]:
    """A run's ``checkpoints/episode_N`` folders (the trainer's ``train.checkpoint_every``), as ``(N, folder)`` by
    episode; temporary ``.episode_N.tmp`` ones excluded."""
    return sorted((int(path.name.removeprefix("episode_")), path)
                  for path in (Path(run_dir) / "checkpoints").glob("episode_*") if path.is_dir())


def find_resumable(checkpoints: Path, replay: bool = True) -> Path | None:
    """The newest complete checkpoint under ``checkpoints`` (``last``, numbered ones, or ones a crash left mid-rename).

    Every candidate is checked against its manifest; those holding the replay buffer are preferred (a resume
    without it would start from an empty buffer), then the most episodes, then ``last``. Falling back to
    another folder than ``last`` warns with the reason, and so does one without a replay buffer unless
    ``replay=False`` (a run that keeps none, e.g. an on-policy one).

    Returns:
        The folder, or None when there is no checkpoint at all.

    Raises:
        CheckpointError: checkpoints exist but none is complete (the message names each and why).
    """
    checkpoints = Path(checkpoints)
    folders = sorted(p for p in checkpoints.iterdir() if p.is_dir()) if checkpoints.is_dir() else []
    if not folders:
        return None
    complete, problems = [], []
    for folder in folders:
        try:
            if folder.name.startswith(".") and read_manifest(folder) is None:
                raise CheckpointError(f"{folder} is incomplete (no {MANIFEST_FILE}: the write was interrupted)")
            _verify(folder, "")
            complete.append((has_replay(folder), checkpoint_episodes(folder), folder.name == "last", folder))
        except CheckpointError as error:
            problems.append(str(error))
    if not complete:
        raise CheckpointError(f"no complete checkpoint under {checkpoints}:\n  " + "\n  ".join(problems))
    with_replay, episodes, _, chosen = max(complete, key=lambda c: c[:3])
    if chosen.name != "last" or problems:
        reasons = "; ".join(problems) or f"{checkpoints / 'last'} is missing"
        warnings.warn(f"resuming from {chosen} (episode {episodes}): {reasons}", RuntimeWarning, stacklevel=2)
    if replay and not with_replay:
        warnings.warn(f"{chosen} holds no replay buffer: the resumed run starts with an empty one", RuntimeWarning,
                      stacklevel=2)
    return chosen


def _flatten(config: dict) -> dict[str, object]:
    return {f"{section}.{name}": json.loads(json.dumps(value)) for section, values in config.items()
            for name, value in values.items()}


def check_compatible(saved: dict, current: dict, source: Path, ignore: tuple[str, ...] = ()) -> None:
    """Raises :class:`CheckpointError` naming every :data:`NETWORK_FIELDS` field (but those in ``ignore``) where
    ``saved`` and ``current`` differ."""
    saved, current = _flatten(saved), _flatten(current)

    def shapes_networks(name: str) -> bool:
        return name not in ignore and any(name == f or (f.endswith(".*") and name.startswith(f[:-1]))
                                          for f in NETWORK_FIELDS)

    differ = [f"{name}: {saved.get(name)!r} in the checkpoint, {current.get(name)!r} now"
              for name in sorted(set(saved) | set(current)) if shapes_networks(name) and saved.get(name) != current.get(name)]
    if differ:
        raise CheckpointError(f"{source} was written for other networks than this run's config:\n  " + "\n  ".join(differ))
