"""Files written whole: readers only ever see no file, the old one, or the whole new one.

One scheme for every file lobelight writes (models, checkpoints, images, reports, caches): the
bytes go to a unique temporary name beside the target (``mkstemp``: ``.<name>.<random>.partial``
plus the target's own suffix, for writers that pick a format by extension), are flushed to disk,
get the permissions a plainly created file would have (``mkstemp`` makes owner-only files), and
``os.replace`` renames them over the target. Two processes writing one path each rename a
complete file, and the last one wins; an error removes the temporary file and leaves the target
as it was.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

__all__ = ["PARTIAL_SUFFIX", "atomic_path", "atomic_writer"]

#: What every temporary name contains (before the target's suffix); their names are unique.
PARTIAL_SUFFIX = ".partial"


def _publish(tmp: str, path: Path) -> None:
    with open(tmp, "rb+") as f:  # the data is on disk before the name points at it
        os.fsync(f.fileno())
    mask = os.umask(0)
    os.umask(mask)
    os.chmod(tmp, 0o666 & ~mask)
    os.replace(tmp, path)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """A temporary path beside ``path``, ending in ``path``'s suffix, that becomes ``path``
    when the ``with`` block ends without an error (module docstring). For writers that open
    the file themselves (image and EXR libraries); the parent folder is created."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(
        prefix=f".{path.name}.", suffix=PARTIAL_SUFFIX + path.suffix, dir=path.parent
    )
    os.close(fd)
    try:
        yield Path(tmp)
        _publish(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


@contextlib.contextmanager
def atomic_writer(path: str | os.PathLike) -> Iterator[BinaryIO]:
    """A binary file that becomes ``path`` when the ``with`` block ends without an error
    (:func:`atomic_path`)."""
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        yield f
