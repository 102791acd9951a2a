"""Process-wide settings for a process that runs lobelight's heavy work.

They change the whole process, so the library never makes them itself: the command line
(:func:`lobelight.cli.main`, which owns its process) makes them at start, and a program that
embeds lobelight may call :func:`lobelight.cli.tune` once, early, for the same effect.

- :func:`keep_freed_memory`: a fit allocates and frees tensors of 16-32 MB hundreds of times per
  chunk; glibc serves such blocks with ``mmap`` and returns them with ``munmap``, so each
  allocation page-faults its memory in again. Kept in the heap, they are reused (a fit's system
  time mostly disappears: ``docs/benchmarks.md``). The cost: the process keeps its peak heap
  until it exits.
- :func:`short_openmp_spin`: a process that shades cosine lobes fused holds two OpenMP runtimes
  (torch's, and the system's ``libgomp`` that TorchInductor's kernels and numba load), each
  with a worker per core that spins after its parallel region; on few cores the spinning
  workers of one take the cores from the other. A short spin lets the system runtime's
  workers sleep sooner. It reads the setting when it loads, so this runs after torch is
  imported (torch's own runtime keeps its default) and before the first compiled kernel.

- :func:`imports_uncollected`: importing torch and the commands creates hundreds of thousands
  of objects, and the cyclic garbage collector, triggered by their count, walks all of them
  again and again (hundreds of collections, a sizeable part of a short command's start, most
  of it in full ones). Those objects are modules, functions and types that live as long as
  the process: the imports run with the collector off, and ``gc.freeze`` then moves what they
  made out of its reach, so later collections walk only what the command makes.

And one for a process that has done its work: :func:`end_process` ends it at once (the
interpreter's teardown of a process that imported torch, sympy and a GL driver is a sizeable
part of a short command's wall time), once everything that matters at exit has happened.
"""

from __future__ import annotations

import atexit
import contextlib
import ctypes
import functools
import gc
import os
import sys
import threading

from .._memory import glibc_function

__all__ = ["end_process", "imports_uncollected", "keep_freed_memory", "short_openmp_spin", "tune"]

# glibc's mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_TOP_PAD = -2
_M_MMAP_THRESHOLD = -3


@functools.cache
def keep_freed_memory() -> bool:
    """Serve blocks up to 32 MB (glibc's largest mmap threshold) from the heap and never trim it.

    Returns whether it took effect (glibc on Linux only; elsewhere a no-op). Process-wide and
    idempotent.
    """
    mallopt = glibc_function("mallopt", [ctypes.c_int, ctypes.c_int], ctypes.c_int)
    if mallopt is None:
        return False
    ok = mallopt(_M_MMAP_THRESHOLD, 32 * 1024 * 1024)
    ok &= mallopt(_M_TRIM_THRESHOLD, 2**31 - 1)
    ok &= mallopt(_M_TOP_PAD, 512 * 1024 * 1024)
    return bool(ok)


def short_openmp_spin() -> None:
    """Let idle OpenMP workers of runtimes loaded from now on sleep after 20,000 spins
    (``GOMP_SPINCOUNT``), unless the environment sets it."""
    os.environ.setdefault("GOMP_SPINCOUNT", "20000")


def tune() -> None:
    """Both settings above: for a process that bakes, fits and shades (the command line's)."""
    short_openmp_spin()
    keep_freed_memory()


@contextlib.contextmanager
def imports_uncollected():
    """Run the block (the imports of a process's start) with the cyclic garbage collector off,
    then freeze what exists (``gc.freeze``: later collections skip it) and restore the
    collector's state.

    Process-wide: objects alive at the end of the block are never collected, so a cycle made
    unreachable after it stays in memory. Use it only in a process that is the caller's own,
    around imports of modules that live as long as it does.
    """
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        if enabled:
            gc.enable()


def end_process(code: int) -> None:
    """End this process now with exit status ``code``, skipping the interpreter's teardown.

    First what a normal exit does that anyone can observe: the ``atexit`` handlers run
    (logging's shutdown, which flushes and closes its handlers; ``weakref.finalize``'s, which
    removes temporary folders; multiprocessing's, which joins its children; those of torch and
    PIL), then Python's stdout and stderr are flushed, and C's stdio buffers (``fflush``).
    Skipped, with ``os._exit``: the garbage collection and deallocation of every object and
    module (memory the kernel frees at once; no output file is open by then, every file being
    written whole and closed), and the C libraries' exit handlers and static destructors
    (torch's, the OpenMP runtimes', the GL driver's and LLVM's: they free memory and end
    threads, which the kernel does as well).

    Returns without ending where that would cut anything short: a thread other than the main
    one that is not a daemon still runs (the interpreter waits for it), the interpreter is to
    stay interactive (``python -i``), or stdout or stderr cannot be flushed (the normal exit
    reports it). Call it only where the process is the caller's, with nothing left to do.
    """
    main = threading.main_thread()
    if threading.current_thread() is not main or sys.flags.inspect:
        return
    if any(t is not main and t.is_alive() and not t.daemon for t in threading.enumerate()):
        return
    atexit._run_exitfuncs()  # each handler once: the list is empty after this
    try:
        for stream in (sys.stdout, sys.stderr):
            if stream is not None:
                stream.flush()
    except (OSError, ValueError):  # a closed stream or a reader gone: the normal exit's case
        return
    _flush_c_stdio()
    os._exit(code)


def _flush_c_stdio() -> None:
    """``fflush(NULL)``: what C code printed into its stdio buffers (a normal exit flushes
    them); nothing where the C library cannot be loaded."""
    try:
        libc = ctypes.CDLL(None)
        libc.fflush(None)
    except (OSError, AttributeError, TypeError):  # TypeError: no CDLL(None) on Windows
        pass
