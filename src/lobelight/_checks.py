"""Argument checks at the public door, one helper per kind of check.

Each raises one :class:`~lobelight.errors.InputError` naming the input, the form it must have
and what came, so every function that takes an integer, a batch of directions or a cube map
refuses bad input in the same words. Checks specific to one concept (a BRDF's parameters, a
scene file's tables) stay with that concept.
"""

from __future__ import annotations

from typing import Any

import torch

from .errors import InputError

__all__ = ["check_cube", "check_directions", "check_int"]


def check_int(value: Any, name: str, *, minimum: int = 1) -> int:
    """``value`` as an ``int >= minimum``: Python's and numpy's integers, and integral floats.

    A bool is refused (``True`` is not a count); returns the value as a Python ``int``.
    """
    try:
        ok = not isinstance(value, bool) and int(value) == value and value >= minimum
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise InputError(name, f"must be an integer >= {minimum}, got {value!r}")
    return int(value)


def check_directions(x: torch.Tensor, name: str = "dirs") -> None:
    """Refuse anything but a ``(..., 3)`` tensor (directions or points on the last axis)."""
    if x.ndim < 1 or x.shape[-1] != 3:
        raise InputError(name, f"must be a (..., 3) array of directions, got {tuple(x.shape)}")


def check_cube(cube: torch.Tensor, name: str = "cube", *, power_of_two: bool = False) -> int:
    """Refuse anything but a ``(6, R, R, C)`` cube map; returns ``R``.

    power_of_two : also refuse a face resolution ``R`` that is not a power of two
    """
    if cube.ndim != 4 or cube.shape[0] != 6 or cube.shape[1] != cube.shape[2]:
        raise InputError(name, f"must be a (6, R, R, C) cube map, got shape {tuple(cube.shape)}")
    res = cube.shape[1]
    if power_of_two and (res < 1 or res & (res - 1)):
        raise InputError(name, f"face resolution must be a power of two, got {res}")
    return res
