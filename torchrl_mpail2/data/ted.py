r"""Observation-only demonstrations from TorchRL's TED format (the layout of its collectors, replay buffers and
``torchrl.data.datasets``: ``LeRobotExperienceReplay``, ``MinariExperienceReplay``, ``OpenXExperienceReplay``, ...).

A TED batch holds transitions: observations at the root, the next ones under ``"next"``, and ``"action"``,
``("next", "reward")`` and done flags beside them. Episodes are told apart by an episode-id key (``"episode"`` in
the datasets, ``("collector", "traj_ids")`` in collector output) or, without one, by ``("next", "done")``. Each
episode of ``T`` transitions becomes its ``T + 1`` observations; actions and rewards are dropped. Where the data
holds ``("next", "success")``, each episode's success after its last transition is kept in the header.
"""
from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.utils import NestedKey
from torchrl.data import find_start_stop_traj

from torchrl_mpail2.data.demos import EPISODE_KEY, Demonstrations, check_finite_observations, demos_from_arrays
from torchrl_mpail2.envs.keys import observation_keys_of

__all__ = ["EPISODE_ID_KEYS", "SUCCESS_KEY", "demos_from_ted", "import_ted"]

#: Episode-id keys looked for, in order: TorchRL's datasets, its collectors, ``TrajCounter``'s default.
EPISODE_ID_KEYS: tuple[NestedKey, ...] = ("episode", ("collector", "traj_ids"), "traj_count")
#: The success flag after each transition, as this library's envs write it.
SUCCESS_KEY: NestedKey = ("next", "success")


def _episode_slices(data: TensorDictBase, episode_key: NestedKey | None) -> list[slice]:
    """Consecutive runs of one episode id (or up to each ``("next", "done")``) as slices of the flat batch.

    TorchRL's ``split_trajectories`` does not fit here: it pads every key into an ``[episodes, longest]`` copy (all
    of a memory-mapped dataset's cameras in memory at once), and it sizes each episode by counting every transition
    carrying its id, so an id that comes back later (two collector outputs saved one after the other) fails. The
    boundaries are those of ``find_start_stop_traj``, the routine behind TorchRL's ``SliceSampler``: a new episode
    wherever the id changes, or after each done flag, and the last transition always ends one.
    """
    n = data.shape[0]
    if episode_key is not None:
        boundaries = {"trajectory": data.get(episode_key).reshape(n)}
    else:
        done = data.get(("next", "done"), None)
        if done is None:
            return [slice(0, n)]
        boundaries = {"end": done.reshape(n).bool()}
    start, stop, _ = find_start_stop_traj(**boundaries, at_capacity=False)
    return [slice(a, b + 1) for a, b in zip(start[:, 0].tolist(), stop[:, 0].tolist())]


def _observations_by_episode(data: TensorDictBase, observation_keys: Sequence[str],
                             slices: list[slice]) -> TensorDict:
    """The observation keys (at the root and under ``"next"``) with the episode index of each transition, in the
    layout :func:`~torchrl_mpail2.data.demos.check_finite_observations` reads."""
    episode = torch.cat([torch.full((part.stop - part.start,), i) for i, part in enumerate(slices)])
    columns = {full: data.get(full) for key in observation_keys for full in (key, ("next", key))}
    return TensorDict({**columns, EPISODE_KEY: episode}, batch_size=data.batch_size)


def demos_from_ted(data: TensorDictBase, observation_keys: Sequence[str], *, env_id: str = "custom",
                   episode_key: NestedKey | None = None, source: str | None = None) -> Demonstrations:
    """Groups a TED batch by episode into observation-only demonstrations, with each episode's success after its
    last transition where the batch holds :data:`SUCCESS_KEY`.

    Args:
        data (TensorDictBase): transitions ``[N]`` (or ``[B, T]``, flattened row by row as collectors lay them out)
            with each key of ``observation_keys`` at the root and under ``"next"``.
        observation_keys (sequence of str): the observation keys to keep (e.g. the env's).

    Keyword Args:
        env_id (str): recorded in the demos. Defaults to ``"custom"``.
        episode_key (NestedKey, optional): the episode-id key; by default the first of :data:`EPISODE_ID_KEYS`
            present, else episodes end at ``("next", "done")``.
        source (str, optional): what the header's ``source`` names (a path or a dataset id).

    Raises:
        KeyError: an observation key missing at the root or under ``"next"``, or a missing ``episode_key``.
        ValueError: no transitions; NaN or Inf in an observation (the key and the episodes are named); an episode
            whose transitions do not follow one another (``next`` of step t differs from the observation of step
            t + 1: out of time order, or episodes interleaved without an id key).

    Examples:
        >>> obs = torch.arange(12.0).reshape(6, 2)
        >>> td = TensorDict({"observation": obs[:-1], ("next", "observation"): obs[1:],
        ...                  "episode": torch.tensor([0, 0, 0, 1, 1])}, [5])
        >>> td["observation"][3], td["next", "observation"][3] = obs[4], obs[5]  # episode 1 starts afresh
        >>> demos_from_ted(td, ["observation"]).episode_lengths
        [3, 2]
    """
    where = f"TED data {source}" if source else "TED data"
    if data.batch_dims == 0:
        raise ValueError(f"{where}: a TED batch needs at least one batch dimension (transitions)")
    if math.prod(data.batch_size) == 0:  # (TensorDict.numel() is 1 for an empty batch)
        raise ValueError(f"{where} holds no transitions")
    data = data.reshape(-1)
    for key in observation_keys:
        for full in (key, ("next", key)):
            if data.get(full, None) is None:
                raise KeyError(f"TED data has no {full!r}; present: {sorted(map(str, data.keys(True, True)))}")
    if episode_key is None:
        episode_key = next((k for k in EPISODE_ID_KEYS if data.get(k, None) is not None), None)
    elif data.get(episode_key, None) is None:
        raise KeyError(f"TED data has no episode key {episode_key!r}")
    slices = _episode_slices(data, episode_key)
    # before the order check, which NaN (unequal to itself) would fail with a misleading message
    check_finite_observations(_observations_by_episode(data, observation_keys, slices), ValueError, where)
    episodes = []
    for i, part in enumerate(slices):
        ep = data[part]
        for key in observation_keys:
            if not torch.equal(ep.get(("next", key))[:-1], ep.get(key)[1:]):
                raise ValueError(f"episode {i} ({part.start}..{part.stop - 1}) of the {where}: ('next', {key!r}) of a "
                                 "step differs from the next step's observation (transitions out of order, or "
                                 "episodes interleaved without an episode-id key)")
        episodes.append({key: torch.cat([ep.get(key), ep.get(("next", key))[-1:]]) for key in observation_keys})
    success = data.get(SUCCESS_KEY, None)
    # success at the episode's last observation, as recorded demos and the robomimic importer keep it
    flags = None if success is None else [bool(success[part.stop - 1].any()) for part in slices]
    demos = demos_from_arrays(episodes, env_id=env_id, success=flags)
    demos.header["source"] = {"format": "ted", "from": source, "episode_key": None if episode_key is None else
                              str(episode_key), "dropped": ["actions", "rewards"]}
    return demos


def _check_memmap_sizes(folder: Path) -> None:
    """Refuses a ``<key>.memmap`` file whose size differs from the shape and dtype its folder's ``meta.json``
    records, naming the file and both sizes: a memory-mapped file cut short would otherwise read as zeros."""
    for meta_file in sorted(folder.rglob("meta.json")):
        meta = json.loads(meta_file.read_text())
        for key, entry in meta.items():
            if not isinstance(entry, dict) or "shape" not in entry or "dtype" not in entry or entry.get("is_nested"):
                continue  # the tensordict's own shape, a sub-tensordict, or a nested tensor (no fixed size)
            dtype = getattr(torch, str(entry["dtype"]).removeprefix("torch."), None)
            if not isinstance(dtype, torch.dtype):
                continue
            expected = math.prod(entry["shape"]) * dtype.itemsize
            file = meta_file.parent / f"{key}.memmap"
            size = file.stat().st_size if file.is_file() else 0
            if size != expected:
                found = f"{size} bytes on disk" if file.is_file() else "missing"
                raise ValueError(f"{file} is truncated or corrupted: {found}, {expected} expected from its shape "
                                 f"{entry['shape']} and dtype {entry['dtype']} in {meta_file}")


def import_ted(path: str | Path, env, *, progress: bool = False) -> Demonstrations:
    """Demonstrations from a TED tensordict saved with ``td.memmap(path)`` (``train.demos=ted:PATH``), keeping the
    observation keys of ``env``.

    Raises:
        FileNotFoundError: ``path`` holds no memory-mapped tensordict.
        ValueError: a memmap file's size differs from its recorded shape and dtype (the file and both sizes are
            named), or the data is refused by :func:`demos_from_ted`.
    """
    path = Path(path)
    if not (path / "meta.json").is_file():
        raise FileNotFoundError(f"{path}: not a memory-mapped tensordict (no meta.json); save one with td.memmap(path)")
    _check_memmap_sizes(path)
    data = TensorDict.load_memmap(path)
    return demos_from_ted(data, observation_keys_of(env), source=str(path.resolve()))
