"""Data that ships with the package: small real HDR environment maps (CC0, see LICENSES.md).

:func:`envmap_path` resolves a bundled map by its stem (``"rooitou_park_512"``);
:func:`envmap_names` lists them; :func:`resolve_envmap` is the one rule for a name a user gives
(``"builtin"``, a file, or a bundled map's stem).
"""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError

__all__ = [
    "DATA_ENV",
    "DEFAULT_ENVMAP",
    "MAP_SUFFIXES",
    "envmap_names",
    "envmap_path",
    "resolve_envmap",
]

#: The environment map files lobelight reads (and writes): Radiance RGBE and OpenEXR.
MAP_SUFFIXES = (".hdr", ".exr")

_ENVMAPS = Path(__file__).resolve().parent / "envmaps"

#: The environment variable naming a folder of larger data (``meshes/``, ``envmaps/``) that does
#: not ship with the package: the gallery's scenes, compare-brdf's default map.
DATA_ENV = "LOBELIGHT_DATA"

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


def resolve_envmap(source: str, *, relative_to: str | Path | None = None) -> str | None:
    """The environment a user names: ``"builtin"`` as it is; a file (relative to the folder
    ``relative_to``, else the working directory) when one exists; else the bundled map with that
    stem; None when it is none of these. A file that is not a map (by its suffix) is passed
    over for a bundled map of that name, else an :class:`InputError`."""
    if source == "builtin":
        return source
    path = Path(relative_to) / source if relative_to is not None else Path(source)
    bundled = envmap_path(source)
    if path.is_file() and (path.suffix.lower() in MAP_SUFFIXES or bundled is None):
        if path.suffix.lower() not in MAP_SUFFIXES:
            problem = f"is not an environment map (lobelight reads {', '.join(MAP_SUFFIXES)})"
            raise InputError(source, problem)
        return str(path.resolve() if relative_to is not None else path)
    return str(bundled) if bundled is not None else None
