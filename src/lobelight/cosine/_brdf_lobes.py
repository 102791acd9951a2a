"""Reflectance as cosine lobes: ``f_r(wi, wo) (n . wi)`` as a lobe sum in ``wi`` (paper 5.1).

For a fixed point and view, each supported model is a sum of cosine lobes in ``wi``; the model
says which (:meth:`lobelight.brdf.BRDF.cosine_lobes`, None for the others):

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

import torch

from .. import brdf as _brdf
from ..errors import InputError
from ._fused import kernel
from ._lobeset import Lobes, _multiply_flat
from ._tables import LobeTables

__all__ = ["brdf_lobes"]


def _lobe_flags(model: _brdf.BRDF) -> tuple[bool, ...]:
    """``model``'s :attr:`~lobelight.brdf.BRDF.cosine_lobe_flags`; InputError where it has none."""
    flags = model.cosine_lobe_flags
    if flags is None:
        raise InputError(
            "brdf",
            f"{type(model).__name__} is not a cosine-lobe model (such as Lambert, Phong, "
            "Lafortune and their sums)",
        )
    return flags


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
    model : a model with cosine lobes (Lambert, Phong, Lafortune or a Sum of them);
        parameters of shape () or per point (P,) / (P, 3) (spatially varying)
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
    _lobe_flags(model)
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
    and multiplies the factors in. (Stacking and multiplying here as well is slower:
    TorchInductor then computes the table lookups inside the (P, 3) loop of the
    scales, unvectorised.)
    """
    lobes = model.cosine_lobes(wo, normals, tangents)
    front = ((wo * normals).sum(-1) > 0).to(normals.dtype)  # (P,): the models are one-sided
    axes, exponents, factors, scales = [], [], [], []
    for axis, e, scale, cos in lobes:
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
