"""Where lobelight keeps files it can rebuild, and how it writes them.

:func:`cache_dir` is the one folder for everything cached on disk (the cosine-lobe tables, the
prefiltered environment chains): ``$LOBELIGHT_CACHE`` if set, else the platform's user cache
folder (``platformdirs.user_cache_dir("lobelight")``: ``~/.cache/lobelight`` on Linux,
``~/Library/Caches/lobelight`` on macOS, ``%LOCALAPPDATA%\\lobelight\\Cache`` on Windows). Anything
in it may be deleted at any time; it is rebuilt when next needed.

Entries are written whole (:func:`lobelight._io.atomic_writer`), so two processes writing one
entry each rename a complete file and the last one wins. An entry that is not a regular file (a
FIFO, a device someone put there) is a miss, never opened (:func:`regular_entry`: opening a FIFO
waits for a writer forever).

The folder's size cap is ``$LOBELIGHT_CACHE_MAX_MB`` (:func:`cache_max_bytes`): a number of
megabytes >= 0, or ``inf`` for no cap; anything else (``nan``, ``-inf``, a negative number, a
word) is refused at the command line's door (:func:`check_environment`) before any work.
"""

from __future__ import annotations

import math
import os
import stat
import sys
import tokenize
import zipfile
import zlib
from pathlib import Path

import platformdirs

from .errors import InputError

__all__ = [
    "MAX_MB_ENV",
    "UNREADABLE",
    "cache_dir",
    "cache_max_bytes",
    "check_environment",
    "regular_entry",
]

#: The environment variable of the cache's size cap in megabytes (``inf``: no cap).
MAX_MB_ENV = "LOBELIGHT_CACHE_MAX_MB"

#: What reading a damaged ``.npz`` can raise, from zipfile, zlib and numpy's ``.npy`` reader: a
#: bad zip structure, unknown compression method or flags (NotImplementedError, RuntimeError),
#: corrupt deflate data, a short member, an impossible header (ValueError, MemoryError or
#: OverflowError for absurd shapes), a missing member (KeyError), a mangled ``.npy`` header
#: (SyntaxError, tokenize.TokenError from its literal parser).
UNREADABLE = (
    OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zipfile.LargeZipFile,
    NotImplementedError, RuntimeError, zlib.error, MemoryError, OverflowError, SyntaxError,
    tokenize.TokenError,
)  # fmt: skip


def cache_dir() -> Path:
    """``$LOBELIGHT_CACHE`` if set, else the platform's user cache folder for lobelight."""
    env = os.environ.get("LOBELIGHT_CACHE")
    if env:
        return Path(env).expanduser()
    return Path(platformdirs.user_cache_dir("lobelight", appauthor=False))


def cache_max_bytes(default_mb: float) -> int:
    """The cache's size cap in bytes: ``$LOBELIGHT_CACHE_MAX_MB`` megabytes (``inf``: no cap,
    ``sys.maxsize``), ``default_mb`` where it is unset or empty; an :class:`InputError` naming
    the variable where it is not a number >= 0 (``nan``, ``-inf``, ``-1``, a word)."""
    text = os.environ.get(MAX_MB_ENV, "").strip()
    if not text:
        mb = float(default_mb)
    else:
        try:
            mb = float(text)
        except ValueError:
            mb = math.nan
        if not mb >= 0:  # NaN, negative, -inf, a word
            raise InputError(
                MAX_MB_ENV, f"must be megabytes >= 0, or inf for no cap; got {text[:40]!r}"
            )
    if mb * 2**20 >= sys.maxsize:  # inf, or more bytes than any disk holds
        return sys.maxsize
    return int(mb * 2**20)


def check_environment() -> None:
    """The environment's settings of the cache checked at a program's door (the command line's,
    before any work): :func:`cache_max_bytes`."""
    cache_max_bytes(0)


def regular_entry(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a regular file (symbolic links followed), so that it can be opened
    without blocking; False for a missing entry, a FIFO, a device or a folder."""
    try:
        return stat.S_ISREG(os.stat(path).st_mode)
    except (OSError, ValueError):
        return False
