"""A package's public names loaded from their modules on first use (PEP 562).

:func:`lazy_names` gives a package the module-level ``__getattr__`` and ``__dir__`` that import
a name's home module only when the name is first read, and keep the value in the package from
then on: a package whose modules import heavy libraries (torch, Mitsuba, numba) then costs
nothing to import until one of its names is used.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable

__all__ = ["lazy_names"]


def lazy_names(package: str, homes: dict[str, str]) -> tuple[Callable, Callable]:
    """``(__getattr__, __dir__)`` for the package named ``package`` whose public names live in
    the modules ``homes`` gives (``{name: ".module"}``, relative to the package)."""

    def __getattr__(name: str):
        if name not in homes:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(homes[name], package), name)
        setattr(sys.modules[package], name, value)
        return value

    def __dir__() -> list[str]:
        return sorted({*vars(sys.modules[package]), *homes})

    return __getattr__, __dir__
