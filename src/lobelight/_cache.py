"""Where lobelight keeps files it can rebuild, and how it writes them.

:func:`cache_dir` is the one folder for everything cached on disk (the cosine-lobe tables, the
prefiltered environment chains): ``$LOBELIGHT_CACHE`` if set, else the platform's user cache
folder (``platformdirs.user_cache_dir("lobelight")``: ``~/.cache/lobelight`` on Linux,
``~/Library/Caches/lobelight`` on macOS, ``%LOCALAPPDATA%\\lobelight\\Cache`` on Windows). Anything
in it may be deleted at any time; it is rebuilt when next needed.

Entries are written whole (:func:`lobelight._io.atomic_writer`), so two processes writing one
entry each rename a complete file and the last one wins.
"""

from __future__ import annotations

import os
import tokenize
import zipfile
import zlib
from pathlib import Path

import platformdirs

__all__ = ["UNREADABLE", "cache_dir"]

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
