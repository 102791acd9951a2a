"""Sums of cosine lobes per shaded point, and their products through the product table.

A :class:`Lobes` holds ``K`` lobes for each of ``P`` points (or any leading batch):
``sum_k scale_k max(axis_k . w, 0)^(exponent_k)`` with an RGB ``scale`` (a BRDF's albedo, a
light's radiance) so that one table lookup serves all colour channels. Products of two lobes go
through the fused table lookup directly (this module is the shading
hot path: no input checks beyond the public doors, no numpy dispatch).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch

from ..geometry.sphere import frame
from ._fused import kernel
from ._tables import LobeTables, _product_lookup

__all__ = ["Lobes"]

_TWO_PI = 2 * math.pi


class Lobes(NamedTuple):
    """Cosine lobes ``scale * max(axis . w, 0)^exponent``.

    Attributes
    ----------
    axis : (..., 3) unit axes
    exponent : (...) >= 0
    scale : (..., C) colour scales (C = 1 or 3)
    """

    axis: torch.Tensor
    exponent: torch.Tensor
    scale: torch.Tensor

    def integral(self) -> torch.Tensor:
        """``(..., C)`` integrals over the sphere, ``2 pi scale / (e + 1)`` (exact)."""
        return (_TWO_PI / (self.exponent + 1)).unsqueeze(-1) * self.scale

    def cat(self, other: Lobes, dim: int = -1) -> Lobes:
        """Concatenate along the lobe dimension ``dim`` (of the ``(...)`` batch)."""
        d = dim if dim >= 0 else dim - 1  # the axis and scale tensors have one more dimension
        return Lobes(
            torch.cat([self.axis, other.axis], d),
            torch.cat([self.exponent, other.exponent], dim),
            torch.cat([self.scale, other.scale], d),
        )


def multiply(tables: LobeTables, a: Lobes, b: Lobes, *, preserve_integral: bool) -> Lobes:
    """The product lobe of ``a`` and ``b`` (broadcast), one table lookup per pair.

    Parameters
    ----------
    a, b : :class:`Lobes` with broadcastable batch shapes
    preserve_integral : scale the product lobe to the exact ``∫ c1 c2`` (tabulated) instead
        of the paper's L2-best scale

    Returns
    -------
    :class:`Lobes` of the broadcast batch shape; ``scale = p_r * scale_a * scale_b`` (the axes
    are a view of component rows, ``(3, ...)`` moved last)
    """
    a1, a2, e1, e2, batch = _flat_pairs(a, b)
    axis, exponent, unit = _multiply_flat(
        a1, a2, e1, e2, tables.product_table, tables._grid, bool(preserve_integral)
    )
    scale = unit.reshape(batch).unsqueeze(-1) * a.scale * b.scale  # (..., C)
    return Lobes(axis.reshape(3, *batch).movedim(0, -1), exponent.reshape(batch), scale)


def product_integral(tables: LobeTables, a: Lobes, b: Lobes, *, preserve_integral: bool):
    """``∫ a b`` by the table, without building the product lobe's axis: ``(..., C)``."""
    a1, a2, e1, e2, batch = _flat_pairs(a, b)
    unit = _integral_flat(
        a1, a2, e1, e2, tables.product_table, tables._grid, bool(preserve_integral)
    )
    return unit.reshape(batch).unsqueeze(-1) * a.scale * b.scale


def _flat_pairs(a: Lobes, b: Lobes):
    """Both lobes' axes as (3, M) component rows and exponents (M,), broadcast to one batch of
    ``M`` pairs, contiguous; and the batch shape.

    The fused kernels take flat, dense lists: a compiled loop over broadcast (stride-0) views
    is slower than the copy this makes, and one over (M, 3) rows (stride 3) is not vectorised
    by TorchInductor (docs/cosine-lobes.md, "Speed: kernel fusion").
    """
    a1, a2 = torch.broadcast_tensors(a.axis, b.axis)
    batch = a1.shape[:-1]
    e1, e2 = a.exponent.expand(batch), b.exponent.expand(batch)
    rows = [x.movedim(-1, 0).reshape(3, -1).contiguous() for x in (a1, a2)]
    return rows[0], rows[1], e1.reshape(-1).contiguous(), e2.reshape(-1).contiguous(), batch


@kernel
def _multiply_flat(a1, a2, e1, e2, tab, grid, preserve: bool):
    """(3, M) axes (component rows), (M,) exponents -> product axis (3, M), exponent (M,),
    unit scale (M,)."""
    c = (a1 * a2).sum(0)
    perp = a2 - c * a1  # (3, M) a2's part orthogonal to a1
    s = torch.sqrt((perp * perp).sum(0))
    # parallel or opposite axes: any tangent will do (beta is 0, or the product is zero)
    fallback = frame(a1.T)[0].T  # (3, M)
    tiny = torch.finfo(s.dtype).tiny
    tangent = torch.where(s > tiny, perp / s.clamp_min(tiny), fallback)
    cb, sb, exponent, log_scale = _product_lookup(e1, e2, c.clamp(-1, 1), s, tab, grid, preserve)
    return cb * a1 + sb * tangent, exponent, torch.exp(log_scale)


@kernel
def _integral_flat(a1, a2, e1, e2, tab, grid, preserve: bool):
    """(3, M) axes (component rows), (M,) exponents -> ``∫ c1 c2`` of unit-scale lobes, (M,)."""
    x1, y1, z1 = a1.unbind(0)
    x2, y2, z2 = a2.unbind(0)
    c = (x1 * x2 + y1 * y2 + z1 * z2).clamp(-1, 1)
    # |a1 x a2| keeps sin(alpha) accurate for nearly parallel axes (sqrt(1 - c^2) does not)
    cx, cy, cz = y1 * z2 - z1 * y2, z1 * x2 - x1 * z2, x1 * y2 - y1 * x2
    s = torch.sqrt(cx * cx + cy * cy + cz * cz)
    _, _, exponent, log_scale = _product_lookup(e1, e2, c, s, tab, grid, preserve)
    return torch.exp(log_scale) * (_TWO_PI / (exponent + 1))
