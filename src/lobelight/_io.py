"""Files written whole: readers only ever see no file, the old one, or the whole new one.

One scheme for every file lobelight writes (models, checkpoints, images, reports, caches): the
bytes go to a unique temporary name beside the target (``mkstemp``: ``.<name>.<random>.partial``
plus the target's own suffix, for writers that pick a format by extension), are flushed to disk,
get the permissions a plainly created file would have (``mkstemp`` makes owner-only files), and
``os.replace`` renames them over the target. Two processes writing one path each rename a
complete file, and the last one wins; an error removes the temporary file and leaves the target
as it was.

Files read go through one door too, :func:`read_input` (or :func:`check_input` for a library
that opens the file by name): a regular file of a known size, under a limit per kind, read in
one bounded call. A device, a pipe or a socket (``/dev/zero``, a FIFO) would be read forever.
"""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

from .errors import InputError

__all__ = [
    "IMAGE_LIMIT",
    "PARTIAL_SUFFIX",
    "TEXT_LIMIT",
    "atomic_path",
    "atomic_writer",
    "check_input",
    "read_input",
]

#: Size limits of the files read, in bytes: images (a 16K x 8K float EXR is 1.6 GB) and scene
#: descriptions (TOML or JSON text); meshes have theirs in lobelight.scene (MAX_MESH_BYTES).
IMAGE_LIMIT = 4 << 30
TEXT_LIMIT = 16 << 20

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


def check_input(path: str | os.PathLike, *, limit: int) -> int:
    """The size of ``path`` in bytes, after checking that it is a regular file (symbolic links
    followed) of at most ``limit`` bytes; else :class:`InputError` naming it."""
    name = str(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise InputError(name, "no such file") from None
    except OSError as e:
        raise InputError(name, f"cannot read the file ({e.strerror or e})") from None
    if stat.S_ISDIR(st.st_mode):
        raise InputError(name, "is a directory, not a file")
    if not stat.S_ISREG(st.st_mode):
        raise InputError(name, "is not a regular file (a device, pipe or socket has no end)")
    if st.st_size > limit:
        raise InputError(name, f"is {st.st_size:,} bytes, more than the {limit:,} bytes read here")
    return st.st_size


def read_input(path: str | os.PathLike, *, limit: int) -> bytes:
    """The bytes of ``path``, a regular file of at most ``limit`` bytes (:func:`check_input`),
    read in reads sized by the file, not by the limit (a read asks for that much memory at
    once), and refused if it grows past the limit meanwhile."""
    size = check_input(path, limit=limit)
    chunks: list[bytes] = []
    total = 0
    try:
        with open(path, "rb") as f:
            want = size + 1  # one read for a file that does not change, and one to see its end
            while chunk := f.read(min(want, limit + 1 - total)):
                chunks.append(chunk)
                total += len(chunk)
                if total > limit:
                    raise InputError(str(path), f"grew past {limit:,} bytes while it was read")
                want = 1 << 20
    except OSError as e:
        raise InputError(str(path), f"cannot read the file ({e.strerror or e})") from None
    return b"".join(chunks)
