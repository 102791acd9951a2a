"""Data that ships with the package: small real HDR environment maps (CC0, see LICENSES.md).

:func:`envmap_path` resolves a bundled map by its stem (``"rooitou_park_512"``);
:func:`envmap_names` lists them.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["DEFAULT_ENVMAP", "envmap_names", "envmap_path"]

_ENVMAPS = Path(__file__).resolve().parent / "envmaps"

#: The bundled map the demo and the examples light with: a park under a clear sky with a small,
#: unclipped sun.
DEFAULT_ENVMAP = "rooitou_park_512"


def envmap_names() -> list[str]:
    """The stems of the bundled environment maps, sorted."""
    return sorted(p.stem for p in _ENVMAPS.glob("*.hdr"))


def envmap_path(name: str) -> Path | None:
    """The file of the bundled map ``name`` (its stem), or None when there is none by that name."""
    p = _ENVMAPS / f"{name}.hdr"
    return p if name and "/" not in name and p.is_file() else None
