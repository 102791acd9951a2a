"""Each vertex's visibility of the environment as a function of direction, on an octahedral
tile: what a renderer needs to place a sharp reflection's occlusion per pixel.

The fitted Gaussians carry visibility only at the 92 stored views; a mirror's reflected
direction turns by twice the view's angle, so between two neighbouring views (about 20
degrees) a reflection sweeps about 40 degrees of the sphere, and an occluder's edge seen in a
sharp metal lands anywhere in between. The tile samples visibility every few degrees whatever
the view (:data:`VISIBILITY_RES`), and the renderer reads it at each pixel's own reflected
direction (``lobelight.render``'s per-pixel reflection; docs/method.md has the measurement).
It depends on the mesh alone, so a model computes it on first use when its file does not
carry it.

Where the tile says the environment is hidden, the object itself is seen: :func:`hit_tiles`
records, per texel, which triangle the ray through the texel's centre hits and how far away,
so that a renderer can shade the reflected part of the object per pixel (its position, normal
and own reflection) instead of a fitted Gaussian's blur of it.
"""

from __future__ import annotations

import torch

from .._checks import check_int
from ..geometry import octahedral
from ..geometry.raycast import RayCaster
from ..transport import vertex_origins

__all__ = ["VISIBILITY_RES", "VISIBILITY_SUB", "hit_tiles", "visibility_tiles"]

#: Octahedral tile resolution: 32 x 32 texels over the sphere, about 6.3 degrees apart.
VISIBILITY_RES = 32
#: Rays per texel side: a texel holds the visible fraction of its 2 x 2 rays, so an edge
#: crossing it is placed within the texel by the bilinear lookup.
VISIBILITY_SUB = 2
#: Rays cast at once (bounds the batch's memory at about 100 MB).
_RAYS_PER_BATCH = 1 << 20


def visibility_tiles(
    mesh, *, res: int = VISIBILITY_RES, sub: int = VISIBILITY_SUB, caster: RayCaster | None = None
) -> torch.Tensor:
    """The environment's visible fraction per texel of each vertex's octahedral tile.

    Rays leave each vertex's ray origin (as the transport's do) along ``sub x sub``
    stratified directions per texel; a direction below the vertex normal's horizon counts as
    occluded (the surface itself is in the way).

    Parameters
    ----------
    mesh : lobelight.scene.Mesh (V vertices);  res, sub : tile resolution and rays per texel side
    caster : the mesh's ray caster (built here when None)

    Returns
    -------
    (V, res, res) uint8, the visible fraction times 255, on the mesh's device
    """
    res = check_int(res, "res", minimum=2)
    sub = check_int(sub, "sub")
    caster = RayCaster(mesh) if caster is None else caster
    dev = mesh.vertices.device
    d = octahedral.texel_directions(res, sub=sub, device=dev).reshape(-1, 3)  # (D, 3)
    out = torch.zeros(mesh.n_vertices, res * res, dtype=torch.uint8, device=dev)
    for vi, bi, di, o in _rays_above_horizon(mesh, d, caster):
        vis = torch.zeros(vi.shape[0], d.shape[0], device=dev)
        vis[bi, di] = (~caster.occluded(o, d[di])).float()
        frac = vis.reshape(-1, res * res, sub * sub).mean(-1)  # (b, res^2)
        out[vi] = (frac * 255).round().to(torch.uint8)
    return out.reshape(-1, res, res)


def _rays_above_horizon(mesh, d: torch.Tensor, caster: RayCaster):
    """The rays of each batch of vertices along directions ``d (D, 3)`` above the vertex
    normal's horizon, at most :data:`_RAYS_PER_BATCH` per batch: yields ``vi (b,)`` the
    batch's vertex ids, ``bi, di (R,)`` each ray's row in the batch and direction index, and
    ``origins (R, 3)``: the vertices' ray origins as the transport's
    (:func:`lobelight.transport.vertex_origins`), lifted off the surface (the caster's
    offset)."""
    dev = mesh.vertices.device
    start = vertex_origins(mesh, caster=caster).points
    batch = max(1, _RAYS_PER_BATCH // d.shape[0])
    for s in range(0, mesh.n_vertices, batch):
        vi = torch.arange(s, min(mesh.n_vertices, s + batch), device=dev)
        p, n = start[vi], mesh.normals[vi]
        bi, di = ((n @ d.T) > 0).nonzero(as_tuple=True)
        yield vi, bi, di, caster.spawn(p[bi], n[bi], d[di])


def hit_tiles(
    mesh, *, res: int = VISIBILITY_RES, caster: RayCaster | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """What each vertex sees of the object along its octahedral tile's texel centres.

    One ray per texel leaves the vertex's ray origin (as the transport's do) along
    the texel's centre direction; directions below the vertex normal's horizon cast none.

    Parameters
    ----------
    mesh : lobelight.scene.Mesh (V vertices);  res : tile resolution
    caster : the mesh's ray caster (built here when None)

    Returns
    -------
    face : (V, res, res) int32, the triangle hit, -1 where the ray escapes (or is not cast)
    distance : (V, res, res) float16, the distance to the hit along the ray, 0 where none
    """
    res = check_int(res, "res", minimum=2)
    caster = RayCaster(mesh) if caster is None else caster
    dev = mesh.vertices.device
    d = octahedral.texel_directions(res, device=dev).reshape(-1, 3)  # (D, 3) texel centres
    face = torch.full((mesh.n_vertices, d.shape[0]), -1, dtype=torch.int32, device=dev)
    dist = torch.zeros(mesh.n_vertices, d.shape[0], dtype=torch.float16, device=dev)
    for vi, bi, di, o in _rays_above_horizon(mesh, d, caster):
        tri, t, _ = caster.first_hit(o, d[di])
        hit = tri >= 0
        face[vi[bi[hit]], di[hit]] = tri[hit].to(torch.int32)
        dist[vi[bi[hit]], di[hit]] = t[hit].to(torch.float16)
    return face.reshape(-1, res, res), dist.reshape(-1, res, res)
