"""Files written whole: readers only ever see no file, the old one, or the whole new one.

One scheme for every file lobelight writes (models, checkpoints, images, reports, caches): the
bytes go to a unique temporary name beside the target (``mkstemp``:
``.<name>.p<pid>.<random>.partial`` plus the target's own suffix, for writers that pick a format
by extension), are flushed to disk,
get the permissions a plainly created file would have (``mkstemp`` makes owner-only files), and
``os.replace`` renames them over the target. Two processes writing one path each rename a
complete file, and the last one wins; an error removes the temporary file and leaves the target
as it was.

Files read go through one door too, :func:`read_input` (or :func:`check_input` for a library
that opens the file by name): a regular file of a known size, under a limit per kind, read in
one bounded call. A device, a pipe or a socket (``/dev/zero``, a FIFO) would be read forever.

Leftovers. A process killed while it writes (``kill -9``, a power cut) leaves its temporary
file behind. The first write of a process (of each command, within :func:`protect_inputs`)
into a folder removes the stale ones there
(:func:`remove_stale_partials`): those of a process no longer running on this machine, untouched
for :data:`STALE_SECONDS`, and any untouched for :data:`ABANDONED_SECONDS` (a name without a
process id, or a process id since reused); a live writer's temporary file is never touched.

Inputs kept safe. Within :func:`protect_inputs` (the command line runs each command in it),
every file read through this door is remembered by its device and inode (so a hard link or a
symbolic link to it is the same file): :func:`check_outputs` refuses an output that is one of
them, and :func:`atomic_path` never replaces one.
"""

from __future__ import annotations

import contextlib
import os
import re
import stat
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

from .errors import InputError

__all__ = [
    "ABANDONED_SECONDS",
    "IMAGE_LIMIT",
    "PARTIAL_SUFFIX",
    "STALE_SECONDS",
    "TEXT_LIMIT",
    "atomic_path",
    "atomic_writer",
    "check_input",
    "check_outputs",
    "note_input",
    "protect_inputs",
    "read_input",
    "remove_stale_partials",
]

#: Size limits of the files read, in bytes: images (a 16K x 8K float EXR is 1.6 GB) and scene
#: descriptions (TOML or JSON text); meshes have theirs in lobelight.scene (MAX_MESH_BYTES).
IMAGE_LIMIT = 4 << 30
TEXT_LIMIT = 16 << 20

#: What every temporary name contains (before the target's suffix); their names are unique.
PARTIAL_SUFFIX = ".partial"

#: A temporary file of a process no longer running is stale once untouched this long (seconds):
#: a writer on another machine sharing the folder, whose process id means nothing here, writes
#: more often than that.
STALE_SECONDS = 60.0
#: Any temporary file untouched this long (seconds) is abandoned.
ABANDONED_SECONDS = 86400.0

# .<name>.[p<pid>.]<mkstemp's 8 characters>.partial[<suffix>]
_PARTIAL = re.compile(r"\..+?\.(?:p(?P<pid>\d+)\.)?[a-z0-9_]{8}\.partial(?:\.[^./]*)?")
# the folders this process has cleaned (once each)
_CLEANED: set[str] = set()

# within protect_inputs: (device, inode) -> the name of every file read through check_input
_INPUTS: dict[tuple[int, int], str] | None = None


def _publish(tmp: str, path: Path) -> None:
    with open(tmp, "rb+") as f:  # the data is on disk before the name points at it
        os.fsync(f.fileno())
    mask = os.umask(0)
    os.umask(mask)
    os.chmod(tmp, 0o666 & ~mask)
    check_outputs(path)  # the last guard: an input is never replaced
    os.replace(tmp, path)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """A temporary path beside ``path``, ending in ``path``'s suffix, that becomes ``path``
    when the ``with`` block ends without an error (module docstring). For writers that open
    the file themselves (image and EXR libraries); the parent folder is created."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_partials(path.parent)
    fd, tmp = tempfile.mkstemp(
        prefix=f".{path.name}.p{os.getpid()}.", suffix=PARTIAL_SUFFIX + path.suffix, dir=path.parent
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
    if _INPUTS is not None:
        _INPUTS.setdefault((st.st_dev, st.st_ino), name)
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


def note_input(path: str | os.PathLike) -> None:
    """Within :func:`protect_inputs`, remember ``path`` as an input (as :func:`check_input` does
    for what it checks), for a file read elsewhere or only named (a scene's environment map); a
    missing one is skipped."""
    if _INPUTS is None:
        return
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return
    _INPUTS.setdefault((st.st_dev, st.st_ino), str(path))


@contextlib.contextmanager
def protect_inputs() -> Iterator[None]:
    """Within the ``with`` block, the files read are inputs that no output may be (module
    docstring): :func:`check_outputs` refuses them and :func:`atomic_path` never replaces one.
    Process-wide; not nested."""
    global _INPUTS
    _INPUTS = {}
    _CLEANED.clear()  # a new run: each folder it writes in is cleaned again
    try:
        yield
    finally:
        _INPUTS = None


def check_outputs(*paths: str | os.PathLike) -> None:
    """Within :func:`protect_inputs`, an :class:`InputError` naming the first of ``paths`` that
    is a file read as an input (the same path, a hard link or a symbolic link to it: the same
    device and inode); a path that does not exist yet is none."""
    if _INPUTS is None:
        return
    for path in paths:
        try:
            st = os.stat(path)
        except (OSError, ValueError):
            continue
        source = _INPUTS.get((st.st_dev, st.st_ino))
        if source is not None:
            same = "" if os.path.abspath(source) == os.path.abspath(path) else f" {source!r}"
            raise InputError(
                str(path), f"is the input{same}: writing it would destroy it (name another output)"
            )


def _partial_is_stale(entry: os.DirEntry, now: float) -> bool:
    m = _PARTIAL.fullmatch(entry.name)
    if m is None:
        return False
    try:
        st = entry.stat(follow_symlinks=False)
    except OSError:
        return False
    if not stat.S_ISREG(st.st_mode):
        return False
    idle = now - st.st_mtime
    if idle > ABANDONED_SECONDS:
        return True
    pid = int(m["pid"]) if m["pid"] else None
    return pid is not None and pid != os.getpid() and idle > STALE_SECONDS and not _alive(pid)


def _alive(pid: int) -> bool:
    """Whether a process ``pid`` runs on this machine (or cannot be told apart from one)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, OSError):
        return True  # someone else's process, or a number no process can have: left alone
    return True


def remove_stale_partials(folder: str | os.PathLike, *, force: bool = False) -> list[str]:
    """Remove the stale temporary files of killed writers in ``folder`` (module docstring), once
    per folder and process unless ``force``; returns the names removed. Never raises."""
    key = os.path.abspath(folder)
    if key in _CLEANED and not force:
        return []
    _CLEANED.add(key)
    removed = []
    now = time.time()
    try:
        with os.scandir(folder) as it:
            stale = [e for e in it if _partial_is_stale(e, now)]
    except OSError:
        return []
    for e in stale:
        with contextlib.suppress(OSError):
            os.unlink(e.path)
            removed.append(e.name)
    return removed
