"""Byte sizes and sha256 digests of the files of a folder: written with demonstrations and checkpoints, checked on load.

A manifest maps each file's path (relative to the folder, POSIX style) to ``{"nbytes": int, "sha256": str}``.
A memory-mapped file that was cut short would otherwise read as zeros, and a flipped byte as a changed number.
"""
from __future__ import annotations

import hashlib
from collections.abc import Mapping
from pathlib import Path

__all__ = ["file_digest", "folder_manifest", "verify_manifest"]

_HASH_CHUNK_BYTES = 1 << 20


def file_digest(path: str | Path) -> str:
    """sha256 of a file's bytes, as hex."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for chunk in iter(lambda: handle.read(_HASH_CHUNK_BYTES), b""):
            digest.update(chunk)
    return digest.hexdigest()


def folder_manifest(root: str | Path, under: str | Path | None = None) -> dict[str, dict]:
    """Size and sha256 of every file below ``root / under`` (all of ``root`` by default), keyed relative to ``root``.

    Examples:
        >>> import tempfile
        >>> with tempfile.TemporaryDirectory() as d:
        ...     _ = (Path(d) / "a.bin").write_bytes(b"abc")
        ...     folder_manifest(d)["a.bin"]["nbytes"]
        3
    """
    root = Path(root)
    base = root / under if under is not None else root
    return {file.relative_to(root).as_posix(): {"nbytes": file.stat().st_size, "sha256": file_digest(file)}
            for file in sorted(base.rglob("*")) if file.is_file()}


def verify_manifest(root: str | Path, manifest: Mapping[str, Mapping], error: type[Exception], *,
                    check_digests: bool = True) -> None:
    """Raises ``error`` naming the first file of ``manifest`` that is missing, has another size or another sha256.

    Args:
        root (str or Path): the folder the manifest's paths are relative to.
        manifest (Mapping): as written by :func:`folder_manifest`.
        error (type): the exception class to raise (e.g. ``DemoFormatError``).

    Keyword Args:
        check_digests (bool): compare sha256 digests too (sizes are always compared). Defaults to ``True``.
    """
    root = Path(root)
    for relative, expected in manifest.items():
        file = root / relative
        if not file.is_file():
            raise error(f"{file} is missing: the folder is truncated or corrupted.")
        size = file.stat().st_size
        if size != expected["nbytes"]:
            raise error(f"{file} is truncated or corrupted: {size} bytes on disk, {expected['nbytes']} recorded.")
        if check_digests and file_digest(file) != expected["sha256"]:
            raise error(f"{file} is corrupted: its sha256 does not match the one recorded.")
