"""Image sizes as the command line takes them: ``N`` (square) or ``WxH``."""

from __future__ import annotations

import re

from ..errors import InputError

__all__ = ["MAX_PIXELS", "check_pixels", "parse_size"]

#: The largest width or height accepted (GL's usual maximum texture size).
MAX_PIXELS = 16384


def parse_size(text: str, what: str = "--size") -> tuple[int, int]:
    """``"N"`` as ``(N, N)``, ``"WxH"`` as ``(W, H)``; anything else is an error naming ``what``.
    The range is checked by :func:`check_pixels`."""
    m = re.fullmatch(r"(\d+)(?:[xX](\d+))?", str(text))
    if not m:
        raise InputError(what, f"expected N or WxH, got {text!r}")
    return int(m.group(1)), int(m.group(2) or m.group(1))


def check_pixels(what: str, value: int) -> int:
    """``value`` if it is a usable width or height, else an error naming ``what``."""
    if not 1 <= value <= MAX_PIXELS:
        raise InputError(what, f"must be 1..{MAX_PIXELS} pixels, got {value}")
    return value
