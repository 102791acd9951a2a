"""The ranges of the command line's numeric flags: each flag's type checks its value at parse
time (one line, exit 2, before any work) and its help states the range.

Sizes that cost memory have a maximum derived from this machine's memory
(:func:`lobelight._memory.memory_bytes`): a command plans for at most
:data:`~lobelight._memory.MEMORY_SHARE` of it, at the bytes per pixel
(:data:`RENDER_BYTES_PER_PIXEL`) and per texel of the sharpest prefiltered level
(:data:`~lobelight._memory.PREFILTER_BYTES_PER_TEXEL`) the renderers take at their peak (the
torch renderer, the larger of the two; ``docs/benchmarks.md``). The other counts are bounded by
what their types hold or by what can finish: a seed within 63 bits, exposures within float32's
range.

Building these imports no torch (the parser's rule).
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

from .._memory import MEMORY_SHARE, max_base_res, memory_bytes

__all__ = [
    "MAX_BASE_RES",
    "MAX_BOUNCES",
    "MAX_DEPTH",
    "MAX_EXPOSURE",
    "MAX_FRAMES",
    "MAX_INDIRECT_PATHS",
    "MAX_REFINE_ROUNDS",
    "MAX_RENDER_PIXELS",
    "MAX_REPEATS",
    "MAX_SAMPLES",
    "MAX_SEED",
    "MAX_SIDE",
    "MAX_SPP",
    "RENDER_BYTES_PER_PIXEL",
    "bounded_float",
    "bounded_int",
    "pixels_help",
]

#: Bytes a rendered pixel takes at the renderers' peak (4 samples per pixel, the default).
RENDER_BYTES_PER_PIXEL = 400


def _budget() -> float:
    return MEMORY_SHARE * memory_bytes()


#: The largest width or height (GL's usual maximum texture size).
MAX_SIDE = 16384
#: The most pixels one image may have (width x height) on this machine: its memory share at
#: :data:`RENDER_BYTES_PER_PIXEL`, and no more than a MAX_SIDE square.
MAX_RENDER_PIXELS = int(min(MAX_SIDE**2, _budget() // RENDER_BYTES_PER_PIXEL))
#: The largest ``--base-res`` (a power of two) whose chain fits this machine's memory share.
MAX_BASE_RES = max_base_res()
#: The most stops of ``--exposure`` either way: 2**64 times the brightest radiance a map may
#: hold stays within float32, and beyond it every pixel is black or white.
MAX_EXPOSURE = 64.0
#: Counts bounded by what can finish or what their types hold: bounces and indirect paths of a
#: bake (each multiplies its time), seeds (63 bits), samples per pixel (a float32 mean of more
#: adds nothing), timed repeats, a Mitsuba path's depth.
MAX_BOUNCES = 64
MAX_INDIRECT_PATHS = 4096
#: Rounds of a bake's mesh refinement (each may split a long edge once more; the refinement's
#: vertex budget bounds them all).
MAX_REFINE_ROUNDS = 8
MAX_SEED = 2**63 - 1
MAX_SPP = 1 << 20
MAX_SAMPLES = 256
MAX_REPEATS = 10_000
MAX_DEPTH = 1024
#: The most frames of an animation (a turntable, the lobes demo); their images are also
#: bounded together by the memory share.
MAX_FRAMES = 3600


def pixels_help() -> str:
    """The sentence the size flags' help ends with."""
    gb = memory_bytes() / 2**30
    return (
        f"1..{MAX_SIDE} each, width x height at most {MAX_RENDER_PIXELS / 1e6:.1f} megapixels "
        f"(about {RENDER_BYTES_PER_PIXEL} bytes a pixel within {MEMORY_SHARE:.0%} of this "
        f"machine's {gb:.0f} GB)"
    )


def bounded_int(lo: int, hi: int) -> Callable[[str], int]:
    """An argparse type: a whole number in ``lo..hi``, else one line naming the range."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"expected a whole number {lo}..{hi}, got {text[:40]!r}"
            ) from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"must be {lo}..{hi}, got {text[:40]}")
        return value

    parse.__name__ = "whole number"
    return parse


def base_res_type(text: str) -> int | str:
    """An argparse type: ``auto`` or a whole number 1..MAX_BASE_RES (a power of two, checked by
    the command)."""
    if text == "auto":
        return text
    try:
        return bounded_int(1, MAX_BASE_RES)(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(
            f"expected 'auto' or a whole number 1..{MAX_BASE_RES}, got {text[:40]!r}"
        ) from None


def bounded_float(lo: float, hi: float, *, lo_open: bool = False) -> Callable[[str], float]:
    """An argparse type: a number in ``[lo, hi]`` (``(lo, hi]`` with ``lo_open``); ``hi`` may
    be ``inf``, NaN never passes."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        ok = (lo < value if lo_open else lo <= value) and value <= hi
        if not ok:  # NaN too
            left = "(" if lo_open else "["
            raise argparse.ArgumentTypeError(
                f"must be a number in {left}{lo:g}, {hi:g}], got {text[:40]!r}"
            )
        return value

    parse.__name__ = "number"
    return parse
