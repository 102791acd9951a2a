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


def diffuse_interreflection(
    transport: Transport,
    shadowed: torch.Tensor,
    *,
    bounces: int = BOUNCES,
    res: int = 8,
    batch: int = 4096,
    glossy: tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor] | None = None,
    progress: Callable[[str, int, int], None] | None = None,
) -> torch.Tensor:
    """Add diffuse interreflection to self-shadowed SH transfer vectors (Sloan et al. 2002).

    Bounce ``k + 1``: ``T_x = T0_x + G_x + (albedo_x / pi) sum_w T_y(w) cos(w) Omega(w)`` over
    the directions ``w`` (a cube map of ``res``) whose ray from ``x`` hits the object at
    ``y(w)``; ``T_y`` is the barycentric blend of the previous bounce's vectors at the hit
    triangle's corners. The hit records are cast once and kept as a sparse gather matrix, so a
    bounce is one sparse product.

    ``G_x`` is the light that the hit points' *glossy* lobes send towards ``x`` (a diffuse
    floor by a metal wall receives most of its indirect light that way): with ``glossy`` given
    (the fitted Gaussians of the glossy transport, direct and, where baked, indirect), it is
    ``(albedo_x / pi) sum_w cos Omega P(y, -w)``, with ``P(y, v)`` the SH projection of ``y``'s
    Gaussians for the view ``v`` (blended over the geodesic triangle of views around ``v`` and
    over the hit triangle's corners). Without it only the hit points' diffuse light is carried.

    Parameters
    ----------
    shadowed : (V, n, 3) self-shadowed transfer of every vertex (:meth:`Transport.diffuse`)
    bounces : bounces of interreflection (0: ``shadowed`` unchanged)
    res : face resolution of the cube map of gather directions
    batch : vertices whose rays are cast at once
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
    bounces = int(bounces)
    if bounces == 0:
        return shadowed.clone()
    order = round(math.sqrt(shadowed.shape[1]))
    shadowed = shadowed.to(dev)
    d = cubemap.texel_directions(res, device=dev).reshape(-1, 3)
    om = cubemap.texel_solid_angles(res, device=dev).reshape(-1)
    lobes = _glossy_lobes(glossy, v, order, dev) if glossy is not None else None
    extra = torch.zeros_like(shadowed)  # the hit points' glossy light, summed at x
    rows, cols, vals = [], [], []  # the sparse gather matrix, x <- hit triangle corners
    starts = range(0, v, batch)
    total = len(starts) + bounces
    for step, s in enumerate(starts):
        vidx = torch.arange(s, min(v, s + batch), device=dev)
        p, n = mesh.vertices[vidx][:, None], mesh.normals[vidx][:, None]
        cos = (n * d[None]).sum(-1)  # (b, D)
        bi, di = (cos > 0).nonzero(as_tuple=True)  # (m,) rays above the horizon
        o = transport.caster.spawn(p[bi, 0], n[bi, 0], d[di])
        tri, _, bary = transport.caster.first_hit(o, d[di])
        hit = tri >= 0
        vx, di = vidx[bi[hit]], di[hit]  # (h,)
        corners, bary = mesh.faces[tri[hit]], bary[hit]  # (h, 3) each
        w = cos[bi[hit], di] * om[di]  # (h,) cosine-weighted solid angle
        rows.append(vx.repeat_interleave(3))
        cols.append(corners.reshape(-1))
        vals.append((w[:, None] * bary).reshape(-1))
        if lobes is not None:
            _add_glossy(extra, lobes, vx, corners, bary, -d[di], w)
        if progress is not None:
            progress("interreflection", step + 1, total)
    idx = torch.stack([torch.cat(rows), torch.cat(cols)])
    gather = torch.sparse_coo_tensor(
        idx, torch.cat(vals), (v, v), check_invariants=False
    ).coalesce()
    rho = (transport.materials.diffuse.to(dev) / math.pi)[:, None, :]  # (V, 1, 3)
    base = shadowed + rho * extra
    cur = base
    for k in range(bounces):
        gathered = torch.sparse.mm(gather, cur.reshape(v, -1)).reshape(cur.shape)  # (V, n, 3)
        cur = base + rho * gathered
        if progress is not None:
            progress("interreflection", len(starts) + k + 1, total)
    return cur


@dataclass(eq=False)
class _Lobes:
    """The fitted glossy Gaussians, ready to be projected onto SH at any view."""

    geodesic: bool  # views are the geodesic views (blend over their triangles) or not (nearest)
    views: torch.Tensor  # (J, 3)
    w: torch.Tensor  # (V, J, N, 3)
    mu: torch.Tensor  # (V, J, N, 3)
    zonal: torch.Tensor  # (V, J, N, order) zonal SH of each Gaussian about its mean
    live: torch.Tensor  # (V,) bool, vertices with any glossy weight


def _glossy_lobes(glossy, v: int, order: int, dev) -> _Lobes:
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
    geodesic = views.shape == geo.shape and bool(torch.allclose(views.float(), geo, atol=1e-5))
    return _Lobes(
        geodesic=geodesic,
        views=views.float(),
        w=w.float(),
        mu=mu.float(),
        zonal=sh.sg_zonal(lam.float().clamp_min(0), order),
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
