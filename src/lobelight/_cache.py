"""Where lobelight keeps files it can rebuild, and how it writes them.

:func:`cache_dir` is the one folder for everything cached on disk (the cosine-lobe tables, the
prefiltered environment chains): ``$LOBELIGHT_CACHE`` if set, else the platform's user cache
folder (``platformdirs.user_cache_dir("lobelight")``: ``~/.cache/lobelight`` on Linux,
``~/Library/Caches/lobelight`` on macOS, ``%LOCALAPPDATA%\\lobelight\\Cache`` on Windows). Anything
in it may be deleted at any time; it is rebuilt when next needed.

:func:`atomic_writer` writes a file so that readers only ever see no file, the old one or the
whole new one: the bytes go to a unique temporary name in the same folder (``mkstemp``), which
``os.replace`` then renames over the target, so two processes writing the same entry each
rename a complete file and the last one wins.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
import zipfile
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

import platformdirs

__all__ = ["PARTIAL_SUFFIX", "UNREADABLE", "atomic_writer", "cache_dir"]

#: Suffix of the temporary files :func:`atomic_writer` renames away (their names are unique).
PARTIAL_SUFFIX = ".partial"

#: What reading a damaged ``.npz`` can raise, from zipfile, zlib and numpy's ``.npy`` reader: a
#: bad zip structure, unknown compression method or flags (NotImplementedError, RuntimeError),
#: corrupt deflate data, a short member, an impossible header (ValueError, MemoryError or
#: OverflowError for absurd shapes), a missing member (KeyError).
UNREADABLE = (
    OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zipfile.LargeZipFile,
    NotImplementedError, RuntimeError, zlib.error, MemoryError, OverflowError,
)  # fmt: skip


def cache_dir() -> Path:
    """``$LOBELIGHT_CACHE`` if set, else the platform's user cache folder for lobelight."""
    env = os.environ.get("LOBELIGHT_CACHE")
    if env:
        return Path(env).expanduser()
    return Path(platformdirs.user_cache_dir("lobelight", appauthor=False))


@contextlib.contextmanager
def atomic_writer(path: str | os.PathLike) -> Iterator[BinaryIO]:
    """A binary file that becomes ``path`` when the ``with`` block ends without an error.

    The parent folder is created. On an error the temporary file is removed and the error
    propagates; ``path`` is then untouched.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=PARTIAL_SUFFIX, dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            yield f
            f.flush()
            os.fsync(f.fileno())  # the data is on disk before the name points at it
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
