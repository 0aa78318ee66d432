"""Saving and loading demonstrations in the on-disk format (described in :mod:`torchrl_mpail2.data.demos`), with
checksums, content checks and an optional check against an environment's observation spec."""
from __future__ import annotations

import json
import os
import shutil
import uuid
from collections.abc import Sequence
from pathlib import Path

import torch
from tensordict import TensorDict
from torchrl.data import Composite
from torchrl.envs import EnvBase

from torchrl_mpail2.data.checksums import folder_manifest, verify_manifest
from torchrl_mpail2.data.demos import (
    EPISODE_KEY, FORMAT_NAME, FORMAT_VERSION, HEADER_FILE, INDEX_KEYS, OBSERVATIONS_DIR, STEP_KEY, DemoFormatError,
    Demonstrations, check_finite_observations, _dtype_from_name, _key_from_json,
)
from torchrl_mpail2.envs.keys import observation_keys_of, pictures_of

__all__ = ["check_observation_spec", "env_options_hint", "load_demos", "save_demos"]


def save_demos(demos: Demonstrations, path: str | Path, overwrite: bool = False) -> Path:
    """Writes demonstrations to a directory (format in the module docstring).

    Written to a temporary sibling first and moved into place, so an interrupted save never
    leaves a half-written demo directory under ``path``.

    Args:
        demos (Demonstrations): what to write.
        path (str or Path): target directory; must not exist unless ``overwrite``.
        overwrite (bool): replace an existing directory. Defaults to ``False``.

    Returns:
        Path: ``path``.
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; pass overwrite=True to replace it.")
    check_finite_observations(demos.observations, ValueError, f"Not saving demonstrations to {path}")
    path.parent.mkdir(parents=True, exist_ok=True)
    staging = path.parent / f".{path.name}.tmp-{uuid.uuid4().hex[:8]}"
    try:
        staging.mkdir()
        arrays_dir = staging / OBSERVATIONS_DIR
        demos.observations.memmap(arrays_dir)
        files = folder_manifest(staging, OBSERVATIONS_DIR)
        header = {key: value for key, value in demos.header.items() if key != "files"}
        header["files"] = files
        (staging / HEADER_FILE).write_text(json.dumps(header, indent=1))
        if path.exists() and overwrite:
            shutil.rmtree(path)
        try:
            os.replace(staging, path)
        except OSError as error:  # another writer moved its folder into place after the check above
            if path.exists():
                raise FileExistsError(f"{path} exists (written meanwhile by another process)") from error
            raise
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return path


def _read_header(path: Path) -> dict:
    header_path = path / HEADER_FILE
    if not header_path.is_file():
        raise DemoFormatError(f"{path} is not a demo directory: {HEADER_FILE} is missing.")
    try:
        header = json.loads(header_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise DemoFormatError(f"{header_path} is truncated or corrupted: {error}") from error
    if not isinstance(header, dict) or header.get("format") != FORMAT_NAME:
        raise DemoFormatError(f"{header_path} is corrupted or not a {FORMAT_NAME} header.")
    if header.get("format_version") != FORMAT_VERSION:
        raise DemoFormatError(
            f"{header_path} has format_version {header.get('format_version')!r}; this code reads {FORMAT_VERSION}."
        )
    required = ("env_id", "observation_keys", "num_episodes", "num_steps", "num_observations", "episodes", "files")
    missing = [name for name in required if name not in header]
    if missing:
        raise DemoFormatError(f"{header_path} is truncated or corrupted: missing fields {missing}.")
    return header


def _check_contents(observations: TensorDict, header: dict) -> None:
    """Cross-checks the loaded arrays against the header (catches edited or mismatched headers)."""
    expected = {_key_from_json(entry["key"]): entry for entry in header["observation_keys"]}
    stored = set(observations.keys(True, True)) - set(INDEX_KEYS)
    if stored != set(expected) or not all(key in observations.keys() for key in INDEX_KEYS):
        raise DemoFormatError(f"Stored keys {sorted(map(str, stored))} disagree with the header; data is corrupted.")
    count = header["num_observations"]
    if observations.batch_size != torch.Size([count]):
        raise DemoFormatError(f"{observations.batch_size[0]} observations stored, {count} in the header; data is corrupted.")
    for key, entry in expected.items():
        tensor = observations.get(key)
        if list(tensor.shape[1:]) != list(entry["shape"]) or tensor.dtype != _dtype_from_name(entry["dtype"]):
            raise DemoFormatError(f"Key {key!r} stored as {tuple(tensor.shape[1:])} {tensor.dtype}, header says {entry}.")
    lengths = [int(meta["length"]) for meta in header["episodes"]]
    counts = torch.tensor(lengths, dtype=torch.long) + 1
    if len(lengths) != header["num_episodes"] or sum(lengths) != header["num_steps"] or int(counts.sum()) != count:
        raise DemoFormatError("Episode metadata disagrees with the episode/step counts; header is corrupted.")
    episode_index = torch.repeat_interleave(torch.arange(len(lengths)), counts)
    step_index = torch.cat([torch.arange(int(c)) for c in counts])
    if not (torch.equal(observations[EPISODE_KEY], episode_index) and torch.equal(observations[STEP_KEY], step_index)):
        raise DemoFormatError("The episode/step index arrays disagree with the header; data is corrupted.")


#: Shown for an env option a header or an env does not set (the env's default applies).
_UNSET = "not set"


def env_options_hint(recorded: dict | None, env_kwargs: dict | None) -> str:
    """A sentence naming the env options (``make_env`` arguments, ``obs`` included) that differ between the options
    the demonstrations were made with (``recorded``, their header's ``env_kwargs``) and the env's (``env_kwargs``);
    the demos' options alone where the env's are unknown, and ``""`` where the header records none or none differ.

    Examples:
        >>> env_options_hint({"obs": "state"}, {"obs": "state", "observe_gripper_command": True}).split(";")[0]
        ' The env option that likely differs: observe_gripper_command (demos: not set, env: True)'
        >>> env_options_hint({}, {"obs": "state"})
        ''
    """
    if not recorded:
        return ""
    if env_kwargs is None:
        return f" The demos were made with the env options {recorded}."
    differing = [name for name in sorted({*recorded, *env_kwargs})
                 if recorded.get(name, _UNSET) != env_kwargs.get(name, _UNSET)]
    if not differing:
        return ""
    listed = ", ".join(f"{name} (demos: {recorded.get(name, _UNSET)}, env: {env_kwargs.get(name, _UNSET)})"
                       for name in differing)
    options = "option that likely differs" if len(differing) == 1 else "options that likely differ"
    return (f" The env {options}: {listed}; make the demos with the env's options "
            "(demos import/record --preset NAME or --env-kwargs JSON).")


def check_observation_spec(demos: Demonstrations, observation_spec: Composite | EnvBase,
                           keys: Sequence[str] | None = None, *, env_kwargs: dict | None = None) -> None:
    """Raises ``ValueError`` if the demos' observation keys or shapes differ from an env's spec.

    The keys compared are those of :func:`~torchrl_mpail2.envs.keys.observation_keys_of` (pass the env
    rather than its spec so that its own bookkeeping transforms are recognised), or ``keys`` (some of them: the
    demos must hold those and may lack the others, as video-only demonstrations do); batch dimensions of the
    spec are stripped before shapes are compared.

    Keyword Args:
        env_kwargs (dict, optional): the options the env was built with (``{"obs": ..., **make_env kwargs}``). Where
            the demos' header records its own (``env_kwargs``), the error names the options that differ
            (:func:`env_options_hint`).
    """
    spec_keys = observation_keys_of(observation_spec)
    if keys is not None:
        unknown = [key for key in keys if key not in spec_keys]
        if unknown:
            raise ValueError(f"demonstration keys {unknown} are not observation keys of the env {spec_keys}")
        spec_keys = [key for key in spec_keys if key in keys]
    if isinstance(observation_spec, EnvBase):
        drawn, recorded = pictures_of(observation_spec), demos.header.get("pictures")
        if drawn is not None and drawn != recorded and any(key in spec_keys for key in demos.observation_keys):
            raise ValueError(
                f"Demonstrations ({demos.env_id}) hold pictures "
                f"{f'drawn as {recorded!r}' if recorded else 'drawn before the header recorded how'}, the env draws "
                f"them as {drawn!r}: record the demonstrations again (or delete their cached folder under demos/ so "
                "that a run records them)")
        observation_spec = observation_spec.observation_spec
    hint = env_options_hint(demos.header.get("env_kwargs"), env_kwargs)
    demo_keys = demos.observation_keys
    missing = [key for key in spec_keys if key not in demo_keys]
    extra = [key for key in demo_keys if key not in spec_keys and key not in (keys or ())]
    if missing or extra:
        raise ValueError(
            f"Demonstrations ({demos.env_id}) do not match the observation spec: "
            f"keys missing from the demos {missing}, extra keys in the demos {extra}.{hint}"
        )
    batch_dims = len(observation_spec.shape)
    for key in spec_keys:
        expected = tuple(observation_spec[key].shape[batch_dims:])
        stored = tuple(demos.observations.get(key).shape[1:])
        if expected != stored:
            raise ValueError(
                f"Observation key {key!r} has shape {stored} in the demonstrations but {expected} in the observation "
                f"spec.{hint}"
            )
        if observation_spec[key].dtype != demos.observations.get(key).dtype:
            raise ValueError(
                f"Observation key {key!r} has dtype {demos.observations.get(key).dtype} in the demonstrations "
                f"but {observation_spec[key].dtype} in the observation spec.{hint}"
            )


def load_demos(path: str | Path, observation_spec: Composite | EnvBase | None = None, verify: bool = True,
               keys: Sequence[str] | None = None, *, env_kwargs: dict | None = None) -> Demonstrations:
    """Loads and validates demonstrations written by :func:`save_demos`.

    Every stored file is checked against the byte size and sha256 recorded in the header before
    anything is read, so truncated or corrupted data raises instead of loading silently (a
    truncated memmap would otherwise read as zeros). The data is copied into memory.

    Args:
        path (str or Path): demo directory.
        observation_spec (Composite or EnvBase, optional): an env (or its observation spec) to check keys and
            shapes against (:func:`check_observation_spec`).
        verify (bool): also compare sha256 checksums (sizes are always checked). Defaults to ``True``.
        keys (Sequence[str], optional): keep only these observation keys, which the demos must hold; the spec's
            other keys may be missing (``train.demo_keys``: video-only demonstrations).

    Keyword Args:
        env_kwargs (dict, optional): the options the env of ``observation_spec`` was built with, so that a mismatch
            names the options that differ from those in the demos' header (:func:`check_observation_spec`).

    Raises:
        DemoFormatError: missing/invalid header, unknown format version, truncated or corrupted files, NaN or Inf
            in an observation (the message names the key and the episodes).
        ValueError: keys or shapes differ from ``observation_spec`` (the message names the key and both shapes,
            and the env options that differ where both are known).
    """
    path = Path(path)
    header = _read_header(path)
    try:
        verify_manifest(path, header["files"], DemoFormatError, check_digests=verify)
        observations = TensorDict.load_memmap(path / OBSERVATIONS_DIR).to_tensordict()
        _check_contents(observations, header)
        check_finite_observations(observations, DemoFormatError, str(path))
    except DemoFormatError:
        raise
    except (KeyError, TypeError, ValueError, RuntimeError, OSError, AttributeError) as error:
        raise DemoFormatError(f"{path} is truncated or corrupted: {type(error).__name__}: {error}") from error
    demos = Demonstrations(observations=observations, header=header)
    if keys is not None:
        demos = demos.with_keys(keys)
    if observation_spec is not None:
        check_observation_spec(demos, observation_spec, keys, env_kwargs=env_kwargs)
    return demos
