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
"""

from __future__ import annotations

import torch

from .._checks import check_int
from ..geometry import octahedral
from ..geometry.raycast import RayCaster

__all__ = ["VISIBILITY_RES", "VISIBILITY_SUB", "visibility_tiles"]

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

    Rays leave each vertex (lifted off the surface as the transport's are) along ``sub x sub``
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
    n_dirs = d.shape[0]
    out = torch.zeros(mesh.n_vertices, res * res, dtype=torch.uint8, device=dev)
    batch = max(1, _RAYS_PER_BATCH // n_dirs)
    for s in range(0, mesh.n_vertices, batch):
        vi = torch.arange(s, min(mesh.n_vertices, s + batch), device=dev)
        p, n = mesh.vertices[vi], mesh.normals[vi]
        bi, di = ((n @ d.T) > 0).nonzero(as_tuple=True)  # rays above the horizon
        vis = torch.zeros(vi.shape[0], n_dirs, device=dev)
        o = caster.spawn(p[bi], n[bi], d[di])
        vis[bi, di] = (~caster.occluded(o, d[di])).float()
        frac = vis.reshape(-1, res * res, sub * sub).mean(-1)  # (b, res^2)
        out[vi] = (frac * 255).round().to(torch.uint8)
    return out.reshape(-1, res, res)
