"""This machine's memory, and the share of it a command or a renderer plans for: what the
command line's size limits (``lobelight.cli._limits``) and the renderers' own choices
(:func:`lobelight.render.auto_base_res`) are derived from; and glibc's heap functions, which
the command line and a bake call (:func:`glibc_function`). Imports no torch."""

from __future__ import annotations

import ctypes
import ctypes.util
import math
import os
import sys

__all__ = [
    "FALLBACK_MEMORY",
    "MEMORY_SHARE",
    "PREFILTER_BYTES_PER_TEXEL",
    "glibc_function",
    "max_base_res",
    "memory_bytes",
]

#: The share of the machine's memory a command plans for.
MEMORY_SHARE = 0.5
#: Bytes a texel of the sharpest prefiltered level takes while the chain is built (its six
#: faces counted one by one; the coarser levels and the working buffers included).
PREFILTER_BYTES_PER_TEXEL = 400
#: The memory assumed where the platform does not say (bytes).
FALLBACK_MEMORY = 8 << 30


def memory_bytes() -> int:
    """This machine's physical memory in bytes (``sysconf``), else :data:`FALLBACK_MEMORY`."""
    try:
        n = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):
        return FALLBACK_MEMORY
    return n if n > 0 else FALLBACK_MEMORY


def max_base_res() -> int:
    """The largest base resolution (a power of two, at least 2) whose prefiltered chain fits
    :data:`MEMORY_SHARE` of this machine's memory at :data:`PREFILTER_BYTES_PER_TEXEL`."""
    budget = MEMORY_SHARE * memory_bytes()
    return 1 << max(int(math.log2(math.sqrt(budget / (6 * PREFILTER_BYTES_PER_TEXEL)))), 1)


def glibc_function(name: str, argtypes: list, restype):
    """The C library's function ``name`` (glibc's heap settings and ``malloc_trim``) with its C
    signature, or None where this is not Linux or the C library lacks it (musl)."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        fn = getattr(ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6"), name)
    except (OSError, AttributeError):
        return None
    fn.argtypes, fn.restype = argtypes, restype
    return fn
