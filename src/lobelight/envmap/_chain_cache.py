"""Prefiltered chains, and resampled cube maps, kept on disk: a map is prefiltered (and
resampled for a renderer's background and SH projection) once per machine.

Layout: one uncompressed ``.npz`` (no pickles) per chain, ``<folder>/<key>.npz`` with the folder
``lobelight._cache.cache_dir() / "prefilter"`` by default, holding

- ``header``: a JSON string, the key and what it was computed from (:func:`chain_key`);
- ``lambdas``: ``(K,)`` float64, the levels' sharpness;
- ``level_00`` ... ``level_{K-1}``: ``(6, R_k, R_k, 3)`` float32, the levels as computed (float32
  because that is what the chain holds, so a cached chain equals a fresh one bit for bit; float16
  would halve the bytes but overflows above 65504, below an unclipped sun's radiance).

The key is a sha256 over a JSON description (this module's :data:`FORMAT_VERSION`, the source's
kind, dtype and shape, and the chain's settings, which include the prefilter's own version and
numerical constants) followed by the source's float32 bytes. Reading checks everything it reads
(zip CRCs, the key, the level count, shapes, dtypes, finiteness); an entry that fails, or cannot
be read at all, is a miss: the chain is computed again and the entry rewritten. Entries are
written atomically (:func:`lobelight._io.atomic_writer`), so concurrent writers of one key
leave one whole entry, and deleting any of them, or the folder, at any time is harmless.

A resampled cube map (:meth:`lobelight.envmap.EnvMap.to_cubemap` with ``cache``) is an entry
``<folder>/cube-<key>.npz`` in the same folder, holding ``header`` (as above) and ``cube``:
``(6, R, R, 3)`` float32 as computed; its key is made the same way (:func:`chain_key`, with the
resampling's version, resolution and constants as the description), read with the same checks
(:func:`read_cube`) and written the same way (:func:`write_cube`).

The folder is kept under a size cap (:func:`max_bytes`: ``$LOBELIGHT_CACHE_MAX_MB``, default
2048 MB; a base-512 chain takes about 100 MB): after each write the least recently used entries
go first (a read marks an entry used by touching its modification time).
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .._cache import UNREADABLE, cache_dir, cache_max_bytes, regular_entry
from .._io import atomic_writer
from ..errors import InputError

__all__ = [
    "FORMAT_VERSION",
    "cache_folder",
    "chain_key",
    "default_folder",
    "max_bytes",
    "read_chain",
    "read_cube",
    "trim",
    "write_chain",
    "write_cube",
]

#: Layout of the stored file; bumped when it changes (the key changes with it).
FORMAT_VERSION = 1

logger = logging.getLogger(__name__)


#: The cap of the cache folder unless ``$LOBELIGHT_CACHE_MAX_MB`` says otherwise.
DEFAULT_MAX_MB = 2048


def max_bytes() -> int:
    """The size cap of the chain folder, in bytes (module docstring)."""
    return cache_max_bytes(DEFAULT_MAX_MB)


def trim(folder: str | os.PathLike, limit: int, *, keep: str | os.PathLike | None = None) -> None:
    """Delete the least recently used entries of ``folder`` until they sum to at most ``limit``
    bytes; ``keep`` (the entry just written) goes last. Entries that vanish meanwhile (another
    process trimming) are skipped."""
    entries = []
    for p in Path(folder).glob("*.npz"):
        try:
            st = p.stat()
        except OSError:
            continue
        entries.append((p == Path(keep) if keep is not None else False, st.st_mtime, st.st_size, p))
    total = sum(e[2] for e in entries)
    for _, _, size, p in sorted(entries, key=lambda e: (e[0], e[1])):
        if total <= limit:
            break
        try:
            p.unlink()
        except OSError:
            continue
        total -= size


def default_folder() -> Path:
    """``cache_dir() / "prefilter"``, where :func:`lobelight.envmap.prefilter` keeps chains."""
    return cache_dir() / "prefilter"


def cache_folder(cache, accepted: str = "a bool or a folder") -> Path | None:
    """The folder a ``cache`` argument names: None for False (no cache), :func:`default_folder`
    for True, else the folder given. Raises InputError naming ``cache`` for anything else
    (``accepted`` says what the caller takes)."""
    if cache is False:
        return None
    if cache is True:
        return default_folder()
    if isinstance(cache, (str, os.PathLike)):
        return Path(cache)
    raise InputError("cache", f"must be {accepted}, got {cache!r}")


def chain_key(source: torch.Tensor, description: dict[str, Any]) -> str:
    """Hex sha256 naming the chain of ``source`` (any shape and dtype) built as ``description``.

    ``description`` (JSON-serialisable) holds everything besides the source's values that the
    levels depend on; the source's dtype and shape are added here.
    """
    arr = source.detach().to("cpu", torch.float32).contiguous().numpy()
    head = {
        **description,
        "format": FORMAT_VERSION,
        "dtype": str(source.dtype),
        "shape": list(arr.shape),
    }
    h = hashlib.sha256(json.dumps(head, sort_keys=True).encode())
    h.update(b"\0")
    h.update(arr.reshape(-1).view(np.uint8))
    return h.hexdigest()


def _open_entry(path: Path, kind: str) -> np.lib.npyio.NpzFile | None:
    """The open ``.npz`` archive of a cache entry, or None (logged) when it is missing, not a
    regular file (a pipe or device would block the read), unreadable or not an archive."""
    if not regular_entry(path):
        return None
    try:
        z = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        return None
    except UNREADABLE as exc:
        logger.info("ignoring the unreadable %s cache entry %s (%r)", kind, path, exc)
        return None
    if not isinstance(z, np.lib.npyio.NpzFile):  # a bare .npy file loads as one array
        logger.info("ignoring %s: not a %s cache entry", path, kind)
        return None
    return z


def read_chain(
    path: str | os.PathLike, key: str, resolutions: list[int]
) -> tuple[np.ndarray, list[np.ndarray]] | None:
    """``(lambdas (K,) float64, levels [(6, R_k, R_k, 3) float32])`` from an entry, or None.

    None when the file is missing, unreadable or not exactly the chain ``key`` with levels at
    ``resolutions`` (``K`` of them).
    """
    path = Path(path)
    z = _open_entry(path, "prefilter")
    if z is None:
        return None
    try:
        with z:
            got = _check(z, key, resolutions)
        if got is not None:
            _touch(path)
        return got
    except UNREADABLE as exc:
        logger.info("ignoring the unreadable prefilter cache entry %s (%r)", path, exc)
        return None


def _touch(path: Path) -> None:
    """Mark an entry used (its modification time), for :func:`trim`'s order."""
    try:
        os.utime(path)
    except OSError:
        pass


def _is_entry(z, key: str) -> bool:
    """Whether an open entry's header names it the entry ``key``."""
    header = z["header"]
    if header.dtype.kind != "U" or header.ndim != 0:
        return False
    head = json.loads(header.item())
    return isinstance(head, dict) and head.get("key") == key


def _check(z, key: str, resolutions: list[int]) -> tuple[np.ndarray, list[np.ndarray]] | None:
    if not _is_entry(z, key):
        return None
    lambdas = z["lambdas"]
    if lambdas.dtype != np.float64 or lambdas.shape != (len(resolutions),):
        return None
    levels = []
    for k, res in enumerate(resolutions):
        lv = z[f"level_{k:02d}"]
        if lv.dtype != np.float32 or lv.shape != (6, res, res, 3) or not np.isfinite(lv).all():
            return None
        levels.append(lv)
    return lambdas, levels


def write_chain(
    path: str | os.PathLike,
    key: str,
    description: dict[str, Any],
    lambdas: torch.Tensor,
    levels: list[torch.Tensor],
) -> None:
    """Store a chain as ``path`` (atomically; the folder is created). Raises OSError on failure.

    Parameters
    ----------
    lambdas : (K,) sharpness;  levels : K tensors (6, R_k, R_k, 3), any device
    """
    arrays = {
        "header": np.array(json.dumps({**description, "key": key}, sort_keys=True)),
        "lambdas": lambdas.detach().to("cpu", torch.float64).numpy(),
    }
    for k, lv in enumerate(levels):
        arrays[f"level_{k:02d}"] = lv.detach().to("cpu", torch.float32).numpy()
    with atomic_writer(path) as f:
        np.savez(f, **arrays)
    trim(Path(path).parent, max_bytes(), keep=path)


def cube_path(folder: str | os.PathLike, key: str) -> Path:
    """Where the resampled cube map named ``key`` is kept in ``folder``."""
    return Path(folder) / f"cube-{key}.npz"


def read_cube(path: str | os.PathLike, key: str, res: int) -> np.ndarray | None:
    """The ``(6, res, res, 3)`` float32 cube map of an entry, or None when the file is missing,
    unreadable or not exactly the cube ``key`` at ``res`` (finite values included)."""
    path = Path(path)
    z = _open_entry(path, "cube")
    if z is None:
        return None
    try:
        with z:
            if not _is_entry(z, key):
                return None
            cube = z["cube"]
    except UNREADABLE as exc:
        logger.info("ignoring the unreadable cube cache entry %s (%r)", path, exc)
        return None
    if cube.dtype != np.float32 or cube.shape != (6, res, res, 3) or not np.isfinite(cube).all():
        return None
    _touch(path)
    return cube


def write_cube(
    path: str | os.PathLike, key: str, description: dict[str, Any], cube: torch.Tensor
) -> None:
    """Store a resampled cube map ``(6, R, R, 3)`` as ``path`` (atomically; the folder is
    created), then trim the folder. Raises OSError on failure."""
    arrays = {
        "header": np.array(json.dumps({**description, "key": key}, sort_keys=True)),
        "cube": cube.detach().to("cpu", torch.float32).numpy(),
    }
    with atomic_writer(path) as f:
        np.savez(f, **arrays)
    trim(Path(path).parent, max_bytes(), keep=path)
