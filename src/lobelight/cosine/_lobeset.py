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

from ._fused import kernel
from ._lobe import _axis_pair
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
    :class:`Lobes` of the broadcast batch shape; ``scale = p_r * scale_a * scale_b``
    """
    a1, a2, e1, e2 = _flat_pairs(a, b)
    batch = a1.shape[:-1]
    axis, exponent, unit = _multiply_flat(
        a1.reshape(-1, 3), a2.reshape(-1, 3), e1.reshape(-1), e2.reshape(-1),
        tables.product_table, tables._grid, bool(preserve_integral),
    )  # fmt: skip
    scale = unit.reshape(batch).unsqueeze(-1) * a.scale * b.scale  # (..., C)
    return Lobes(axis.reshape(*batch, 3), exponent.reshape(batch), scale)


def product_integral(tables: LobeTables, a: Lobes, b: Lobes, *, preserve_integral: bool):
    """``∫ a b`` by the table, without building the product lobe's axis: ``(..., C)``."""
    a1, a2, e1, e2 = _flat_pairs(a, b)
    batch = a1.shape[:-1]
    unit = _integral_flat(
        a1.reshape(-1, 3), a2.reshape(-1, 3), e1.reshape(-1), e2.reshape(-1),
        tables.product_table, tables._grid, bool(preserve_integral),
    )  # fmt: skip
    return unit.reshape(batch).unsqueeze(-1) * a.scale * b.scale


def _flat_pairs(a: Lobes, b: Lobes):
    """Axes (..., 3) and exponents (...) of both, broadcast to one batch and contiguous.

    The fused kernels take flat, dense lists: a compiled loop over broadcast (stride-0) views
    was measured 3x slower than the copy this makes.
    """
    a1, a2 = torch.broadcast_tensors(a.axis, b.axis)
    batch = a1.shape[:-1]
    e1, e2 = a.exponent.expand(batch), b.exponent.expand(batch)
    return a1.contiguous(), a2.contiguous(), e1.contiguous(), e2.contiguous()


@kernel
def _multiply_flat(a1, a2, e1, e2, tab, grid, preserve: bool):
    """(M, 3) axes, (M,) exponents -> product axis (M, 3), exponent (M,), unit scale (M,)."""
    c, s, tangent = _axis_pair(a1, a2)
    cb, sb, exponent, log_scale = _product_lookup(e1, e2, c, s, tab, grid, preserve)
    axis = cb.unsqueeze(-1) * a1 + sb.unsqueeze(-1) * tangent
    return axis, exponent, torch.exp(log_scale)


@kernel
def _integral_flat(a1, a2, e1, e2, tab, grid, preserve: bool):
    """(M, 3) axes, (M,) exponents -> ``∫ c1 c2`` of unit-scale lobes, (M,)."""
    c = (a1 * a2).sum(-1).clamp(-1, 1)
    # |a1 x a2| keeps sin(alpha) accurate for nearly parallel axes (sqrt(1 - c^2) does not)
    s = torch.linalg.vector_norm(torch.linalg.cross(a1, a2, dim=-1), dim=-1)
    _, _, exponent, log_scale = _product_lookup(e1, e2, c, s, tab, grid, preserve)
    return torch.exp(log_scale) * (_TWO_PI / (exponent + 1))
