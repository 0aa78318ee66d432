r"""Observation-only demonstrations: the in-memory container, the on-disk format and its I/O (recording lives in
:mod:`torchrl_mpail2.data.recording`).

MPAIL2 imitates from observations alone, so a demonstration is a sequence of observations
:math:`o_0, \dots, o_T` per episode. Actions and rewards are deliberately **not stored**: a learner
that could read them would no longer be learning from observation.

On-disk format (a directory)::

    PATH/
      header.json        # format name/version, env id, keys/shapes/dtypes, episode metadata,
                         # byte size + sha256 of every stored file
      observations/      # TensorDict.memmap of the flat observation TensorDict:
        observation.memmap   #   one entry per observation key, [N, *shape]
        episode.memmap       #   int64 [N], episode index of each observation
        step.memmap          #   int64 [N], time step within the episode (0..T)
        meta.json

Episodes are stored one after the other, each with its final next-observation, so an episode of
``T`` steps has ``T + 1`` observations and ``N = sum(T_i + 1)``.
"""
from __future__ import annotations

import hashlib

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import torch
from tensordict import TensorDict

from torchrl_mpail2.envs.keys import observation_keys_of

__all__ = [
    "DemoFormatError",
    "Demonstrations",
    "demos_from_arrays",
    "observation_keys_of",
]

FORMAT_NAME = "torchrl_mpail2.demos"
FORMAT_VERSION = 1
HEADER_FILE = "header.json"
OBSERVATIONS_DIR = "observations"
EPISODE_KEY = "episode"
STEP_KEY = "step"
INDEX_KEYS = (EPISODE_KEY, STEP_KEY)
NOT_STORED_NOTE = (
    "Observation-only demonstrations: actions and rewards are not stored. "
    "Per-episode task_return is kept for reporting only and must not be used for learning."
)
#: Episodes listed by name in an error about non-finite observations.
_EPISODES_SHOWN = 10
#: Floor on per-dimension standard deviations, so constant dimensions do not blow up normalisation.
MIN_STD = 1e-3


class DemoFormatError(Exception):
    """A demo directory is not in the expected format, or is truncated or corrupted."""


def _key_to_json(key) -> str | list[str]:
    return key if isinstance(key, str) else list(key)


def _key_from_json(key) -> str | tuple[str, ...]:
    return key if isinstance(key, str) else tuple(key)


def _dtype_name(dtype: torch.dtype) -> str:
    return str(dtype).removeprefix("torch.")


def _dtype_from_name(name: str) -> torch.dtype:
    dtype = getattr(torch, str(name), None)
    if not isinstance(dtype, torch.dtype):
        raise DemoFormatError(f"header.json is corrupted: unknown dtype {name!r}.")
    return dtype


def check_finite_observations(observations: TensorDict, error: type[Exception], where: str) -> None:
    """Raises ``error`` naming the first float observation key that holds NaN or Inf, and its episodes."""
    episode = observations.get(EPISODE_KEY)
    for key, tensor in observations.items(True, True):
        if key in INDEX_KEYS or not tensor.is_floating_point():
            continue
        bad = ~torch.isfinite(tensor.reshape(tensor.shape[0], -1)).all(-1)
        if bool(bad.any()):
            episodes = sorted(set(episode[bad].tolist()))
            more = f" and {len(episodes) - _EPISODES_SHOWN} more" if len(episodes) > _EPISODES_SHOWN else ""
            raise error(f"{where}: observation key {key!r} holds NaN or Inf in episode(s) "
                        f"{episodes[:_EPISODES_SHOWN]}{more} ({int(bad.sum())} observation(s)).")


@dataclass
class Demonstrations:
    """Observation-only demonstrations held in memory.

    Attributes:
        observations (TensorDict): flat ``[N]`` TensorDict with one entry per observation key
            (``[N, *shape]``) plus ``"episode"`` and ``"step"`` (int64 ``[N]``).
        header (dict): format metadata: ``env_id``, ``observation_keys`` (key, shape, dtype),
            ``num_episodes``, ``num_steps`` (transitions, ``sum T_i``), ``num_observations``
            (``sum (T_i + 1)``), ``episodes`` (per episode: ``length``, ``success``, ``task_return``,
            ``seed``, ``first_observation``). After :func:`load_demos` it also has ``files``.

    Examples:
        >>> import torch
        >>> demos = demos_from_arrays([torch.zeros(4, 2), torch.ones(3, 2)], env_id="toy")
        >>> demos.num_episodes, demos.num_steps, demos.episode(1)["observation"].shape
        (2, 5, torch.Size([3, 2]))
    """

    observations: TensorDict
    header: dict

    @property
    def env_id(self) -> str:
        return self.header["env_id"]

    def content_digest(self) -> str:
        """sha256 (hex) of the observations, every key's values in key order: a run records it so that a resume
        notices demonstrations replaced between launches."""
        digest = hashlib.sha256()
        for key in sorted(self.observations.keys(True, True), key=str):
            digest.update(str(key).encode())
            digest.update(self.observations.get(key).detach().cpu().contiguous().view(-1).view(torch.uint8).numpy())
        return digest.hexdigest()

    @property
    def observation_keys(self) -> list:
        return [_key_from_json(entry["key"]) for entry in self.header["observation_keys"]]

    @property
    def num_episodes(self) -> int:
        return int(self.header["num_episodes"])

    @property
    def num_steps(self) -> int:
        """Number of transitions ``(o, o')`` over all episodes."""
        return int(self.header["num_steps"])

    @property
    def episode_lengths(self) -> list[int]:
        """Steps ``T_i`` per episode (each episode has ``T_i + 1`` observations)."""
        return [int(meta["length"]) for meta in self.header["episodes"]]

    def episode(self, index: int) -> TensorDict:
        """The ``[T_i + 1]`` observations of episode ``index`` (negative indices count from the end)."""
        meta = self.header["episodes"][index]
        start = int(meta["first_observation"])
        return self.observations[start : start + int(meta["length"]) + 1]

    @property
    def success_rate(self) -> float:
        """Fraction of episodes successful at their last step; ``nan`` if success was not recorded."""
        episodes = self.header["episodes"]
        flags = [meta["success"] for meta in episodes if meta.get("success") is not None]
        return sum(map(bool, flags)) / len(flags) if flags else math.nan

    @property
    def mean_return(self) -> float:
        """Mean task return per episode (reporting only); ``nan`` if not recorded."""
        episodes = self.header["episodes"]
        returns = [meta["task_return"] for meta in episodes if meta.get("task_return") is not None]
        return sum(returns) / len(returns) if returns else math.nan

    def with_keys(self, keys: Sequence) -> Demonstrations:
        """The same episodes holding only the observation keys ``keys`` (e.g. the table camera's frames alone, for
        the paper's video-only demonstrations).

        Raises:
            KeyError: naming the keys the demonstrations do not hold, and the keys they do.
        """
        keys = list(keys)
        missing = [key for key in keys if key not in self.observation_keys]
        if missing or not keys:
            raise KeyError(f"demonstrations ({self.env_id}) hold no observation keys {missing or keys}; "
                           f"their keys: {self.observation_keys}")
        kept = [entry for entry in self.header["observation_keys"] if _key_from_json(entry["key"]) in keys]
        return Demonstrations(self.observations.select(*keys, *INDEX_KEYS),
                              {**{k: v for k, v in self.header.items() if k != "files"}, "observation_keys": kept})

    def observation_stats(self, keys: Sequence | None = None) -> dict:
        """Per-dimension ``(mean, std)`` over all stored observations of floating-point keys.

        What the encoder's fixed observation normalisation is set from
        (:meth:`~torchrl_mpail2.modules.MPAIL2Modules.normalize_from_demos`).

        Args:
            keys (sequence of keys, optional): keys to summarise; defaults to every floating-point
                observation key (pixel keys, stored as integers, are left out).

        Returns:
            dict mapping each key to ``(mean, std)`` tensors of the key's feature shape; ``std`` is
            floored at ``MIN_STD``.

        Raises:
            KeyError: a key is not an observation key of the demonstrations (the message lists them).
            ValueError: a key does not hold floating-point data (the message names it and its dtype).

        Examples:
            >>> demos = demos_from_arrays([torch.tensor([[0.0, 5.0], [2.0, 5.0], [4.0, 5.0]])])
            >>> mean, std = demos.observation_stats()["observation"]
            >>> mean.tolist(), round(std[1].item(), 6)  # the constant dimension's std is floored
            ([2.0, 5.0], 0.001)
        """
        if keys is None:
            keys = [key for key in self.observation_keys if self.observations.get(key).is_floating_point()]
        stats = {}
        for key in keys:
            if key not in self.observation_keys:
                raise KeyError(f"{key!r} is not an observation key of the demonstrations; keys: {self.observation_keys}")
            values = self.observations.get(key)
            if not values.is_floating_point():
                raise ValueError(f"Key {key!r} has dtype {values.dtype}; statistics need floating-point data.")
            stats[key] = (values.mean(0), values.std(0, unbiased=False).clamp_min(MIN_STD))
        return stats

    def summary(self) -> str:
        """A human-readable description of the header."""
        header, lengths = self.header, self.episode_lengths
        env_kwargs = f" {header['env_kwargs']}" if header.get("env_kwargs") else ""
        lines = [
            f"format: {header['format']} v{header['format_version']}",
            f"env: {self.env_id}{env_kwargs}",
            f"episodes: {self.num_episodes}  steps: {self.num_steps}  observations: {header['num_observations']}",
            f"episode length: min {min(lengths)}  max {max(lengths)}  mean {sum(lengths) / len(lengths):.1f}",
            f"success rate: {self.success_rate:.3f}  mean task return: {self.mean_return:.3f}",
            "observation keys:",
            *(f"  {entry['key']}: shape {entry['shape']} {entry['dtype']}" for entry in header["observation_keys"]),
            header["note"],
        ]
        return "\n".join(lines)


def assemble_demonstrations(
    episodes: Sequence[Mapping[Any, torch.Tensor]],
    metadata: Sequence[dict],
    env_id: str,
    env_kwargs: dict | None = None,
    pictures: str | None = None,
) -> Demonstrations:
    """Flattens per-episode ``{key: [T + 1, ...]}`` tensors into a :class:`Demonstrations` (``pictures``: how the
    env drew its picture observations, :func:`~torchrl_mpail2.envs.keys.pictures_of`, kept in the header)."""
    if not episodes:
        raise ValueError("At least one episode is needed.")
    keys = list(episodes[0].keys())
    for key in keys:
        if key in INDEX_KEYS:
            raise ValueError(f"Observation key {key!r} is reserved for the episode/step index.")
    reference = {key: (tuple(episodes[0][key].shape[1:]), episodes[0][key].dtype) for key in keys}
    lengths = []
    for i, episode in enumerate(episodes):
        if set(episode.keys()) != set(keys):
            raise ValueError(
                f"Episode {i} has keys {sorted(map(str, episode.keys()))}, episode 0 has {sorted(map(str, keys))}."
            )
        num_observations = {int(episode[key].shape[0]) for key in keys}
        if len(num_observations) != 1:
            raise ValueError(f"Episode {i}: keys disagree on the number of observations {sorted(num_observations)}.")
        (count,) = num_observations
        if count < 2:
            raise ValueError(f"Episode {i} has {count} observation(s); at least 2 ([T + 1], T >= 1) are needed.")
        for key in keys:
            shape, dtype = tuple(episode[key].shape[1:]), episode[key].dtype
            if (shape, dtype) != reference[key]:
                raise ValueError(
                    f"Episode {i}, key {key!r}: shape {shape} {dtype}, episode 0 has {reference[key]}."
                )
        lengths.append(count - 1)

    counts = torch.tensor(lengths) + 1
    columns = {key: torch.cat([episode[key].detach().cpu() for episode in episodes]) for key in keys}
    columns[EPISODE_KEY] = torch.repeat_interleave(torch.arange(len(episodes)), counts)
    columns[STEP_KEY] = torch.cat([torch.arange(int(count)) for count in counts])
    observations = TensorDict(columns, batch_size=[int(counts.sum())])
    check_finite_observations(observations, ValueError, "Demonstrations")

    first = torch.cumsum(counts, 0) - counts
    episode_meta = [
        {
            "length": length,
            "success": meta.get("success"),
            "task_return": meta.get("task_return"),
            "seed": meta.get("seed"),
            "first_observation": int(start),
        }
        for length, meta, start in zip(lengths, metadata, first.tolist())
    ]
    header = {
        "format": FORMAT_NAME,
        "format_version": FORMAT_VERSION,
        "note": NOT_STORED_NOTE,
        "env_id": env_id,
        "env_kwargs": dict(env_kwargs or {}),
        **({"pictures": pictures} if pictures is not None else {}),
        "observation_keys": [
            {"key": _key_to_json(key), "shape": list(shape), "dtype": _dtype_name(dtype)}
            for key, (shape, dtype) in reference.items()
        ],
        "num_episodes": len(episodes),
        "num_steps": int(sum(lengths)),
        "num_observations": int(counts.sum()),
        "episodes": episode_meta,
    }
    return Demonstrations(observations=observations, header=header)


def demos_from_arrays(
    episodes: Sequence[Mapping[str, Any]] | Sequence[Any],
    env_id: str = "custom",
    key: str = "observation",
    *,
    success: Sequence[bool] | None = None,
    task_returns: Sequence[float] | None = None,
) -> Demonstrations:
    """Builds demonstrations from your own recordings.

    Each episode of ``T`` steps is given as its ``T + 1`` observations, the last one being the
    observation after the final step: either a dict ``{key: [T + 1, *shape]}`` (several keys; all
    episodes need the same keys, shapes and dtypes) or a single array ``[T + 1, *shape]`` stored under
    ``key``. Arrays may be numpy arrays, torch tensors or nested lists; ``shape`` must have at least
    one dimension (a vector). float64 is cast to float32, the dtype of every env of the project.

    Args:
        episodes: the episodes, as described above.
        env_id (str): name of the env the observations come from (checked by nobody, but shown
            by ``info`` and useful to match demos with envs). Defaults to ``"custom"``.
        key (str): key for plain arrays. Defaults to ``"observation"``.

    Keyword Args:
        success (sequence of bool, optional): per-episode success flags, if known.
        task_returns (sequence of float, optional): per-episode task returns, if known (reporting only).

    Examples:
        >>> import numpy as np
        >>> demos = demos_from_arrays([np.zeros((51, 4)), np.zeros((31, 4))], env_id="point_mass")
        >>> demos.episode_lengths, demos.observations["observation"].dtype
        ([50, 30], torch.float32)
        >>> demos_from_arrays([{"joint_pos": np.zeros((11, 7)), "cube_pos": np.zeros((11, 3))}]).observation_keys
        ['joint_pos', 'cube_pos']
    """
    tensors = []
    for i, episode in enumerate(episodes):
        items = episode.items() if isinstance(episode, Mapping) else [(key, episode)]
        converted = {}
        for name, array in items:
            tensor = torch.as_tensor(array)
            if tensor.dtype == torch.float64:
                tensor = tensor.float()
            if tensor.ndim < 2:
                raise ValueError(
                    f"Episode {i}, key {name!r}: expected [T + 1, *shape] with a non-empty shape, "
                    f"got shape {tuple(tensor.shape)}."
                )
            converted[name] = tensor
        tensors.append(converted)
    for name, values in (("success", success), ("task_returns", task_returns)):
        if values is not None and len(values) != len(tensors):
            raise ValueError(f"{name} has {len(values)} entries for {len(tensors)} episodes.")
    metadata = [
        {
            "success": None if success is None else bool(success[i]),
            "task_return": None if task_returns is None else float(task_returns[i]),
        }
        for i in range(len(tensors))
    ]
    return assemble_demonstrations(tensors, metadata, env_id=env_id)
