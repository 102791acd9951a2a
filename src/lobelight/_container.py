"""A model file's container: a zip archive of ``.npy`` members. How much a read of one may
decompress, and its members inflated ahead of the read, in a child process, while the command
line imports torch.

The size rule. A model's arrays are floats, which deflate compresses by a few times at most,
while a zip bomb's members expand a thousandfold and more: a read decompresses at most
:func:`declared_limit` of the file's size, judged by the sizes the zip directory declares (which
decompression never exceeds), before anything is decompressed.

Reading ahead. A render's start spends most of a second importing torch, on one of the
machine's cores, and then a few tenths inflating the model file's members (zlib, about 300 MB
a second on one core). A thread beside the import slows it by as much as it saves (the import
holds the interpreter's lock), a child process does not: :func:`read_ahead` forks a child
before torch is imported that inflates every member into shared anonymous memory, one mapping
per member, and ends. The model reader (:mod:`lobelight.model._format`) asks :func:`take` for
the file's members once its own checks of the container have passed; it gets them only if the
file is the one the child read (the same device, inode, size, modification time and zip
directory) and the child inflated every member with its checksum right, and reads the file
itself otherwise, with its own errors. The arrays it gets share the mappings, which are freed
with them; a member's mapping is as large as the array the reader would allocate anyway.

Only where :func:`os.fork` is safe (Linux), only before anything has started a thread, and only
in a process of the command line's own: a program that embeds the library reads as before.
"""

from __future__ import annotations

import mmap
import os
import signal
import stat
import sys
import threading
import zipfile
from dataclasses import dataclass
from pathlib import Path

#: The largest model file read (a 50K-vertex model with three Gaussians is about 100 MB).
MAX_FILE_BYTES = 1 << 36

#: Decompressed bytes a model file may hold beyond ``EXPANSION`` times its own size.
EXPANSION_SLACK = 64 << 20
EXPANSION = 100

#: The most memory a model takes once read, in bytes (8 GiB): its arrays as decompressed plus
#: its Gaussians expanded to every (vertex, view) record, 7 float32 per Gaussian, which is
#: ``2,576 N`` bytes per vertex for N Gaussians per view (a million vertices at N = 3, 417,000
#: at N = 8). A file whose sizes (those the zip directory declares, and the counts of its
#: metadata) add up to more is refused before they are allocated; a read's peak stays within
#: about twice this (the arrays are copied as the model is built from them).
MAX_READ_BYTES = 8 << 30

#: Members' declared bytes below which a file is not read ahead (a child costs a few
#: milliseconds; a small file inflates in less).
AHEAD_MIN_BYTES = 8 << 20

# bytes inflated per call in the child (bounds zlib's own buffers)
_CHUNK = 16 << 20


def declared_limit(file_bytes: int) -> int:
    """The most bytes a model file of ``file_bytes`` bytes may decompress to."""
    return min(EXPANSION_SLACK + EXPANSION * file_bytes, MAX_READ_BYTES)


def directory(archive: zipfile.ZipFile) -> list[tuple]:
    """What a zip directory declares of each member: name, sizes, checksum, offset."""
    return [
        (i.filename, i.file_size, i.compress_size, i.CRC, i.header_offset)
        for i in archive.infolist()
    ]


@dataclass
class _Ahead:
    """A read ahead under way: the file's identity, its directory, the child and what it
    fills (one shared anonymous mapping per member, in directory order)."""

    path: str
    identity: tuple
    directory: list[tuple]
    pid: int
    done: int  # the read end of the pipe the child answers on
    maps: list[mmap.mmap]


# the read ahead of this process, if any (a command reads one model)
_AHEAD: _Ahead | None = None


def _other_threads() -> bool:
    """Whether a thread besides this one runs: a fork copies only the calling thread, and a
    lock another thread holds stays held in the child."""
    return threading.active_count() > 1


def _identity(st: os.stat_result) -> tuple:
    return (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)


def read_ahead(path) -> bool:
    """Start inflating the model file ``path``'s members in a child process (see the module's
    text); returns whether it started. Nothing is started, and nothing is said, where the file
    is not a regular zip file within the size rule, is small (:data:`AHEAD_MIN_BYTES`), the
    platform is not Linux, or a thread besides the main one is running: the reader then reads
    the file itself, and reports what is wrong with it."""
    global _AHEAD
    if _AHEAD is not None or not sys.platform.startswith("linux"):
        return False
    if _other_threads():
        return False
    p = str(Path(path))
    try:
        st = os.stat(p)
        if not 0 < st.st_size <= MAX_FILE_BYTES or not stat.S_ISREG(st.st_mode):
            return False
        with zipfile.ZipFile(p) as archive:
            infos = archive.infolist()
            found = directory(archive)
    except (OSError, zipfile.BadZipFile, ValueError, EOFError):
        return False
    total = sum(i.file_size for i in infos)
    if total < AHEAD_MIN_BYTES or total > declared_limit(st.st_size):
        return False
    if any(i.file_size == 0 or i.flag_bits & 0x1 for i in infos):  # empty or encrypted
        return False
    maps = [mmap.mmap(-1, i.file_size) for i in infos]  # shared with the child
    done, answer = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: inflate, answer, end without the parent's exit handlers
        os.close(done)
        _inflate_and_exit(p, infos, maps, answer)
    os.close(answer)
    _AHEAD = _Ahead(p, _identity(st), found, pid, done, maps)
    return True


def _inflate_and_exit(path: str, infos: list[zipfile.ZipInfo], maps: list[mmap.mmap], answer):
    """The child's whole life: every member inflated into its mapping, the checksums checked as
    the last bytes are read; ``b"1"`` on the pipe when all is well, ``b"0"`` otherwise."""
    ok = False
    try:
        # Ctrl-C reaches the child as well: it ends as the parent does, without a traceback
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        with zipfile.ZipFile(path) as archive:
            for info, m in zip(infos, maps, strict=True):
                with archive.open(info) as f:
                    pos = 0
                    while pos < info.file_size:
                        chunk = f.read(min(_CHUNK, info.file_size - pos))
                        if not chunk:
                            break
                        m[pos : pos + len(chunk)] = chunk
                        pos += len(chunk)
                    # read to the member's end: zipfile checks the checksum there
                    ok_member = pos == info.file_size and f.read(1) == b""
                if not ok_member:
                    raise ValueError(f"{info.filename}: not its declared size")
        ok = True
    except BaseException:  # any failure: the parent reads the file itself
        ok = False
    finally:
        try:
            os.write(answer, b"1" if ok else b"0")
        finally:
            os._exit(0)


def take(path, found: list[tuple]) -> dict[str, memoryview] | None:
    """The members of the file ``path`` read ahead, by name, if the read ahead was of this file
    as it is now (its identity, and the zip directory ``found`` the reader checked), and the
    child inflated all of them; None otherwise (the reader then reads the file itself). Waits
    for the child where it is still at work. The read ahead is spent either way."""
    global _AHEAD
    ahead, _AHEAD = _AHEAD, None
    if ahead is None:
        return None
    try:
        answer = os.read(ahead.done, 1)
    except OSError:
        answer = b""
    finally:
        os.close(ahead.done)
        _reap(ahead.pid)
    try:
        same = (
            str(Path(path)) == ahead.path
            and _identity(os.stat(ahead.path)) == ahead.identity
            and found == ahead.directory
        )
    except OSError:
        same = False
    if answer != b"1" or not same:
        for m in ahead.maps:
            m.close()
        return None
    return {d[0]: memoryview(m) for d, m in zip(ahead.directory, ahead.maps, strict=True)}


def _reap(pid: int) -> None:
    try:
        os.waitpid(pid, 0)
    except ChildProcessError:
        pass
