"""Direct lighting of a set of points with cosine lobes (paper sections 4.3 and 5.4).

Per point, reflectance ``f_r cos`` (lobes ``i``, :mod:`._brdf_lobes`), lighting (one cap lobe
per spherical light ``j``, :mod:`._light`) and visibility (``1 - sum_k w_k c_k`` per light,
:mod:`._visibility`) are lobe sums. The rendering equation is expanded in the paper's order
(its 5.4): reflectance x lighting first, ``m_ij = f_i L_j`` (one table product each), then each
product that survives the threshold by the light's shadow lobes::

    L_o = sum_ij [ ∫ m_ij - sum_k w_k ∫ m_ij c_k ]

A product whose integral (largest colour channel) is below the threshold ``t`` is dropped from
the sum, and a dropped ``m_ij`` is not multiplied further (the paper's culling, its 4.3). The
result is clamped at 0 (a lobe sum can overshoot a shadow's darkness a little). The number of
table products each point needed is returned too (the paper's Figure 16 false colours).

Points are processed in chunks (bounded memory); nothing loops over points, lobes or leaves.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass
from typing import Any

import torch

from .. import brdf as _brdf
from ..errors import InputError
from ._brdf_lobes import _lobe_flags, _lobe_parts, brdf_lobes
from ._calibration import default_weights
from ._fused import fusion, kernel
from ._light import SphereLight, _geometry, _light_tensors, cap_lobes, cap_scale
from ._lobeset import Lobes, _integral_flat, multiply
from ._tables import LobeTables, _cap_lookup, cpu_threads, get_tables
from ._visibility import (
    MASK_MODES,
    _check_spheres,
    depth_weights,
    interp_coefficients,
    shadow_leaves,
)

__all__ = ["ShadeResult", "shade_points", "shadow_features"]


@dataclass
class ShadeResult:
    """Output of :func:`shade_points`.

    Attributes
    ----------
    radiance : (P, 3) outgoing radiance towards ``wo``
    products : (P,) int64 table products computed per point (cosine, lighting, visibility)
    leaves : (P,) int64 shadow leaves per point (all lights)
    """

    radiance: torch.Tensor
    products: torch.Tensor
    leaves: torch.Tensor


def _check_points(name: str, x: torch.Tensor, P: int | None = None) -> None:
    if x.ndim != 2 or x.shape[-1] != 3 or (P is not None and x.shape[0] != P):
        want = f"({P}, 3)" if P is not None else "(P, 3)"
        raise InputError(name, f"must be {want}, got {tuple(x.shape)}")
    # NaN and Inf propagate through min and max: two reductions, no (P, 3) temporaries
    if x.numel() and not bool(torch.isfinite(torch.stack([x.amin(), x.amax()])).all()):
        raise InputError(name, "must be finite (NaN or Inf found)")


def shade_points(
    points: Any,
    normals: Any,
    wo: Any,
    brdf: _brdf.BRDF,
    lights: SphereLight | list[SphereLight],
    *,
    spheres: Any = None,
    exclude: Any = None,
    depth: int = 5,
    mode: str = "aggressive",
    threshold: float = 1e-3,
    margin: float = 1.0,
    weights: torch.Tensor | None = None,
    cosine: str = "product",
    preserve_integral: bool = True,
    tables: LobeTables | None = None,
    chunk: int | None = None,
    threads: int | None = None,
    fused: bool | None = None,
    device: Any = None,
) -> ShadeResult:
    """Outgoing direct radiance of ``P`` points lit by spherical lights, shadowed by spheres.

    Parameters
    ----------
    points, normals, wo : (P, 3) positions, unit shading normals, unit directions to the viewer
    brdf : Lambert, Phong, Lafortune or a Sum of them; per-point parameters (P,) / (P, 3)
    lights : one :class:`~._light.SphereLight` or a list
    spheres : optional (N, 4) occluder spheres ``(x, y, z, radius)`` (e.g. :func:`sphere_set`)
    exclude : optional (P,) int64 sphere index each point ignores (its own sphere; -1: none)
    depth : maximal depth of the visibility masks;  mode : "aggressive" or "conservative"
    threshold : the paper's ``t``: products with a smaller integral are dropped (0: keep all)
    margin : visibility square half-angle / light cap half-angle (1: the paper's)
    weights : (depth + 1, 12) eq. (39) weights (default: the stored calibration)
    cosine, preserve_integral : see :func:`~._brdf_lobes.brdf_lobes`; ``preserve_integral``
        also applies to the lighting and visibility products
    tables : lobe tables (default :func:`get_tables` on ``device``)
    chunk : points per batch (memory: ~ a few kB per point and shadow leaf); default 16,384
        with occluders, 65,536 without (a few hundred bytes per point)
    threads : torch CPU threads while shading (None: as set). One thread can be the faster
        where other processes share the cores (:func:`lobelight.bench.cosine.bench_lobes`
        times both).
    fused : run the hot path compiled by ``torch.compile`` (:mod:`._fused`: faster per frame
        once compiled; the first call compiles, which takes a while). None: as the enclosing
        :func:`~._fused.fusion` block says (default off)
    device : where to compute (default: the device of ``points``)

    Returns
    -------
    :class:`ShadeResult`
    """
    pts = torch.as_tensor(points)
    dev = torch.device(device) if device is not None else pts.device
    pts = pts.to(device=dev, dtype=torch.float32)
    nrm = torch.as_tensor(normals).to(device=dev, dtype=torch.float32)
    view = torch.as_tensor(wo).to(device=dev, dtype=torch.float32)
    P = pts.shape[0] if pts.ndim == 2 else -1
    _check_points("points", pts)
    _check_points("normals", nrm, P)
    _check_points("wo", view, P)
    lights = [lights] if isinstance(lights, SphereLight) else list(lights)
    if not lights or not all(isinstance(lt, SphereLight) for lt in lights):
        raise InputError("lights", "must be a SphereLight or a non-empty list of them")
    if mode not in MASK_MODES:
        raise InputError("mode", f"must be one of {MASK_MODES}, got {mode!r}")
    if cosine not in ("product", "axis", "none"):
        raise InputError("cosine", f"must be 'product', 'axis' or 'none', got {cosine!r}")
    if not (threshold >= 0):
        raise InputError("threshold", f"must be >= 0, got {threshold!r}")
    sph = None
    if spheres is not None:
        sph = torch.as_tensor(spheres).to(device=dev, dtype=torch.float32)
        _check_spheres(sph)
        if sph.shape[0] == 0:
            sph = None
    ex = None
    if exclude is not None:
        ex = torch.as_tensor(exclude).to(device=dev, dtype=torch.long).reshape(-1)
        if ex.shape[0] != P:
            raise InputError("exclude", f"must be ({P},), got {tuple(ex.shape)}")
    if sph is not None:
        w = default_weights(mode, depth) if weights is None else torch.as_tensor(weights)
        if w.shape != (depth + 1, 12):
            raise InputError("weights", f"must be ({depth + 1}, 12), got {tuple(w.shape)}")
        w = w.to(device=dev, dtype=torch.float32)
    else:
        w = None
    tables = tables if tables is not None else get_tables(device=dev)
    model = brdf.to(dev)
    outs, prods, nleaves = [], [], []
    ctx = cpu_threads(threads) if dev.type == "cpu" else contextlib.nullcontext()
    fuse = contextlib.nullcontext() if fused is None else fusion(fused)
    with ctx, fuse, torch.no_grad():
        if chunk is None:
            chunk = 16384 if sph is not None else 65536
        if int(chunk) < 1:
            raise InputError("chunk", f"must be >= 1, got {chunk!r}")
        for s in range(0, P, chunk):
            sl = slice(s, s + chunk)
            whole = s == 0 and chunk >= P  # one chunk: the model as it is, no gather
            m = (
                model.take(torch.arange(s, min(s + chunk, P), device=dev))
                if model.per_element_params and not whole
                else model
            )
            r = _shade_chunk(
                pts[sl],
                nrm[sl],
                view[sl],
                m,
                lights,
                sph,
                None if ex is None else ex[sl],
                w,
                tables,
                depth=depth,
                mode=mode,
                threshold=threshold,
                margin=margin,
                cosine=cosine,
                preserve=preserve_integral,
            )
            outs.append(r[0])
            prods.append(r[1])
            nleaves.append(r[2])
    return ShadeResult(torch.cat(outs), torch.cat(prods), torch.cat(nleaves))


def shadow_features(
    points: torch.Tensor,
    normals: torch.Tensor,
    wo: torch.Tensor,
    brdf: _brdf.BRDF,
    lights: SphereLight | list[SphereLight],
    spheres: torch.Tensor,
    *,
    depth: int,
    mode: str,
    margin: float = 1.0,
    tables: LobeTables | None = None,
):
    """The unshadowed radiance and each shadow leaf's unweighted product: what the eq. (39)
    weights multiply.

    Shaded radiance is linear in the weights, ``L_o = U - sum_k w(depth_k, dist_k) v_k``; these
    are ``U`` and the ``v_k``, with every leaf built and nothing culled (threshold 0), the
    reflectance lobes as :func:`shade_points` makes them by default (``cosine="product"``,
    integral-preserving products). The weight calibration (``tools/calibrate_cosine_weights.py``)
    fits the weights to Monte Carlo radiance from them.

    Parameters
    ----------
    points, normals, wo : (P, 3) float32, on one device (no chunking: ``P`` bounds the memory)
    brdf : as :func:`shade_points`;  lights : one :class:`~._light.SphereLight` or a list
    spheres : (N, 4) float32 occluders ``(x, y, z, radius)``, N >= 1
    depth, mode, margin : the visibility masks' settings, as :func:`shade_points`
    tables : lobe tables (default :func:`get_tables` on the points' device)

    Returns
    -------
    unshadowed : (P, 3) the radiance without occluders, ``U``
    features : a list, one entry per light that casts leaves, of ``(point, depth, i0, i1, lam,
        value)``: each leaf's point and depth (L,) int64, the ``dist`` nodes ``i0, i1`` (L,)
        int64 between which its weight is interpolated and the interpolation's ``lam`` (L,),
        and its product ``v_k`` (L, 3)
    """
    lights = [lights] if isinstance(lights, SphereLight) else list(lights)
    tables = tables if tables is not None else get_tables(device=points.device)
    with torch.no_grad():
        unshadowed, _, _, features = _shade_chunk(
            points,
            normals,
            wo,
            brdf,
            lights,
            spheres,
            None,
            None,
            tables,
            depth=depth,
            mode=mode,
            threshold=0.0,
            margin=margin,
            cosine="product",
            preserve=True,
            features=True,
        )
    return unshadowed, features


def _shade_chunk(
    x,
    n,
    wo,
    model,
    lights,
    spheres,
    exclude,
    weights,
    tables,
    *,
    depth,
    mode,
    threshold,
    margin,
    cosine,
    preserve,
    features: bool = False,
    leaf_scale: str = "cap",
):
    """One chunk: radiance (P, 3), products (P,), leaves (P,) [, calibration features]."""
    P = x.shape[0]
    dev = x.device
    n_lobes, n_cos = _lobe_counts(model)
    n_cos = n_cos if cosine == "product" else 0
    centres, radii, radiance_l = _light_tensors(lights, x)
    if spheres is None and not features:  # nothing multiplies m_ij again: one kernel
        radiance = _lit(
            model, x, n, wo, centres, radii, radiance_l, tables.product_table, tables._grid,
            tables.cap_table, cosine, preserve, float(threshold),
        )  # fmt: skip
        products = torch.full((P,), n_cos + n_lobes * len(lights), dtype=torch.long, device=dev)
        return radiance, products, torch.zeros(P, dtype=torch.long, device=dev)
    # (P, I, J, 3) integrals and the product lobes m_ij (P, I, J)
    mint, m = _direct(model, x, n, wo, centres, radii, radiance_l, tables, cosine, preserve)
    I, J = mint.shape[1], mint.shape[2]
    keep = mint.amax(-1) >= threshold  # (P, I, J)
    radiance = (mint * keep.unsqueeze(-1)).sum((1, 2))  # (P, 3)
    products = torch.full((P,), n_cos + I * J, dtype=torch.long, device=dev)
    nleaves = torch.zeros(P, dtype=torch.long, device=dev)
    feats = []
    if spheres is not None:
        axis, dist_l, theta = _geometry(x, centres, radii)  # (P, J, 3), (P, J), (P, J)
        # the largest scale of the kept m_ij of each point and light bounds every product of
        # its leaves: cells whose products all fall below the threshold are not built (the
        # calibration wants every leaf)
        peak = (m.scale.amax(-1) * keep).amax(1)  # (P, J)
        for j in range(J):  # lights: a small fixed count
            lv = shadow_leaves(
                x,
                axis[:, j],
                theta[:, j],
                dist_l[:, j],
                spheres,
                depth=depth,
                mode=mode,
                margin=margin,
                exclude=exclude,
                peak=None if features else peak[:, j],
                threshold=threshold,
            )
            if lv.point.numel() == 0:
                continue
            nleaves += lv.count
            # one product per (leaf, reflectance lobe) whose m_ij survived the threshold
            products += lv.count * keep[:, :, j].sum(-1)
            cell = leaf_scale == "cell"
            # the leaves' lobes (named apart from the lights' axis and theta of the loop)
            l_axis, l_theta, l_omega = lv.geometry(solid_angle=cell)  # (L, 3), (L,), (L,)
            # eq. (39)'s weights per point and depth first (P x (depth + 1) lookups), gathered
            # per leaf in the products' loop; calibration wants the unweighted values
            wp = None
            if not features:
                wp = depth_weights(weights, lv.dist).reshape(-1)  # (P * (depth + 1),)
            val = _shadow_products(
                lv.point,
                lv.depth,
                l_axis,
                l_theta,
                l_omega,
                wp,
                m.axis.movedim(-1, 0).reshape(3, -1),
                m.exponent.reshape(-1),
                m.scale.reshape(-1, m.scale.shape[-1]),
                keep.reshape(-1),
                tables.cap_table,
                tables.product_table,
                tables._grid,
                I,
                J,
                j,
                depth + 1,
                preserve,
                cell,
                threshold,
            )  # (L, 3)
            if features:
                i0, i1, lam = interp_coefficients(lv.dist[lv.point])
                feats.append((lv.point, lv.depth, i0, i1, lam, val))
            elif lv.grouped:  # segment sums: faster here than index_add
                shadow = torch.segment_reduce(val, "sum", lengths=lv.count, unsafe=True)
                radiance = radiance - shadow
            else:
                radiance = radiance.index_add(0, lv.point, -val)  # (alpha=-1 is a slow path)
    radiance = radiance.clamp_min(0)
    if features:
        return radiance, products, nleaves, feats
    return radiance, products, nleaves


def _direct(model, x, n, wo, centres, radii, radiance, tables, cosine, preserve):
    """Reflectance x lighting of each point as lobes, ``m_ij = f_i L_j`` (shadows multiply
    them again; without occluders :func:`_lit` needs only their integrals).

    Parameters
    ----------
    x, n, wo : (P, 3);  centres (J, 3), radii (J,), radiance (J, 3) of the lights

    Returns
    -------
    integrals : (P, I, J, 3) ``∫ m_ij``;  the product :class:`Lobes` (P, I, J)
    """
    f = brdf_lobes(model, n, wo, tables=tables, cosine=cosine, preserve_integral=preserve)
    light = cap_lobes(x, centres, radii, radiance, tables=tables)  # (P, J)
    fa = Lobes(f.axis.unsqueeze(2), f.exponent.unsqueeze(2), f.scale.unsqueeze(2))
    la = Lobes(light.axis.unsqueeze(1), light.exponent.unsqueeze(1), light.scale.unsqueeze(1))
    m = multiply(tables, fa, la, preserve_integral=preserve)  # (P, I, J)
    return m.integral(), m


@kernel
def _lit(
    model, x, n, wo, centres, radii, radiance, tab, grid, cap_tab,
    cosine: str, preserve: bool, threshold: float,
):  # fmt: skip
    """Unshadowed radiance ``sum_ij ∫ f_i L_j`` of each point, (P, 3), in one kernel.

    Without occluders nothing multiplies ``m_ij = f_i L_j`` again, so only its integral is
    looked up (no product lobe), and the threshold and the sum follow in the same loop.
    x, n, wo : (P, 3);  centres (J, 3), radii (J,), radiance (J, 3) of the lights;  tab, grid,
    cap_tab : the lobe tables (:class:`LobeTables`)

    The colour channels are separate (P,) rows, stacked last: TorchInductor then runs the
    table lookups once per point, not once per channel (faster than (P, 3) rows, and than
    :func:`_direct`'s separate kernels).
    """
    axes, exps, factors, scales = _lobe_parts(model, n, wo, None, tab, grid, cosine, preserve)
    l_axis, _, theta = _geometry(x, centres, radii)  # (P, J, 3), (P, J)
    l_exp = _cap_lookup(theta, cap_tab)
    l_scale = cap_scale(theta, l_exp)
    out = [torch.zeros_like(x[:, 0]) for _ in range(3)]
    for j in range(centres.shape[0]):  # lights, then reflectance lobes: small fixed counts
        for axis, e, factor, scale in zip(axes, exps, factors, scales, strict=True):
            unit = _integral_flat(axis.T, l_axis[:, j].T, e, l_exp[:, j], tab, grid, preserve)
            unit = unit * factor * l_scale[:, j]
            v = [unit * scale[:, c] * radiance[j, c] for c in range(3)]  # ∫ m_ij per channel
            keep = torch.maximum(torch.maximum(v[0], v[1]), v[2]) >= threshold
            out = [o + torch.where(keep, vc, 0.0) for o, vc in zip(out, v, strict=True)]
    return torch.stack(out, -1)  # a sum of kept integrals: >= 0, as the shadowed sum clamped


@kernel
def _shadow_products(
    point, depth, axis, theta, omega, wp, m_axis, m_exp, m_scale, keep, cap_tab, tab, grid,
    I: int, J: int, j: int, D1: int, preserve: bool, cell: bool, threshold: float,
):  # fmt: skip
    """``w_k sum_i ∫ m_ij c_k`` per shadow leaf ``k`` of light ``j``: (L, C).

    One fused loop over the (leaf, reflectance lobe) pairs, gathering each pair's product lobe
    where it is used. Products ``m_ij`` culled by the threshold (``keep``) and ``(leaf, i)``
    products below it count 0. The leaf's lobe has the paper's bounding-cap exponent; its
    integral is the cell's own solid angle (``cell``) or the bounding cap's.

    point, depth : (L,);  axis (L, 3), theta (L,), omega (L,) the leaves' bounding caps and
    solid angles (:meth:`~._visibility.Leaves.geometry`);  wp : (P D1,) eq. (39)'s weight per
    point and depth (``D1`` depths), or None for ``w_k = 1``;  m_axis (3, P I J) component
    rows, m_exp (P I J,), m_scale (P I J, C) the product lobes and keep (P I J,) bool,
    flattened;  cap_tab, tab, grid : the lobe tables (:class:`LobeTables`)

    (Building the leaves' caps inside this loop as well is slower on the CPU than the two
    kernels.)
    """
    L = point.shape[0]
    q = torch.arange(L * I, device=point.device)
    leaf = q // I  # (L I,) pairs leaf-major
    row = (point[leaf] * I + (q - leaf * I)) * J + j  # (L I,) row of m_ij
    e_k = _cap_lookup(theta[leaf], cap_tab)
    if cell:
        s_k = omega[leaf] * (e_k + 1) / (2 * math.pi)
    else:
        s_k = cap_scale(theta[leaf], e_k)
    unit = _integral_flat(m_axis[:, row], axis.T[:, leaf], m_exp[row], e_k, tab, grid, preserve)
    val = (unit * s_k).unsqueeze(-1) * m_scale[row]  # (L I, C)
    val = val * ((val.amax(-1, keepdim=True) >= threshold) & keep[row].unsqueeze(-1))
    val = val.reshape(L, I, -1).sum(1)
    return val if wp is None else val * wp[point * D1 + depth].unsqueeze(-1)


def _lobe_counts(model: _brdf.BRDF) -> tuple[int, int]:
    """Reflectance lobes of ``model`` and how many of them are multiplied by the cosine."""
    flags = _lobe_flags(model)
    return len(flags), sum(not cos for cos in flags)
