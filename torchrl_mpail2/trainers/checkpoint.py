"""Atomic checkpoint folders: written under a temporary name, then renamed into place."""
from __future__ import annotations

import os
import random
import shutil
from pathlib import Path

import numpy as np
import torch

STATE_FILE = "state.pt"
REPLAY_DIR = "replay"


def rng_state() -> dict:
    """Python, numpy and torch RNG states."""
    return {"python": random.getstate(), "numpy": np.random.get_state(), "torch": torch.get_rng_state()}


def set_rng_state(state: dict) -> None:
    random.setstate(state["python"])
    np.random.set_state(state["numpy"])
    torch.set_rng_state(state["torch"])


def write_checkpoint(path: Path, state: dict, replay_buffer=None) -> Path:
    """Writes ``state`` (and the replay buffer, if given) to the folder ``path`` atomically.

    A crash at any point leaves either the previous checkpoint or the new one, never a mix.
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    old = path.with_name(f".{path.name}.old")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    torch.save(state, tmp / STATE_FILE)
    if replay_buffer is not None:
        replay_buffer.dumps(tmp / REPLAY_DIR)
    shutil.rmtree(old, ignore_errors=True)
    if path.exists():
        os.replace(path, old)
    os.replace(tmp, path)
    shutil.rmtree(old, ignore_errors=True)
    return path


def read_checkpoint(path: Path) -> dict:
    """Loads ``state.pt`` from a checkpoint folder (or a ``.pt`` file), with a clear error if absent."""
    path = Path(path)
    file = path / STATE_FILE if path.is_dir() else path
    if not file.exists():
        raise FileNotFoundError(f"no checkpoint at {path} (expected {file})")
    return torch.load(file, map_location="cpu", weights_only=False)


def has_replay(path: Path) -> bool:
    return (Path(path) / REPLAY_DIR).exists()
