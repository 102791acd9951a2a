"""Environment-map files: the cross and strip layouts of cube maps, and writing a map.

The layouts (``FILE_LAYOUTS``, :data:`CROSS_FACES`, :func:`cross_pixels`) are described with
reading in :mod:`lobelight.envmap._io`; :func:`save` writes a map whole (:mod:`lobelight._io`).
This module knows no :class:`~lobelight.envmap.EnvMap` type, only its ``data`` and ``layout``,
so that ``EnvMap.save`` can call it without an import circle.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import OpenEXR
import torch

from .._io import atomic_path
from ..data import MAP_SUFFIXES
from ..errors import InputError
from ..geometry import cubemap

__all__ = ["CROSS_FACES", "FILE_LAYOUTS", "cross_pixels", "save"]

FILE_LAYOUTS = ("latlong", "vcross", "hcross", "strip")
_EXTENSIONS = MAP_SUFFIXES
# Largest value a half float holds; larger radiance would be written as +Inf.
_HALF_MAX = 65504.0

# Per cross layout: GL face name -> (block row, block column, centre, right, down), with the
# block position in units of faces. Directions as in lobelight.envmap._io's module docstring.
_X, _Y, _Z = (1, 0, 0), (0, 1, 0), (0, 0, 1)


def _neg(v: tuple[int, int, int]) -> tuple[int, int, int]:
    return (-v[0], -v[1], -v[2])


_COMMON = {
    "+y": (0, 1, _Y, _X, _neg(_Z)),
    "-x": (1, 0, _neg(_X), _neg(_Z), _neg(_Y)),
    "-z": (1, 1, _neg(_Z), _X, _neg(_Y)),
    "+x": (1, 2, _X, _Z, _neg(_Y)),
    "-y": (2, 1, _neg(_Y), _X, _Z),
}
CROSS_FACES = {
    "vcross": {**_COMMON, "+z": (3, 1, _Z, _X, _Y)},
    "hcross": {**_COMMON, "+z": (1, 3, _Z, _neg(_X), _neg(_Y))},
}
# (rows, columns) of a layout's image in faces
_GRID = {"vcross": (4, 3), "hcross": (3, 4), "strip": (1, 6)}


def cross_pixels(kind: str, n: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Where each GL cube texel lies in a cross (or strip) image with faces of ``n`` pixels.

    Computed from directions: the centre of GL texel ``[f, i, j]``
    (:mod:`lobelight.geometry.cubemap`) is expressed in the coordinates ``(a, b)`` of the cross
    face of the same axis, which land exactly on a pixel centre.

    Returns
    -------
    rows, cols : (6, n, n) int64 pixel indices into the ``(H, W)`` image
    """
    rows = torch.empty(6, n, n, dtype=torch.long)
    cols = torch.empty(6, n, n, dtype=torch.long)
    if kind == "strip":
        i, j = torch.meshgrid(torch.arange(n), torch.arange(n), indexing="ij")
        for f in range(6):
            rows[f], cols[f] = i, j + f * n
        return rows, cols
    k = torch.arange(n, dtype=torch.float64)
    c = (2 * k + 1) / n - 1  # texel-centre face coordinates
    v, u = torch.meshgrid(c, c, indexing="ij")  # (n, n): rows follow v (= t), columns u (= s)
    for f, name in enumerate(cubemap.FACE_NAMES):
        brow, bcol, centre, right, down = (
            torch.tensor(x, dtype=torch.float64) if isinstance(x, tuple) else x
            for x in CROSS_FACES[kind][name]
        )
        # (n, n, 3) unnormalised directions of GL face f; their major component is exactly +-1
        p = cubemap.face_uv_to_direction(torch.full((n, n), f), u, v)
        # the cross face of the same axis as GL face f: p . centre == 1 on all of it
        assert bool(((p @ centre) == 1).all())
        a = p @ right  # (n, n) cross-face coordinates, exactly on pixel centres
        b = p @ down
        rows[f] = torch.round(((b + 1) * n - 1) / 2).long() + brow * n  # pixel whose centre is b
        cols[f] = torch.round(((a + 1) * n - 1) / 2).long() + bcol * n
    return rows, cols


# -- saving ----------------------------------------------------------------------------------


def save(env: Any, path: str | Path, *, cross: str = "vcross", half: bool = False) -> Path:
    """Write an environment map to ``path``, atomically; the format follows the extension.

    Parameters
    ----------
    env : the map (an :class:`~lobelight.envmap.EnvMap`: its ``data`` and ``layout``)
    path : ``.exr`` (float32, or half with ``half=True``; ZIP compression) or ``.hdr`` (RGBE
        RLE: 8-bit mantissas with a shared exponent, ~0.4 % of the largest channel)
    cross : how a cube map is laid out: ``"vcross"``, ``"hcross"`` or ``"strip"``
        (:mod:`lobelight.envmap._io`); lat-long maps are written as they are
    half : write half floats (EXR only); radiance above 65504 is refused

    Returns
    -------
    The path written.

    Raises
    ------
    InputError
        Unsupported extension, missing directory, half-float overflow, or a failed write.
    """
    p = Path(path)
    name = str(path)
    ext = p.suffix.lower()
    if ext not in _EXTENSIONS:
        raise InputError(name, f"unsupported file type {ext or '(no extension)'!r}: use .hdr, .exr")
    if half and ext != ".exr":
        raise InputError("half", "half floats are only for .exr files")
    if not p.parent.is_dir():
        raise InputError(name, f"the directory {str(p.parent)!r} does not exist")
    if p.is_dir():
        raise InputError(name, "is a directory")
    data = env.data.detach().cpu()
    if env.layout == "cubemap":
        if cross not in _GRID:
            raise InputError("cross", f"must be one of {tuple(_GRID)}, got {cross!r}")
        n = data.shape[1]
        gr, gc = _GRID[cross]
        rows, cols = cross_pixels(cross, n)
        img = torch.zeros(gr * n, gc * n, 3)
        img[rows, cols] = data
    else:
        img = data
    arr = np.ascontiguousarray(img.numpy(), dtype=np.float32)  # (H, W, 3)
    if half:
        peak = float(arr.max(initial=0.0))
        if peak > _HALF_MAX:
            raise InputError(
                name, f"radiance up to {peak:g} does not fit in half floats (max {_HALF_MAX:g})"
            )
        arr = arr.astype(np.float16)
    try:
        with atomic_path(p) as tmp:  # written by name (OpenEXR opens the file itself)
            if ext == ".hdr":
                ok, enc = cv2.imencode(".hdr", np.ascontiguousarray(arr[..., ::-1]))  # to BGR
                if not ok:
                    raise InputError(name, "OpenCV could not encode the image as RGBE")
                tmp.write_bytes(enc.tobytes())
            else:
                header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
                OpenEXR.File(header, {"RGB": arr}).write(str(tmp))
    except InputError:
        raise
    except Exception as e:
        raise InputError(name, f"cannot write the file ({e})") from e
    return p
