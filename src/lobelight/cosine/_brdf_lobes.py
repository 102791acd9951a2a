"""Reflectance as cosine lobes: ``f_r(wi, wo) (n . wi)`` as a lobe sum in ``wi`` (paper 5.1).

For a fixed point and view, each supported model is a sum of cosine lobes in ``wi``:

``Lambert(albedo)``
    ``albedo / pi * max(n . wi, 0)^1``: already ``f_r`` times the cosine, one exact lobe.
``Phong(ks, e)`` (lobelight's modified Phong)
    ``ks (e + 2) / (2 pi) max(r . wi, 0)^e`` about the mirror direction ``r`` of ``wo``.
``Lafortune(lobes)``
    lobe ``j`` is ``rho_j max(d_j . wi, 0)^(e_j)`` with the non-unit local vector
    ``d_j = (cx wo_x, cy wo_y, cz wo_z)`` (paper eq. 30): unit axis ``d_j / |d_j|`` and scale
    ``rho_j |d_j|^(e_j)`` (:func:`~._lobe.from_vector`).
``Sum(...)`` of these
    the concatenation of its components' lobes.

The paper writes the specular lobes without the cosine factor ``n . wi`` (its eq. 24-27). That
factor is not 1 over a glossy lobe away from the normal, and leaving it out is a bias that the
Monte Carlo comparison would show, so here every lobe that is not already the cosine lobe is
multiplied by the cosine lobe ``max(n . wi, 0)^1`` through the product table (one lookup per
lobe and point; the product lobe also vanishes below the horizon, as ``f_r cos`` does).
``cosine="axis"`` instead multiplies the lobe's scale by ``max(n . axis, 0)`` (free, exact in
the sharp limit); ``cosine="none"`` is the paper's form.
"""

from __future__ import annotations

import math

import torch

from .. import brdf as _brdf
from ..errors import InputError
from ._fused import kernel
from ._lobeset import Lobes, _multiply_flat
from ._tables import LobeTables

__all__ = ["brdf_lobes"]

_PI = math.pi


def _rgb(x: torch.Tensor, batch: tuple[int, ...]) -> torch.Tensor:
    """A () / (3,) / (..., 3) colour as (*batch, 3)."""
    if x.ndim == 0:
        x = x.expand(3)
    return x.expand(*batch, 3)


def _scalar(x: torch.Tensor, batch: tuple[int, ...]) -> torch.Tensor:
    return x.expand(batch)


def _raw_lobes(model: _brdf.BRDF, fr, wo_local: torch.Tensor) -> tuple[list, list]:
    """Per component: lists of (axis (P, 3), exponent (P,), scale (P, 3)) and "is cosine" flags."""
    batch = wo_local.shape[:-1]
    like = wo_local
    if isinstance(model, _brdf.Sum):
        lobes, flags = [], []
        for comp in model.components:
            lo, fl = _raw_lobes(comp, fr, wo_local)
            lobes += lo
            flags += fl
        return lobes, flags
    if isinstance(model, _brdf.Lambert):
        albedo = _rgb(model._get("albedo", like), batch)
        return [
            (
                fr.n.expand(*batch, 3),
                torch.ones(batch, dtype=like.dtype, device=like.device),
                albedo / _PI,
            )
        ], [True]
    if isinstance(model, _brdf.Phong):
        e = _scalar(model._get("exponent", like), batch)
        ks = _rgb(model._get("specular", like), batch)
        r_local = wo_local * torch.tensor([-1.0, -1.0, 1.0], dtype=like.dtype, device=like.device)
        axis = fr.world(r_local)
        return [(axis, e, ks * ((e + 2) / (2 * _PI)).unsqueeze(-1))], [False]
    if isinstance(model, _brdf.Lafortune):
        out = []
        for j in range(model.n_lobes):
            cx, cy, cz, e, rho = model._lobe(j, like)
            d = torch.stack(
                torch.broadcast_tensors(
                    cx * wo_local[..., 0], cy * wo_local[..., 1], cz * wo_local[..., 2]
                ),
                -1,
            )
            norm = torch.linalg.vector_norm(d, dim=-1)
            tiny = torch.finfo(norm.dtype).tiny
            axis = fr.world(d / norm.clamp_min(tiny).unsqueeze(-1))
            e = _scalar(e, batch)
            # |d|^e, and 0 for a vanishing vector (the lobe is 0 everywhere)
            mag = torch.where(norm > 0, torch.exp(e * torch.log(norm.clamp_min(tiny))), 0.0)
            out.append((axis, e, _rgb(rho, batch) * mag.unsqueeze(-1)))
        return out, [False] * len(out)
    raise InputError(
        "brdf", f"{type(model).__name__} is not a cosine-lobe model (Lambert, Phong, Lafortune)"
    )


def brdf_lobes(
    model: _brdf.BRDF,
    normals: torch.Tensor,
    wo: torch.Tensor,
    *,
    tables: LobeTables,
    tangents: torch.Tensor | None = None,
    cosine: str = "product",
    preserve_integral: bool = True,
) -> Lobes:
    """``f_r(., wo) (n . .)`` of each point as a lobe sum.

    Parameters
    ----------
    model : Lambert, Phong, Lafortune or a Sum of them; parameters of shape () or per point
        (P,) / (P, 3) (spatially varying)
    normals, wo : (P, 3) unit shading normals and directions towards the viewer
    tables : the lobe tables (for the cosine products)
    tangents : optional (P, 3) (the local x axis of anisotropic Lafortune lobes)
    cosine : "product" (default, see module docstring), "axis" or "none" (the paper's)
    preserve_integral : the cosine products keep their exact integral (else the L2 fit)

    Returns
    -------
    :class:`~._lobeset.Lobes` with axis (P, I, 3), exponent (P, I), scale (P, I, 3); where
    ``n . wo <= 0`` the scales are 0 (the models are one-sided)
    """
    if cosine not in ("product", "axis", "none"):
        raise InputError("cosine", f"must be 'product', 'axis' or 'none', got {cosine!r}")
    axes, exponents, factors, scales = _lobe_parts(
        model, normals, wo, tangents, tables.product_table, tables._grid, cosine,
        bool(preserve_integral),
    )  # fmt: skip
    scale = torch.stack(scales, -2) * torch.stack(factors, -1).unsqueeze(-1)
    return Lobes(torch.stack(axes, -2), torch.stack(exponents, -1), scale)


@kernel
def _lobe_parts(model: _brdf.BRDF, normals, wo, tangents, tab, grid, cosine: str, preserve: bool):
    """:func:`brdf_lobes`'s lobes, one kernel: each lobe that is not already the cosine is
    multiplied by it where it is made (no gather and scatter of the lobes that need it).

    Returns per lobe: axes (P, 3), exponents (P,), factors (P,) (the cosine product's scale
    times the one-sided mask) and the model's scales (P, 3), as lists; the caller stacks them
    and multiplies the factors in. (Stacking and multiplying here as well was measured ~1.2x
    slower: TorchInductor then computes the table lookups inside the (P, 3) loop of the
    scales, unvectorised.)
    """
    fr = _brdf._Frame(normals, tangents)
    wo_local = fr.local(wo)
    raw, is_cos = _raw_lobes(model, fr, wo_local)
    front = (wo_local[..., 2] > 0).to(normals.dtype)  # (P,): the models are one-sided
    axes, exponents, factors, scales = [], [], [], []
    for (axis, e, scale), cos in zip(raw, is_cos, strict=True):
        factor = front
        if not cos and cosine == "product":  # times max(n . wi, 0)^1, by the table
            ones = torch.ones_like(e)
            prod, e, unit = _multiply_flat(axis.T, normals.T, e, ones, tab, grid, preserve)
            axis, factor = prod.T, front * unit
        elif not cos and cosine == "axis":
            factor = front * (axis * normals).sum(-1).clamp_min(0)
        axes.append(axis)
        exponents.append(e.to(normals.dtype))
        factors.append(factor)
        scales.append(scale.to(normals.dtype))
    return axes, exponents, factors, scales
