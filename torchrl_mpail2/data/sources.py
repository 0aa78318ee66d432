"""One entry point for demonstrations: a folder of this library's format, or ``<format>:<path>`` for an importer."""
from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

from torchrl_mpail2.data.demo_files import check_observation_spec, load_demos
from torchrl_mpail2.data.demos import Demonstrations
from torchrl_mpail2.data.minari_import import import_minari
from torchrl_mpail2.data.robomimic_import import import_robomimic
from torchrl_mpail2.data.robosuite_hdf5 import import_robosuite_hdf5
from torchrl_mpail2.data.ted import import_ted

__all__ = ["DEMO_SOURCES", "load_demo_source", "resolve_demo_source"]

#: Importer per source prefix; each takes ``(path, env, progress=...)`` and returns observation-only demos.
DEMO_SOURCES = {
    "minari": import_minari,
    "robomimic": import_robomimic,
    "robosuite_hdf5": import_robosuite_hdf5,
    "ted": import_ted,
}
_PREFIX = re.compile(r"([a-z][a-z0-9_]*):(.+)")


def _split(source: str | Path) -> tuple[str | None, str]:
    """``(prefix, path)`` of ``<format>:<path>``, or ``(None, source)`` for a plain path."""
    text = str(source)
    match = _PREFIX.fullmatch(text)
    if match is None or Path(text).exists():
        return None, text
    return match.group(1), match.group(2)


def resolve_demo_source(source: str | Path) -> str:
    """``source`` with its path made absolute (the prefix kept), so that a saved config loads from any folder."""
    prefix, path = _split(source)
    resolved = str(Path(path).resolve())
    return resolved if prefix is None else f"{prefix}:{resolved}"


def load_demo_source(source: str | Path, env=None, *, progress: bool = False, keys: Sequence[str] | None = None,
                     env_kwargs: dict | None = None, importer_kwargs: dict | None = None) -> Demonstrations:
    """Demonstrations from ``source``: a demo folder (:func:`load_demos`), or ``<format>:<path>`` with a format
    of :data:`DEMO_SOURCES` (e.g. ``robosuite_hdf5:demo.hdf5``), imported through ``env`` and checked against its
    observation spec. This is what ``train.demos=...`` accepts.

    Keyword Args:
        progress (bool): show the importer's progress bar.
        keys (sequence of str, optional): keep only these observation keys (``train.demo_keys``).
        env_kwargs (dict, optional): the options ``env`` was built with (``{"obs": ..., **make_env kwargs}``): an
            import records them in its header (``env_kwargs``), and a mismatch with the env names the options that
            differ from the header's (:func:`check_observation_spec`).
        importer_kwargs (dict, optional): keyword arguments of the importer (e.g. ``{"filter_key": "train"}`` for
            ``robomimic``); refused for a demo folder.
    """
    text = str(source)
    prefix, path = _split(source)
    if prefix is None:
        if importer_kwargs:
            raise ValueError(f"importer options {sorted(importer_kwargs)} apply to <format>:<path> sources, "
                             f"not to the demo folder {text!r}")
        return load_demos(source, env, keys=keys, env_kwargs=env_kwargs)
    if prefix not in DEMO_SOURCES:
        raise ValueError(f"unknown demonstration source prefix {prefix!r} in {text!r}; known: {sorted(DEMO_SOURCES)} "
                         "(or a demo folder path)")
    if env is None:
        raise ValueError(f"importing {text!r} needs the env to replay or check the observations")
    demos = DEMO_SOURCES[prefix](path, env, progress=progress, **(importer_kwargs or {}))
    if env_kwargs is not None:
        demos.header["env_kwargs"] = dict(env_kwargs)
    if keys is not None:
        demos = demos.with_keys(keys)
    check_observation_spec(demos, env, keys, env_kwargs=env_kwargs)
    return demos
