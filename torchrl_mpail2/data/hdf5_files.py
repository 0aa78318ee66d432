"""Reading the HDF5 files of other libraries (robomimic, robosuite, Minari) so that a bad file is named.

h5py reports a file cut short as ``OSError: Unable to synchronously open file (truncated file: ...)`` and a
malformed JSON attribute surfaces as a bare ``JSONDecodeError``; neither names the file. The importers open their
files and parse their JSON attributes through these two functions instead.
"""
from __future__ import annotations

import json
from pathlib import Path

__all__ = ["json_attribute", "open_hdf5"]


def open_hdf5(path: str | Path):
    """``h5py.File(path, "r")``, or a ``ValueError`` naming ``path`` when the file is truncated or not HDF5.

    h5py checks the file's length against the end-of-file address stored in its superblock when it opens it, so
    a file cut short (an interrupted copy or download) is refused here, before any dataset is read.

    Raises:
        ValueError: the file cannot be opened as HDF5 (the message names it and gives h5py's reason).

    Examples:
        >>> import tempfile
        >>> with tempfile.TemporaryDirectory() as d:
        ...     bad = Path(d) / "demo.hdf5"
        ...     _ = bad.write_bytes(b"not hdf5")
        ...     try:
        ...         open_hdf5(bad)
        ...     except ValueError as error:
        ...         print(str(error).startswith(f"{bad} cannot be read as HDF5"))
        True
    """
    import h5py

    try:
        return h5py.File(path, "r")
    except OSError as error:
        raise ValueError(f"{path} cannot be read as HDF5: the file is truncated or corrupted ({error})") from error


def json_attribute(path: str | Path, attrs, name: str, default=None):
    """The attribute ``name`` of an HDF5 group's ``attrs``, parsed as a JSON object; ``default`` where it is absent.

    Args:
        path: the file, named in the error.
        attrs: the group's ``attrs`` (e.g. ``f["data"].attrs``).
        name (str): the attribute (robomimic's ``env_args``, robosuite's ``env_info``).
        default: returned where the attribute is absent.

    Raises:
        ValueError: the attribute is not a JSON object (the message names the file, the attribute and the reason).

    Examples:
        >>> json_attribute("demo.hdf5", {"env_info": '{"control_freq": 20}'}, "env_info")
        {'control_freq': 20}
        >>> json_attribute("demo.hdf5", {"env_info": "{control_freq"}, "env_info")  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        ValueError: demo.hdf5: the attribute 'env_info' is not JSON (Expecting property name ...)
    """
    if name not in attrs:
        return default
    try:
        value = json.loads(attrs[name])
    except (TypeError, ValueError) as error:  # JSONDecodeError is a ValueError; bytes of another encoding too
        raise ValueError(f"{path}: the attribute {name!r} is not JSON ({error})") from error
    if not isinstance(value, dict):
        raise ValueError(f"{path}: the attribute {name!r} is not a JSON object (got {type(value).__name__})")
    return value
