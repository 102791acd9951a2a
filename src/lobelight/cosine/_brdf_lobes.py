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
from ._lobeset import Lobes, multiply
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
    axis, exponent, scale, front, is_cos = _raw_stack(model, normals, wo, tangents)
    need = [i for i, c in enumerate(is_cos) if not c]
    if need and cosine != "none":
        some = len(need) < len(is_cos)  # else every lobe needs the cosine: no gather, no scatter
        if some:
            ix = torch.tensor(need, device=axis.device)
            sub = Lobes(axis[:, ix], exponent[:, ix], scale[:, ix])
        else:
            sub = Lobes(axis, exponent, scale)
        if cosine == "product":
            ones = torch.ones_like(exponent[:, :1])
            cos_lobe = Lobes(normals.unsqueeze(1), ones, torch.ones_like(scale[:, :1, :1]))
            sub = multiply(tables, sub, cos_lobe, preserve_integral=preserve_integral)
        else:
            c = (sub.axis * normals.unsqueeze(1)).sum(-1).clamp_min(0)  # (P, n)
            sub = Lobes(sub.axis, sub.exponent, sub.scale * c.unsqueeze(-1))
        if some:  # put the products back in their places
            axis = axis.index_copy(1, ix, sub.axis)
            exponent = exponent.index_copy(1, ix, sub.exponent)
            scale = scale.index_copy(1, ix, sub.scale)
        else:
            axis, exponent, scale = sub
    return Lobes(axis, exponent, scale * front)


@kernel
def _raw_stack(model: _brdf.BRDF, normals, wo, tangents):
    """The model's lobes before the cosine: axis (P, I, 3), exponent (P, I), scale (P, I, 3),
    the one-sided mask (P, 1, 1) and which lobes are already cosines (a tuple of I bools)."""
    fr = _brdf._Frame(normals, tangents)
    wo_local = fr.local(wo)
    raw, is_cos = _raw_lobes(model, fr, wo_local)
    axis = torch.stack([r[0] for r in raw], -2)  # (P, I, 3)
    exponent = torch.stack([r[1] for r in raw], -1)  # (P, I)
    scale = torch.stack([r[2] for r in raw], -2).to(axis.dtype)  # (P, I, 3)
    front = (wo_local[..., 2] > 0).to(scale.dtype)[:, None, None]  # (P, 1, 1)
    return axis, exponent, scale, front, tuple(is_cos)
