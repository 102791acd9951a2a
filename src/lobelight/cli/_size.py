"""Image sizes as the command line takes them: ``N`` (square) or ``WxH``, within this machine's
memory (:data:`lobelight.cli._limits.MAX_RENDER_PIXELS`)."""

from __future__ import annotations

import re

from .._memory import MEMORY_SHARE, memory_bytes
from ..errors import InputError
from ._limits import MAX_RENDER_PIXELS, MAX_SIDE, pixels_help

__all__ = ["MAX_PIXELS", "check_frames", "check_image", "check_pixels", "parse_size"]

#: The largest width or height accepted (GL's usual maximum texture size).
MAX_PIXELS = MAX_SIDE


def parse_size(text: str, what: str = "--size") -> tuple[int, int]:
    """``"N"`` as ``(N, N)``, ``"WxH"`` as ``(W, H)``; anything else is an error naming ``what``.
    The range is checked by :func:`check_pixels`."""
    m = re.fullmatch(r"(\d{1,9})(?:[xX](\d{1,9}))?", str(text))
    if not m:
        raise InputError(what, f"expected N or WxH (whole numbers), got {str(text)[:40]!r}")
    return int(m.group(1)), int(m.group(2) or m.group(1))


def check_pixels(what: str, value: int) -> int:
    """``value`` if it is a usable width or height, else an error naming ``what``."""
    if not 1 <= value <= MAX_PIXELS:
        raise InputError(what, f"must be 1..{MAX_PIXELS} pixels, got {value}")
    return value


def check_image(what: str, width: int, height: int) -> tuple[int, int]:
    """``(width, height)`` if each side is usable (:func:`check_pixels`) and the image fits this
    machine's memory share, else one error naming ``what``."""
    check_pixels(what, width)
    check_pixels(what, height)
    if width * height > MAX_RENDER_PIXELS:
        raise InputError(
            what, f"{width}x{height} pixels is too large for this machine: {pixels_help()}"
        )
    return width, height


def check_frames(what: str, frames: int, width: int, height: int) -> int:
    """``frames`` if that many frames of ``width x height`` (kept together, 4 bytes a pixel, for
    the animation) fit this machine's memory share, else one error naming ``what``."""
    need = 4 * frames * width * height
    if need > MEMORY_SHARE * memory_bytes():
        raise InputError(
            what,
            f"{frames} frames of {width}x{height} take {need / 2**30:.1f} GB together, more than "
            f"{MEMORY_SHARE:.0%} of this machine's {memory_bytes() / 2**30:.0f} GB: fewer frames "
            "or a smaller --size",
        )
    return frames
