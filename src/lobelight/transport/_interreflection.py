"""Diffuse interreflection of the SH transfer (Sloan et al. 2002), carrying the light that the
hit points' fitted glossy lobes send as well as their diffuse light."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch

from ..errors import InputError
from ..geometry import cubemap, sphere
from ..lobes import sh
from ._transport import BOUNCES, Transport

__all__ = ["diffuse_interreflection"]

# Working memory of diffuse_interreflection's batches by default, in bytes (what the batches
# hold at once, beyond the transfer vectors, the lobes and the gather matrix).
_MEMORY = 512 * 2**20

# Upper estimates of the bytes one unit of work holds at once, from which the batch sizes follow
# (:func:`_plan`). A (vertex, gather direction) pair of a ray batch: its cosine, the ray above the
# horizon (origin, direction, hit triangle, distance, barycentrics, the caster's float64 hit
# geometry) and the hit record until it is merged into the gather matrix.
_RAY_BYTES = 384
# A hit record's Gaussian in _add_glossy: the (3 corners x 3 views) zonal coefficients rotated
# onto 25 SH coefficients in float64 (basis and products) and their RGB projection.
_RECORD_BYTES = 9 * 25 * (4 * 8 + 3 * 4)
# One Gaussian's zonal coefficients (sh.sg_zonal: a float64 table of Legendre values at its
# quadrature nodes, and the integrand), per band.
_ZONAL_BYTES = 3 * 8 * 45


@dataclass(frozen=True)
class _Plan:
    """Batch sizes of one interreflection: vertices whose rays are cast at once, hit records
    projected at once, Gaussians whose zonal coefficients are computed at once."""

    vertices: int
    records: int
    lobes: int


def _plan(memory: int, directions: int, gaussians: int, order: int) -> _Plan:
    """Batch sizes that keep each batch within ``memory`` bytes."""
    memory = max(int(memory), 1)
    return _Plan(
        vertices=max(1, memory // (directions * _RAY_BYTES)),
        records=max(1, memory // (max(gaussians, 1) * _RECORD_BYTES)),
        lobes=max(1, memory // (order * _ZONAL_BYTES)),
    )


def diffuse_interreflection(
    transport: Transport,
    shadowed: torch.Tensor,
    *,
    bounces: int = BOUNCES,
    res: int = 8,
    batch: int | None = None,
    memory: int = _MEMORY,
    glossy: tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor] | None = None,
    progress: Callable[[str, int, int], None] | None = None,
) -> torch.Tensor:
    """Add diffuse interreflection to self-shadowed SH transfer vectors (Sloan et al. 2002).

    Bounce ``k + 1``: ``T_x = T0_x + G_x + (albedo_x / pi) sum_w T_y(w) cos(w) Omega(w)`` over
    the directions ``w`` (a cube map of ``res``) whose ray from ``x`` hits the object at
    ``y(w)``; ``T_y`` is the barycentric blend of the previous bounce's vectors at the hit
    triangle's corners. The hit records are cast once and kept as a sparse gather matrix (each
    batch's records merged per (vertex, corner) as they come), so a bounce is one sparse
    product.

    ``G_x`` is the light that the hit points' *glossy* lobes send towards ``x`` (a diffuse
    floor by a metal wall receives most of its indirect light that way): with ``glossy`` given
    (the fitted Gaussians of the glossy transport, direct and, where baked, indirect), it is
    ``(albedo_x / pi) sum_w cos Omega P(y, -w)``, with ``P(y, v)`` the SH projection of ``y``'s
    Gaussians for the view ``v`` (blended over the geodesic triangle of views around ``v`` and
    over the hit triangle's corners). Without it only the hit points' diffuse light is carried.

    Memory: the batches (rays, glossy records, the Gaussians' zonal coefficients) are sized to
    hold at most about ``memory`` bytes each, whatever the mesh; what grows with the mesh is the
    output's size and the inputs' (transfer vectors, Gaussians and their zonal coefficients, a
    few kilobytes per vertex) and the gather matrix (20 bytes per merged (vertex, corner) pair).

    Parameters
    ----------
    shadowed : (V, n, 3) self-shadowed transfer of every vertex (:meth:`Transport.diffuse`)
    bounces : bounces of interreflection (0: ``shadowed`` unchanged)
    res : face resolution of the cube map of gather directions
    batch : vertices whose rays are cast at once (default: as many as ``memory`` holds)
    memory : bytes a batch may hold (512 MB by default)
    glossy : optional ``(views (J, 3), w (V, J, N, 3), mu (V, J, N, 3), lam (V, J, N))``
    progress : optional ``progress("interreflection", done, total)`` after each batch of rays
        and each bounce

    Returns
    -------
    (V, n, 3) transfer with ``bounces`` bounces of interreflection
    """
    mesh, dev = transport.mesh, transport.device
    v = mesh.n_vertices
    if shadowed.ndim != 3 or shadowed.shape[0] != v or shadowed.shape[-1] != 3:
        raise InputError(
            "shadowed", f"needs (V, n, 3) transfer of all {v} vertices, got {tuple(shadowed.shape)}"
        )
    if int(bounces) != bounces or bounces < 0:
        raise InputError("bounces", f"must be a whole number >= 0, got {bounces}")
    if res < 1:
        raise InputError("res", f"must be a positive face resolution, got {res}")
    if batch is not None and batch < 1:
        raise InputError("batch", f"must be a positive number of vertices, got {batch}")
    bounces = int(bounces)
    if bounces == 0:
        return shadowed.clone()
    order = round(math.sqrt(shadowed.shape[1]))
    shadowed = shadowed.to(dev)
    d = cubemap.texel_directions(res, device=dev).reshape(-1, 3)
    om = cubemap.texel_solid_angles(res, device=dev).reshape(-1)
    n_g = 0 if glossy is None else int(torch.as_tensor(glossy[3]).shape[-1])
    plan = _plan(memory, d.shape[0], n_g, order)
    batch = plan.vertices if batch is None else int(batch)
    lobes = _glossy_lobes(glossy, v, order, dev, plan.lobes) if glossy is not None else None
    extra = torch.zeros_like(shadowed)  # the hit points' glossy light, summed at x
    counts = torch.zeros(v, dtype=torch.int64, device=dev)  # gather entries per row
    cols, vals = [], []  # the sparse gather matrix, x <- hit triangle corners, row by row
    starts = range(0, v, batch)
    total = len(starts) + bounces
    for step, s in enumerate(starts):
        vidx = torch.arange(s, min(v, s + batch), device=dev)
        p, n = transport.origins.points[vidx][:, None], mesh.normals[vidx][:, None]
        cos = (n * d[None]).sum(-1)  # (b, D)
        bi, di = (cos > 0).nonzero(as_tuple=True)  # (m,) rays above the horizon
        o = transport.caster.spawn(p[bi, 0], n[bi, 0], d[di])
        tri, _, bary = transport.caster.first_hit(o, d[di])
        hit = tri >= 0
        vx, di = vidx[bi[hit]], di[hit]  # (h,)
        corners, bary = mesh.faces[tri[hit]], bary[hit]  # (h, 3) each
        w = cos[bi[hit], di] * om[di]  # (h,) cosine-weighted solid angle
        _merge(counts, cols, vals, vx, corners, w[:, None] * bary, v)
        if lobes is not None:
            _add_glossy(extra, lobes, vx, corners, bary, -d[di], w, chunk=plan.records)
        if progress is not None:
            progress("interreflection", step + 1, total)
    rows = torch.repeat_interleave(torch.arange(v, device=dev), counts)
    # the batches cover increasing vertex ranges, each merged and sorted: coalesced as it is
    gather = torch.sparse_coo_tensor(
        torch.stack([rows, torch.cat(cols)]),
        torch.cat(vals),
        (v, v),
        is_coalesced=True,
        check_invariants=False,
    )
    del rows, cols, vals
    rho = (transport.materials.diffuse.to(dev) / math.pi)[:, None, :]  # (V, 1, 3)
    base = shadowed + rho * extra
    del extra
    cur = base
    for k in range(bounces):
        gathered = torch.sparse.mm(gather, cur.reshape(v, -1)).reshape(cur.shape)  # (V, n, 3)
        cur = base + rho * gathered
        if progress is not None:
            progress("interreflection", len(starts) + k + 1, total)
    return cur


def _merge(counts, cols, vals, vx, corners, weights, v: int) -> None:
    """Append one ray batch's hit records to the gather matrix's rows, merged per (gathering
    vertex, corner) and sorted: ``vx`` (h,), ``corners`` (h, 3), ``weights`` (h, 3)."""
    key = vx.repeat_interleave(3) * v + corners.reshape(-1)  # (3h,) row-major position
    uniq, inv = torch.unique(key, sorted=True, return_inverse=True)
    val = torch.zeros(uniq.numel(), dtype=weights.dtype, device=weights.device)
    val.index_add_(0, inv, weights.reshape(-1))
    counts.index_add_(0, uniq // v, torch.ones_like(uniq))
    cols.append(uniq % v)
    vals.append(val)


@dataclass(eq=False)
class _Lobes:
    """The fitted glossy Gaussians, ready to be projected onto SH at any view."""

    geodesic: bool  # views are the geodesic views (blend over their triangles) or not (nearest)
    views: torch.Tensor  # (J, 3)
    w: torch.Tensor  # (V, J, N, 3)
    mu: torch.Tensor  # (V, J, N, 3)
    zonal: torch.Tensor  # (V, J, N, order) zonal SH of each Gaussian about its mean
    live: torch.Tensor  # (V,) bool, vertices with any glossy weight


def _glossy_lobes(glossy, v: int, order: int, dev, chunk: int) -> _Lobes:
    """The glossy Gaussians ready for :func:`_add_glossy`, their zonal coefficients computed
    ``chunk`` Gaussians at a time (the computation's float64 tables would otherwise take
    several hundred bytes per Gaussian and band at once)."""
    try:
        views, w, mu, lam = (torch.as_tensor(t).to(dev) for t in glossy)
    except (TypeError, ValueError) as e:
        raise InputError("glossy", "must be (views, w, mu, lam) tensors") from e
    j = views.shape[0] if views.ndim == 2 else -1
    if views.ndim != 2 or views.shape[1] != 3 or w.shape[:2] != (v, j) or w.shape[-1] != 3:
        raise InputError("glossy", f"needs views (J, 3) and w (V={v}, J, N, 3), got "
                         f"{tuple(views.shape)} and {tuple(w.shape)}")  # fmt: skip
    if mu.shape != w.shape or lam.shape != w.shape[:-1]:
        raise InputError("glossy", "mu must be shaped as w, lam as w without its colour axis")
    geo = sphere.geodesic_views(device=dev)
    lam_f = lam.float().clamp_min(0).reshape(-1)  # (V J N,)
    zonal = torch.empty(lam_f.numel(), order, device=dev)
    for s in range(0, lam_f.numel(), chunk):
        zonal[s : s + chunk] = sh.sg_zonal(lam_f[s : s + chunk], order)
    geodesic = views.shape == geo.shape and bool(torch.allclose(views.float(), geo, atol=1e-5))
    return _Lobes(
        geodesic=geodesic,
        views=views.float(),
        w=w.float(),
        mu=mu.float(),
        zonal=zonal.reshape(*lam.shape, order),
        live=w.amax((1, 2, 3)) > 0,
    )


def _add_glossy(
    out: torch.Tensor,
    lobes: _Lobes,
    vx: torch.Tensor,
    corners: torch.Tensor,
    bary: torch.Tensor,
    towards: torch.Tensor,
    weight: torch.Tensor,
    *,
    chunk: int = 8192,
) -> None:
    """``out[x] += weight * P(y, towards)`` for hit records whose triangle has glossy corners.

    vx : (h,) gathering vertices;  corners, bary : (h, 3) hit triangles and weights;
    towards : (h, 3) directions from the hit points to ``x`` (the view of their glossy lobes);
    weight : (h,) cosine-weighted solid angles
    """
    keep = lobes.live[corners].any(1).nonzero().squeeze(-1)  # (k,) records that see gloss
    for s in range(0, keep.numel(), chunk):
        r = keep[s : s + chunk]
        if lobes.geodesic:
            vi, vb = sphere.locate_views(towards[r])  # (m, 3) view triangle and weights
        else:  # other view sets: the nearest view
            vi = (towards[r] @ lobes.views.T).argmax(-1, keepdim=True)  # (m, 1)
            vb = torch.ones_like(vi, dtype=towards.dtype)
        y = corners[r][:, :, None].expand(-1, -1, vi.shape[1])  # (m, 3 corners, views)
        jv = vi[:, None, :].expand_as(y)
        c = bary[r][:, :, None] * vb[:, None, :]  # (m, 3, views) blend weights
        coef = sh.zonal_to_sh(lobes.zonal[y, jv], lobes.mu[y, jv])  # (m, 3, k, N, order^2)
        proj = (coef[..., None] * lobes.w[y, jv][..., None, :]).sum(-3)  # (m, 3, k, n, 3)
        proj = (proj * c[..., None, None]).sum((1, 2))  # (m, order^2, 3)
        out.index_add_(0, vx[r], proj * weight[r][:, None, None])
