"""The renderer's second path, in torch: the same interpolation and integration as the shaders.

Stage for stage what ``shaders/prt.glsl`` does, so that shader output can be checked against it
(and so that images can be made on any torch device without OpenGL):

1. *vertex stage* (:func:`vertex_stage`): each vertex's own view direction (towards the eye) picks
   the geodesic triangle of views holding it; its three views' Gaussians blend with the
   barycentric weights (:meth:`lobelight.model.Model.transport`); the diffuse colour is the SH
   transfer dotted with the (rotated) lighting's SH coefficients.
2. *pixel stage* (:func:`pixel_stage`): at a pixel, the hit triangle's three vertex Gaussians
   blend with the (perspective-correct) barycentrics of the hit: RGB weights and sigma
   linearly, means linearly then renormalised; each Gaussian is integrated against the lighting
   in one prefiltered lookup at ``R^T mu``; the diffuse colours blend like the weights.

Primary visibility comes from ray casting (Embree); the rasteriser's barycentrics at a pixel
centre are those of the ray through it, so the two paths agree up to rounding.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ..camera import Camera
from ..raycast import RayCaster
from ._lighting import Lighting

__all__ = ["VertexData", "pixel_stage", "render_torch", "vertex_stage"]

#: Pixels shaded per batch (bounds memory at ~1 KB per pixel).
PIXEL_BATCH = 1 << 16


@dataclass(eq=False)
class VertexData:
    """The vertex stage's output for every vertex.

    Attributes
    ----------
    w : (V, N, 3);  mu : (V, N, 3) unit;  sigma : (V, N);  diffuse : (V, 3)
    """

    w: torch.Tensor
    mu: torch.Tensor
    sigma: torch.Tensor
    diffuse: torch.Tensor


def vertex_stage(model, lighting: Lighting, eye, rot: torch.Tensor) -> VertexData:
    """Per-vertex view interpolation and diffuse colour for a camera at ``eye`` (3,)."""
    mesh = model.mesh
    dev = model.device
    eye = torch.as_tensor(eye, dtype=torch.float32, device=dev)
    view = torch.nn.functional.normalize(eye - mesh.vertices.to(dev), dim=-1)  # (V, 3)
    g = model.transport(torch.arange(mesh.n_vertices, device=dev), view)
    shl = lighting.sh_rotated(rot).to(dev)  # (n, 3)
    diffuse = (model.diffuse * shl).sum(-2)  # (V, 3)
    return VertexData(g.w, g.mu, g.lam.rsqrt(), diffuse)


def pixel_stage(
    model,
    lighting: Lighting,
    vd: VertexData,
    tri: torch.Tensor,
    bary: torch.Tensor,
    rot: torch.Tensor,
    *,
    diffuse: bool = True,
    glossy: bool = True,
) -> torch.Tensor:
    """Radiance at surface points given by triangle ids ``tri (P,)`` and barycentrics ``(P, 3)``.

    Returns
    -------
    (P, 3) linear radiance
    """
    dev = model.device
    faces = model.mesh.faces.to(dev)
    out = torch.zeros(tri.shape[0], 3, device=dev)
    for s in range(0, tri.shape[0], PIXEL_BATCH):
        t = tri[s : s + PIXEL_BATCH].to(dev)
        b = bary[s : s + PIXEL_BATCH].to(dev, torch.float32)  # (p, 3)
        c = faces[t]  # (p, 3) corner vertex ids
        acc = torch.zeros(t.shape[0], 3, device=dev)
        if diffuse:
            acc += (vd.diffuse[c] * b[..., None]).sum(1)
        if glossy:
            bw = b[..., None, None]  # (p, 3, 1, 1)
            w = (vd.w[c] * bw).sum(1)  # (p, N, 3)
            mu = torch.nn.functional.normalize((vd.mu[c] * bw).sum(1), dim=-1)
            sigma = (vd.sigma[c] * b[..., None]).sum(1)  # (p, N)
            light = lighting.integrate(mu, sigma.pow(-2), rot).to(dev)  # (p, N, 3)
            acc += (w * light).sum(1)
        out[s : s + PIXEL_BATCH] = acc
    return out


def render_torch(
    model,
    lighting: Lighting,
    camera: Camera,
    width: int,
    height: int,
    *,
    rot: torch.Tensor,
    diffuse: bool = True,
    glossy: bool = True,
    background: bool = True,
    pixels: torch.Tensor | None = None,
    caster: RayCaster | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Render by ray casting and the two stages.

    Parameters
    ----------
    pixels : optional (P, 2) int (row, column): shade only these
    caster : the mesh's ray caster, to reuse its BVH across frames (built here when None)

    Returns
    -------
    image : (H, W, 3), or (P, 3) for ``pixels``;  mask : (H, W) or (P,) bool, object coverage
    """
    dev = model.device
    o, d = camera.rays(width, height)  # (H, W, 3)
    if pixels is not None:
        px = torch.as_tensor(pixels).long().cpu()
        o, d = o[px[:, 0], px[:, 1]], d[px[:, 0], px[:, 1]]
    shape = d.shape[:-1]
    o, d = o.reshape(-1, 3), d.reshape(-1, 3)
    caster = RayCaster(model.mesh, offset=0.0) if caster is None else caster
    tri, _, bary = caster.first_hit(o, d)
    hit = tri >= 0
    vd = vertex_stage(model, lighting, camera.origin, rot)
    img = torch.zeros(o.shape[0], 3, device=dev)
    if background:
        img[~hit.to(dev)] = lighting.background(d[~hit].to(dev), rot).to(dev, torch.float32)
    img[hit.to(dev)] = pixel_stage(
        model, lighting, vd, tri[hit], bary[hit], rot, diffuse=diffuse, glossy=glossy
    )
    return img.reshape(*shape, 3), hit.reshape(shape)
