"""Where each vertex's rays start: off the surfaces that meet it or lie just over it.

A vertex's transport is sampled by rays from the vertex, lifted off its surface by the
caster's offset along its normal (:meth:`lobelight.geometry.raycast.RayCaster.spawn`). Two
kinds of vertex see almost nothing from there although their faces are open:

- **at a hard edge** (split vertices: one position, two normals), the normal of one side lies
  in the plane of the other, so the lift leaves the origin on that other surface and every ray
  hits it at distance 0. Each origin therefore also moves by the caster's offset toward the
  area-weighted centre of the vertex's own faces, tangentially (off the neighbouring surface
  and onto its own);
- **covered** (a sleeve, a frame or a lid lying just over the vertex's point while the faces'
  interiors are open): the vertex's visibility is about 0, and interpolated across its faces
  it darkens them. Such a vertex takes its transport at the nearest point of its own faces
  that sees clearly more of the environment (:data:`EXPOSED_GAIN` more and at least
  :data:`EXPOSED_FLOOR`, by the cosine-weighted visible fraction of a stratified grid of
  rays), searched at fractions :data:`EXPOSED_STEPS` of the way from the vertex to each face's
  centroid. It keeps its normal, its material and its place in the rendered mesh.

:func:`vertex_origins` computes both for a mesh (the result is kept for the mesh's arrays, so
a bake's transport and its model's tiles compute it once); every ray a vertex casts starts at
``caster.spawn(origins.points[v], normal[v], d)``.
"""

from __future__ import annotations

import hashlib
import inspect
import math
from dataclasses import dataclass

import torch

from ..geometry import sphere
from ..geometry.raycast import RayCaster, resolve_engine

__all__ = [
    "EXPOSED_FLOOR",
    "EXPOSED_GAIN",
    "EXPOSED_STEPS",
    "VertexOrigins",
    "vertex_origins",
]

#: Fractions of the way from a vertex to each of its faces' centroids where a covered vertex
#: looks for an exposed point, nearest first.
EXPOSED_STEPS = (0.02, 0.05, 0.1, 0.2, 0.35, 0.5)
#: How much more of the environment (cosine-weighted visible fraction) an exposed point sees
#: than its vertex: a clear step, far above the grid's sampling error (1 / 64 a ray).
EXPOSED_GAIN = 0.3
#: The least an exposed point sees (cosine-weighted visible fraction).
EXPOSED_FLOOR = 0.5
#: Rays per side of the stratified cosine-weighted grid that measures a point's visibility.
_GRID = 8
#: Rays cast at once (bounds a batch's memory at about 100 MB).
_RAYS_PER_BATCH = 1 << 20
#: A vertex whose faces' centre lies this close to it, relative to their mean distance, has no
#: tangential direction worth the name (a flat, symmetric fan): its origin is not moved
#: sideways.
_FLAT_FAN = 1e-3
#: A caster's offset by default, as a fraction of the mesh's diagonal.
_CASTER_OFFSET = inspect.signature(RayCaster).parameters["offset"].default
#: Meshes whose origins are kept (:func:`vertex_origins`), newest last.
_KEPT = 2
_kept: dict[tuple, VertexOrigins] = {}


@dataclass(frozen=True, eq=False)
class VertexOrigins:
    """Where each vertex's rays start, before the caster's lift along the normal.

    Attributes
    ----------
    points : (V, 3) float32, the vertex moved by the caster's offset toward its faces, or,
        where ``exposed``, the exposed point of its faces whose transport it takes
    exposed : (V,) bool, the covered vertices that take an exposed point's transport
    """

    points: torch.Tensor
    exposed: torch.Tensor

    @property
    def n_exposed(self) -> int:
        """How many vertices take an exposed point's transport."""
        return int(self.exposed.sum())

    @classmethod
    def at_vertices(cls, mesh) -> VertexOrigins:
        """Rays from the vertices themselves (no move; a baseline to compare with)."""
        return cls(mesh.vertices, torch.zeros_like(mesh.vertices[:, 0], dtype=torch.bool))


def vertex_origins(mesh, *, caster: RayCaster | None = None, exposed: bool = True) -> VertexOrigins:
    """Each vertex's ray origin: moved off a hard edge's other side and, where the vertex is
    covered, to an exposed point of its own faces (the module's docstring says how).

    Parameters
    ----------
    mesh : lobelight.scene.Mesh (V vertices)
    caster : the mesh's ray caster, whose offset sets the sideways move (built here when None)
    exposed : also look for exposed points for covered vertices (rays: ``8 x 8`` per vertex,
        and as many per candidate point of the vertices that see at most
        ``1 - EXPOSED_GAIN``)

    Returns
    -------
    VertexOrigins, on the mesh's device. The result is kept for the mesh's arrays, the
    caster's offset and engine (the last two meshes'): a second call for the same mesh, with
    an equal caster or none, returns it without casting a ray.
    """
    offset = _CASTER_OFFSET * mesh.scale if caster is None else caster.offset
    engine = resolve_engine(None, mesh.device) if caster is None else caster.engine
    key = (_digest(mesh), offset, engine, bool(exposed))
    if key in _kept:
        return _kept[key]
    caster = RayCaster(mesh) if caster is None else caster
    points = _nudged(mesh, caster.offset)
    moved = torch.zeros(mesh.n_vertices, dtype=torch.bool, device=mesh.device)
    if exposed and mesh.n_vertices:
        points, moved = _exposed(mesh, caster, points)
    out = VertexOrigins(points, moved)
    _kept[key] = out
    while len(_kept) > _KEPT:
        del _kept[next(iter(_kept))]
    return out


def _digest(mesh) -> str:
    """A digest of the mesh's positions, normals and faces (and their device)."""
    h = hashlib.blake2b(digest_size=16)
    for t in (mesh.vertices, mesh.normals, mesh.faces):
        h.update(str((t.dtype, tuple(t.shape), str(t.device))).encode())
        h.update(t.detach().contiguous().cpu().numpy().tobytes())
    return h.hexdigest()


def _fan_centres(mesh) -> tuple[torch.Tensor, torch.Tensor]:
    """The area-weighted centre of each vertex's faces ``(V, 3)`` and the faces' area-weighted
    mean distance from the vertex ``(V,)``, float64 (float32 on MPS)."""
    real = torch.float32 if mesh.device.type == "mps" else torch.float64
    v, f = mesh.vertices.to(real), mesh.faces
    tri = v[f]  # (F, 3 corners, 3)
    area = 0.5 * torch.linalg.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]).norm(dim=-1)
    cen = tri.mean(1)  # (F, 3)
    corner = f.reshape(-1)  # (3F,) each face's corners
    a3 = area.repeat_interleave(3)  # (3F,)
    dist = (cen.repeat_interleave(3, 0) - v[corner]).norm(dim=-1)  # (3F,)
    acc = torch.zeros_like(v).index_add_(0, corner, cen.repeat_interleave(3, 0) * a3[:, None])
    w = torch.zeros_like(v[:, 0]).index_add_(0, corner, a3)
    spread = torch.zeros_like(w).index_add_(0, corner, dist * a3)
    tiny = torch.finfo(real).tiny
    return acc / w.clamp_min(tiny)[:, None], spread / w.clamp_min(tiny)


def _nudged(mesh, offset: float) -> torch.Tensor:
    """The vertices moved by ``offset`` toward the area-weighted centre of their own faces,
    within their tangent plane, ``(V, 3)`` in the vertices' dtype: off the other side of a
    hard edge (whose plane holds this side's normal). A vertex without faces, or whose faces'
    centre lies on its normal, stays."""
    centre, spread = _fan_centres(mesh)
    v = mesh.vertices.to(centre.dtype)
    n = torch.nn.functional.normalize(mesh.normals.to(centre.dtype), dim=-1)
    t = centre - v
    t = t - (t * n).sum(-1, keepdim=True) * n  # (V, 3) tangential part
    length = t.norm(dim=-1, keepdim=True)
    ok = length > _FLAT_FAN * spread[:, None]
    step = torch.where(ok, t / length.clamp_min(torch.finfo(t.dtype).tiny), torch.zeros_like(t))
    return (v + offset * step).to(mesh.vertices.dtype)


def _cosine_grid(device) -> torch.Tensor:
    """``(K, 3)`` a stratified cosine-weighted grid of local directions (z up), ``K = 64``."""
    u = (torch.arange(_GRID, dtype=torch.float64, device=device) + 0.5) / _GRID
    u1, u2 = torch.meshgrid(u, u, indexing="ij")
    r, phi = u1.reshape(-1).sqrt(), 2 * math.pi * u2.reshape(-1)
    z = (1 - r * r).clamp_min(0).sqrt()
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], -1)


def _visible_fraction(caster: RayCaster, points, normals, local) -> torch.Tensor:
    """Cosine-weighted visible fraction ``(N,)`` of points ``(N, 3)`` with unit normals
    ``(N, 3)``, by the grid ``local (K, 3)`` of cosine-weighted directions, batched."""
    k = local.shape[0]
    out = torch.empty(points.shape[0], dtype=torch.float64, device=points.device)
    step = max(1, _RAYS_PER_BATCH // k)
    for s in range(0, points.shape[0], step):
        p, n = points[s : s + step], normals[s : s + step]
        d = sphere.to_world(local.to(n.dtype)[None], n[:, None])  # (b, K, 3)
        o = caster.spawn(p[:, None].expand_as(d), n[:, None].expand_as(d), d)
        out[s : s + step] = 1 - caster.occluded(o, d).double().mean(-1)
    return out


def _exposed(mesh, caster: RayCaster, points: torch.Tensor):
    """The exposed points of the covered vertices: ``points (V, 3)`` with those vertices'
    replaced, and ``moved (V,)`` bool (:func:`vertex_origins`)."""
    dev = mesh.device
    local = _cosine_grid(dev)
    n = torch.nn.functional.normalize(mesh.normals, dim=-1)
    seen = _visible_fraction(caster, points, n, local)  # (V,)
    corner = mesh.faces.reshape(-1)  # (3F,) the vertex of each face corner
    cen = mesh.vertices[mesh.faces].mean(1).repeat_interleave(3, 0)  # (3F, 3) its face's centre
    # only the corners of vertices that could gain enough can move
    open_ = (seen[corner] <= 1 - EXPOSED_GAIN).nonzero().squeeze(-1)  # (C,)
    moved = torch.zeros(mesh.n_vertices, dtype=torch.bool, device=dev)
    points = points.clone()
    for frac in EXPOSED_STEPS:
        c = open_[~moved[corner[open_]]]  # (C',) corners of vertices not moved yet
        if c.numel() == 0:
            break
        vc = corner[c]
        p = mesh.vertices[vc] + frac * (cen[c] - mesh.vertices[vc])  # (C', 3)
        vis = _visible_fraction(caster, p, n[vc], local)
        ok = (vis >= seen[vc] + EXPOSED_GAIN) & (vis >= EXPOSED_FLOOR)
        if not bool(ok.any()):
            continue
        c_ok, v_ok, vis_ok, p_ok = c[ok], vc[ok], vis[ok], p[ok]
        # per vertex the candidate that sees the most, the first corner among equals
        best = torch.full((mesh.n_vertices,), -1.0, dtype=vis.dtype, device=dev)
        best = best.scatter_reduce(0, v_ok, vis_ok, "amax")
        top = vis_ok == best[v_ok]
        first = torch.full((mesh.n_vertices,), c_ok.numel(), dtype=torch.int64, device=dev)
        idx = torch.arange(c_ok.numel(), device=dev)
        first = first.scatter_reduce(0, v_ok[top], idx[top], "amin")
        win = first[first < c_ok.numel()]  # (M,) one candidate per newly moved vertex
        points[v_ok[win]] = p_ok[win].to(points.dtype)
        moved[v_ok[win]] = True
    return points, moved
