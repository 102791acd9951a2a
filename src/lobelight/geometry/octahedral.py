"""The octahedral map: the sphere of directions on one square, ``[-1, 1]^2``.

A direction ``d`` goes to ``(x, y) / (|x| + |y| + |z|)`` on the upper half (``z >= 0``); the
lower half's triangles fold out over the square's corners. The map is continuous across the
square's inside, nearly equal-area (texel solid angles within a factor of about two of each
other), and one texture tile per vertex holds a function of direction with plain 2D
filtering, which a cube map per vertex would not (seams between faces, six tiles). The shaders
use the same formulas (``render/shaders/reflection.glsl``).

Texel ``(row, col)`` of a ``res x res`` tile covers ``x`` in ``[-1 + 2 col / res,
-1 + 2 (col + 1) / res]`` and ``y`` likewise with the row.
"""

from __future__ import annotations

import torch

__all__ = ["bilinear", "decode", "encode", "footprint", "nearest_texel", "texel_directions"]


def _fold(p: torch.Tensor) -> torch.Tensor:
    """The lower half's fold: ``(1 - |p.yx|) sign(p)`` (sign of 0 taken as +)."""
    sign = torch.where(p >= 0, torch.ones_like(p), -torch.ones_like(p))
    return (1 - p.flip(-1).abs()) * sign


def encode(dirs: torch.Tensor) -> torch.Tensor:
    """Unit directions ``(..., 3)`` to points ``(..., 2)`` of ``[-1, 1]^2``."""
    p = dirs[..., :2] / dirs.abs().sum(-1, keepdim=True)
    return torch.where(dirs[..., 2:3] < 0, _fold(p), p)


def decode(points: torch.Tensor) -> torch.Tensor:
    """Points ``(..., 2)`` of ``[-1, 1]^2`` to unit directions ``(..., 3)``."""
    z = 1 - points.abs().sum(-1, keepdim=True)
    xy = torch.where(z < 0, _fold(points), points)
    return torch.nn.functional.normalize(torch.cat([xy, z], -1), dim=-1)


def texel_directions(res: int, *, sub: int = 1, device=None) -> torch.Tensor:
    """Directions at ``sub x sub`` stratified points of each texel of a ``res x res`` tile:
    ``(res, res, sub * sub, 3)`` (row, column, sample)."""
    n = res * sub
    g = (torch.arange(n, device=device, dtype=torch.float32) + 0.5) / n * 2 - 1
    y, x = torch.meshgrid(g, g, indexing="ij")  # (n, n): rows run along y
    d = decode(torch.stack([x, y], -1))  # (n, n, 3)
    return d.reshape(res, sub, res, sub, 3).permute(0, 2, 1, 3, 4).reshape(res, res, sub * sub, 3)


def nearest_texel(dirs: torch.Tensor, res: int) -> torch.Tensor:
    """The flat index ``row * res + column`` of the ``res x res`` tile's texel holding each unit
    direction ``(..., 3)``: ``(...)`` int64."""
    p = encode(dirs)
    ij = ((p + 1) * (0.5 * res)).floor().long().clamp(0, res - 1)  # (..., 2): column, row
    return ij[..., 1] * res + ij[..., 0]


def footprint(dirs: torch.Tensor, res: int) -> tuple[torch.Tensor, ...]:
    """The bilinear footprint of directions ``dirs (..., 3)`` in a tile of ``res``² texels,
    clamped to the tile: its first texel's column and row ``x0, y0 (...)`` int64 (the other
    three are one to the right, below, and both) and the weights ``fx, fy (...)`` of the
    second column and row."""
    p = encode(dirs)
    x = ((p[..., 0] + 1) * (res / 2) - 0.5).clamp(0, res - 1)
    y = ((p[..., 1] + 1) * (res / 2) - 0.5).clamp(0, res - 1)
    x0 = x.floor().long().clamp(max=res - 2)
    y0 = y.floor().long().clamp(max=res - 2)
    return x0, y0, x - x0, y - y0


def bilinear(
    tiles: torch.Tensor, index: torch.Tensor, dirs: torch.Tensor, value=None
) -> torch.Tensor:
    """Bilinear lookup of per-element tiles along directions, clamped at the tile's edge.

    Parameters
    ----------
    tiles : (V, R, R) values per texel;  index : (...) int64 tile of each lookup;
    dirs : (..., 3) unit directions;  value : None, or a function of the gathered texels
        (e.g. a test on them) whose float result is interpolated instead of the texels

    Returns
    -------
    (...) float32
    """
    x0, y0, fx, fy = footprint(dirs, tiles.shape[-1])

    def at(dy: int, dx: int) -> torch.Tensor:
        # gather, then convert: the tiles stay in their own (e.g. uint8) storage
        t = tiles[index, y0 + dy, x0 + dx]
        return (t if value is None else value(t)).float()

    top = at(0, 0) * (1 - fx) + at(0, 1) * fx
    bottom = at(1, 0) * (1 - fx) + at(1, 1) * fx
    return top * (1 - fy) + bottom * fy
