"""The run's replay buffer :math:`\mathcal{B}` of Algorithm 1: TorchRL's ``TensorDictReplayBuffer`` over a memory-mapped
storage, sampled in ``[B, H]`` windows that never cross an episode, each batch carrying expert windows."""
from __future__ import annotations

import shutil
from pathlib import Path

import torch
from tensordict import TensorDictBase
from torchrl.data import LazyMemmapStorage, TensorDictReplayBuffer
from torchrl.data.replay_buffers import SliceSampler

from torchrl_mpail2.data import TRAJ_KEY, AttachExpertWindows, DemoBuffer

__all__ = ["make_replay", "store_episodes"]


def make_replay(capacity: int, batch_size: int, horizon: int, demo_buffer: DemoBuffer,
                scratch: Path | None = None) -> TensorDictReplayBuffer:
    """A buffer of ``capacity`` transitions whose ``sample()`` returns ``batch_size * horizon`` rows, ``batch_size``
    windows of ``horizon`` consecutive steps of one episode, with expert windows from ``demo_buffer`` attached under
    ``"expert"``.

    ``scratch`` is the folder of the live memory-mapped storage (emptied first: it is a working copy, what survives
    a crash is the copy a checkpoint holds); None keeps it in memory.
    """
    if scratch is not None:
        shutil.rmtree(scratch, ignore_errors=True)
    sampler = SliceSampler(slice_len=horizon, traj_key=TRAJ_KEY, strict_length=True)
    replay = TensorDictReplayBuffer(storage=LazyMemmapStorage(capacity, scratch_dir=scratch), sampler=sampler,
                                    batch_size=batch_size * horizon)
    replay.append_transform(AttachExpertWindows(demo_buffer, horizon))
    return replay


def store_episodes(episodes: list[TensorDictBase], first: int, replay: TensorDictReplayBuffer,
                   latest: TensorDictBase | None = None) -> None:
    """Extends ``replay`` with ``episodes``, one after another; ``latest`` (the [-O] ablation's buffer) keeps this
    batch's alone.

    Each episode's trajectory id becomes its run-wide index (``first + i``, ``first`` the episodes done before the
    batch): a collector counts its episodes from 0, again when it is rebuilt after an env error or a resume and in
    each Ray worker, and two neighbouring episodes under one id would be sampled as one trajectory.
    """
    episodes = [episode.set(TRAJ_KEY, torch.full_like(episode.get(TRAJ_KEY), first + i))
                for i, episode in enumerate(episodes)]
    for episode in episodes:
        replay.extend(episode)
    if latest is not None:
        latest.empty()
        for episode in episodes:
            latest.extend(episode)
