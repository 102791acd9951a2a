"""The renderer's second path, in torch: the same interpolation and integration as the shaders.

Stage for stage what ``shaders/prt.glsl`` does, so that shader output can be checked against it
(and so that images can be made on any torch device without OpenGL):

1. *vertex stage* (:func:`vertex_stage`): each vertex's own view direction (towards the eye) picks
   the geodesic triangle of views holding it; its three views' Gaussians blend with the
   barycentric weights (:meth:`lobelight.model.Model.transport`); the diffuse colour is the SH
   transfer dotted with the (rotated) lighting's SH coefficients.
2. *pixel stage* (:func:`pixel_stage`): at a pixel, the hit triangle's three vertex Gaussians
   blend with the (perspective-correct) barycentrics of the hit by the same rule
   (:func:`lobelight.model.blend_lobes`: the light each lobe carries linearly, width and mean
   over the live corners), the means as offsets from each corner's mirror direction re-based
   on the point's own; each Gaussian is integrated against the lighting in one prefiltered
   lookup at ``R^T mu``; the diffuse colours blend linearly.

Primary visibility comes from ray casting (:class:`~lobelight.geometry.raycast.RayCaster`:
Embree on the CPU, NVIDIA Warp on a GPU); the rasteriser's barycentrics at a pixel centre are
those of the ray through it, so the two paths agree up to rounding.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from .._tol import DIVISOR_F32
from ..brdf import sharp_lobe
from ..errors import InputError
from ..geometry.camera import Camera
from ..geometry.raycast import RayCaster
from ..lobes import sg
from ..model import blend_lobes
from ._albedo import diffuse_albedo, diffuse_light, specular_ratio
from ._lighting import Lighting
from ._lobe_visibility import lobe_visibility, lobe_visibility_applies
from ._reflection import (
    hit_free_fraction,
    object_light,
    shade,
    sun_sharp,
)
from ._sun_glossy import sun_glossy, sun_glossy_supported, sun_through, tail_scale
from ._sun_shadow import ALL_TAPS, disc_radius, disc_visibility, sample_taps

__all__ = ["VertexData", "pixel_stage", "render_torch", "sun_stage", "vertex_stage"]

#: Pixels shaded per batch (bounds memory at ~1 KB per pixel).
PIXEL_BATCH = 1 << 16
#: Vertices corrected per batch (:mod:`._lobe_visibility`: about 16 KB per vertex, 128 MB).
VERTEX_BATCH = 1 << 13
#: Shadow-ray origins are lifted off the triangle by this fraction of the mesh's diagonal.
_SHADOW_OFFSET = 1e-4


@dataclass(eq=False)
class VertexData:
    """The vertex stage's output for every vertex.

    Attributes
    ----------
    e : (V, N, 3) the light each lobe carries (weight times integral);  mu : (V, N, 3) unit;
    sigma : (V, N);  diffuse : (V, 3) the diffuse transfer times the lighting (per unit
    albedo where the model reads its albedo per pixel);  mirror : (V, 3) each vertex's view
    direction reflected about its normal;  eye : (3,) the camera's position
    """

    e: torch.Tensor
    mu: torch.Tensor
    sigma: torch.Tensor
    diffuse: torch.Tensor
    mirror: torch.Tensor
    eye: torch.Tensor


def mirror_direction(normal: torch.Tensor, view: torch.Tensor) -> torch.Tensor:
    """``2 (n.v) n - v`` for ``n``, ``v`` normalised: (..., 3), the view reflected about n."""
    n = torch.nn.functional.normalize(normal, dim=-1)
    v = torch.nn.functional.normalize(view, dim=-1)
    return 2 * (n * v).sum(-1, keepdim=True) * n - v


def vertex_stage(model, lighting: Lighting, eye, rot: torch.Tensor) -> VertexData:
    """Per-vertex view interpolation and diffuse colour for a camera at ``eye`` (3,)."""
    mesh = model.mesh
    dev = model.device
    eye = torch.as_tensor(eye, dtype=torch.float32, device=dev)
    view = torch.nn.functional.normalize(eye - mesh.vertices.to(dev), dim=-1)  # (V, 3)
    g = model.transport(torch.arange(mesh.n_vertices, device=dev), view)
    shl = lighting.sh_rotated(rot).to(dev)  # (n, 3)
    diffuse = (model.diffuse * shl).sum(-2)  # (V, 3)
    if model.bounce is not None and lighting.sun is not None:
        # the sun's light bounced off the object: its direct light is shaded per pixel
        diffuse = diffuse + (model.bounce * lighting.sun_sh_rotated(rot).to(dev)).sum(-2)
    mirror = mirror_direction(mesh.normals.to(dev), view)  # (V, 3)
    e = g.w * sg.integral(g.lam)[..., None]
    if lobe_visibility_applies(model):
        # the direct lobes' light corrected for what the object blocks (_lobe_visibility.py)
        nd = model.direct_gaussians
        for s in range(0, e.shape[0], VERTEX_BATCH):
            k = slice(s, s + VERTEX_BATCH)
            vid = torch.arange(s, s + e[k].shape[0], device=dev)
            rho = lobe_visibility(model, lighting, vid, view[k], e[k, :nd], g.mu[k, :nd],
                                  g.lam[k, :nd], rot, rest=lighting.sun is not None)  # fmt: skip
            e[k, :nd] *= rho[:, None]
    return VertexData(e, g.mu, g.lam.rsqrt(), diffuse, mirror, eye)


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
    caster: RayCaster | None = None,
    taps: slice = ALL_TAPS,
) -> torch.Tensor:
    """Radiance at surface points given by triangle ids ``tri (P,)`` and barycentrics ``(P, 3)``
    (with the lighting's sun: ``caster`` casts its shadow rays, towards the directions over its
    disc in ``taps``, the sample's share: :func:`lobelight.render._sun_shadow.sample_taps`).

    Returns
    -------
    (P, 3) linear radiance
    """
    dev = model.device
    faces = model.mesh.faces.to(dev)
    out = torch.zeros(tri.shape[0], 3, device=dev)
    # the sun's glossy reflection per pixel where the BRDF allows (the Gaussians then see the
    # map without the sun)
    sun_gl = glossy and lighting.sun is not None and sun_glossy_supported(model.materials.specular)
    sharp = sharp_lobe(model.materials.specular) if glossy else None
    if caster is None and lighting.sun is not None and (diffuse or sun_gl or sharp is not None):
        raise InputError("caster", "the sun's shadow rays need the mesh's RayCaster")
    for s in range(0, tri.shape[0], PIXEL_BATCH):
        t = tri[s : s + PIXEL_BATCH].to(dev)
        b = bary[s : s + PIXEL_BATCH].to(dev, torch.float32)  # (p, 3)
        c = faces[t]  # (p, 3) corner vertex ids
        acc = torch.zeros(t.shape[0], 3, device=dev)
        if diffuse:
            acc += diffuse_light(model, vd.diffuse, c, b)
        if glossy:
            g = _glossy(model, lighting, vd, c, b, rot, sun_gl=sun_gl, sharp=sharp, caster=caster,
                        taps=taps)  # fmt: skip
            ratio = specular_ratio(model, c, b)  # the texels' F0 (glTF textures)
            acc += g if ratio is None else g * ratio.to(dev)
        out[s : s + PIXEL_BATCH] = acc
    if (diffuse or sun_gl) and lighting.sun is not None:
        out += sun_stage(model, lighting, tri, bary, rot, caster, diffuse=diffuse, glossy=sun_gl,
                         eye=vd.eye, taps=taps)  # fmt: skip
    return out


def _glossy(
    model, lighting, vd: VertexData, c, b, rot, *, sun_gl: bool, sharp, caster, taps
) -> torch.Tensor:
    """The Gaussians' glossy light at points of corners ``c (p, 3)`` and barycentrics
    ``b (p, 3)``: (p, 3). With ``sharp`` (:func:`lobelight.brdf.sharp_lobe`) the direct
    part is the material's own lobe at the point's reflected direction, and the object seen
    in it is shaded where it is seen (:mod:`._reflection`); a lobe per vertex
    (:meth:`lobelight.brdf.SharpLobe.at`) does so at its sharp corners, the Gaussians at the
    others, blended with the barycentrics."""
    dev = model.device
    # means blend as offsets from the corners' mirror directions, re-based on the point's own
    # (from its interpolated normal and its view direction)
    pos = (model.mesh.vertices.to(dev)[c] * b[..., None]).sum(1)
    nrm = torch.nn.functional.normalize(
        (model.mesh.normals.to(dev)[c] * b[..., None]).sum(1), dim=-1
    )
    view = torch.nn.functional.normalize(vd.eye - pos, dim=-1)
    r = mirror_direction(nrm, view)
    if sharp is None:
        return _fitted(model, lighting, vd, c, b, r, rot, sun_gl=sun_gl)
    if sharp.sharp is None:
        return _per_pixel(model, lighting, vd, sharp, c, b, pos, nrm, view, r, rot,
                          sun_gl=sun_gl, caster=caster, taps=taps)  # fmt: skip
    ws = (b * sharp.sharp.to(dev)[c]).sum(1)  # the sharp corners' share
    out = torch.zeros_like(pos)
    k = (ws < 1).nonzero().squeeze(-1)
    if k.numel():
        fit = _fitted(model, lighting, vd, c[k], b[k], r[k], rot, sun_gl=sun_gl)
        out[k] = (1 - ws[k, None]) * fit
    k = (ws > 0).nonzero().squeeze(-1)
    if k.numel():
        px = _per_pixel(model, lighting, vd, sharp, c[k], b[k], pos[k], nrm[k], view[k], r[k],
                        rot, sun_gl=sun_gl, caster=caster, taps=taps)  # fmt: skip
        out[k] += ws[k, None] * px
    return out


def _fitted(model, lighting, vd: VertexData, c, b, r, rot, *, sun_gl: bool) -> torch.Tensor:
    """The fitted Gaussians' light at points of corners ``c (p, 3)``, barycentrics
    ``b (p, 3)`` and reflected directions ``r (p, 3)``: (p, 3)."""
    e, mu, sigma = blend_lobes(vd.e[c], vd.mu[c], vd.sigma[c], b, frame=(vd.mirror[c], r))
    # the carried light times the lighting averaged under the lobe: the integral without
    # forming the (up to 1e5) peak weight
    acc = (e * lighting.lookup(mu, sigma.pow(-2), rot, rest=sun_gl).to(e.device)).sum(1)
    ni = model.indirect_gaussians
    if sun_gl and ni:
        # the sun's light reflected off the object into the indirect lobes
        k = slice(model.n_gaussians - ni, None)
        sd = lighting.sun_direction(rot).to(e.device, torch.float32)
        acc += sun_through(e[:, k], mu[:, k], sigma[:, k].pow(-2), sd, lighting.sun).sum(1)
    return acc


def _per_pixel(model, lighting, vd, sharp, c, b, pos, nrm, view, r, rot, *, sun_gl, caster,
               taps):  # fmt: skip
    """The sharp lobe's light at points (:mod:`._reflection`): (p, 3); ``sharp`` the
    material's lobe (one per vertex: taken at the points' sharp corners)."""
    dev = pos.device
    nv = (nrm * view).sum(-1).clamp_min(0)
    lobe = sharp.at(c, b, sharp_only=True)
    # the object seen in the lobe where a corner's hit tile finds it; the environment in the
    # rest of it
    seen, weight, exact = object_light(model, lighting, vd, sharp, lobe, pos, r, nv, c, b, rot,
                                       sun_gl=sun_gl, caster=caster, taps=taps)  # fmt: skip
    found = weight > 0
    vis = torch.where(found, hit_free_fraction(model.hits()[0].to(dev), c, b, r), 1.0)
    vis = torch.where(exact, 0.0, vis)  # the pixel's own ray meets the object
    acc = shade(lobe, lighting, r, nrm, nv, vis, rot, rest=sun_gl).to(dev)
    hit = seen / weight.clamp_min(DIVISOR_F32)[:, None]
    return acc + lobe.directional_albedo(nv) * (1 - vis)[:, None] * hit


def sun_stage(
    model,
    lighting: Lighting,
    tri: torch.Tensor,
    bary: torch.Tensor,
    rot: torch.Tensor,
    caster,
    *,
    diffuse: bool = True,
    glossy: bool = False,
    eye: torch.Tensor | None = None,
    taps: slice = ALL_TAPS,
) -> torch.Tensor:
    """The sun's light at surface points, ``(albedo / pi + f_s(l, v)) E max(n.l, 0) V``: (P, 3),
    its diffuse and (``glossy``, seen from ``eye``) glossy parts; ``V`` from the directions
    over the disc in ``taps`` (the sample's share).

    ``n`` is the interpolated vertex normal (as the shader's), ``V`` the visible fraction of the
    sun's disc: shadow rays over it from the point lifted off the triangle's plane
    (:func:`lobelight.render._sun_shadow.disc_visibility`; the shader filters its shadow map
    over the same directions).
    """
    dev = model.device
    mesh = model.mesh
    f = mesh.faces.to(dev)[tri.to(dev)]  # (P, 3)
    b = bary.to(dev, torch.float32)[..., None]  # (P, 3, 1)
    verts = mesh.vertices.to(dev)
    pos = (verts[f] * b).sum(1)
    n = torch.nn.functional.normalize((mesh.normals.to(dev)[f] * b).sum(1), dim=-1)
    albedo = diffuse_albedo(model, f, b[..., 0])
    l = lighting.sun_direction(rot).to(dev, torch.float32)
    cos = (n @ l).clamp_min(0)  # (P,)
    lit = cos > 0
    out = torch.zeros(tri.shape[0], 3, device=dev)
    if bool(lit.any()):
        t = verts[f[lit]]  # (p, 3, 3)
        ng = torch.nn.functional.normalize(
            torch.linalg.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), dim=-1
        )
        # the visible fraction of the disc (on the device: Warp's rays stay there)
        radius = disc_radius(lighting.sun)
        vis = disc_visibility(caster, pos[lit], ng, l, radius, offset=_SHADOW_OFFSET, taps=taps)
        e = lighting.sun.irradiance.to(dev)
        if diffuse:
            out[lit] = albedo[lit] / math.pi * e * (cos[lit] * vis)[:, None]
        if glossy:
            spec = _sun_specular(model, lighting, pos[lit], n[lit], eye, f[lit], b[lit], rot)
            ratio = specular_ratio(model, f[lit], b[lit, :, 0])
            if ratio is not None:
                spec = spec * ratio.to(dev)
            out[lit] += spec * vis[:, None]
    return out


def _sun_specular(model, lighting, pos, n, eye, corners, b, rot) -> torch.Tensor:
    """The sun's glossy light at lit points before its visibility, (p, 3): the BRDF's highlight
    of the widened disc (:func:`lobelight.render._sun_glossy.sun_glossy`); for a sharp lobe,
    with the sun's shape in the mixture's core (:func:`lobelight.render._reflection.sun_sharp`)."""
    out = sun_glossy(model, lighting, pos, n, eye, corners, b[..., 0], rot)
    sharp = sharp_lobe(model.materials.specular)
    if sharp is None:
        return out
    view = torch.nn.functional.normalize(eye.to(pos.device, pos.dtype) - pos, dim=-1)
    nv = (n * view).sum(-1).clamp_min(0)
    tail = tail_scale(model.materials.specular, lighting.sun.spread)
    r = mirror_direction(n, view)
    if sharp.sharp is None:
        return sun_sharp(sharp, lighting, r, n, nv, rot, out, tail).to(pos.device)
    # a lobe per vertex: the sun's shape at the sharp corners' share, the analytic highlight
    # at the others'
    ws = (b[..., 0] * sharp.sharp.to(pos.device)[corners]).sum(1)
    k = (ws > 0).nonzero().squeeze(-1)
    if k.numel():
        lobe = sharp.at(corners[k], b[k, :, 0], sharp_only=True)
        # tail_scale per point: GGX's widened alpha'^2 = alpha^2 + spread^2 / 4
        a2 = lobe.alpha.to(pos.device)[:, None] ** 2
        tail = a2 / (a2 + float(lighting.sun.spread) ** 2 / 4)
        shaped = sun_sharp(lobe, lighting, r[k], n[k], nv[k], rot, out[k], tail).to(pos.device)
        out[k] = (1 - ws[k, None]) * out[k] + ws[k, None] * shaped
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
    offsets=None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Render by ray casting and the two stages.

    Parameters
    ----------
    pixels : optional (P, 2) int (row, column): shade only these
    caster : the mesh's ray caster, to reuse its BVH across frames (built here when None)
    offsets : optional (S, 2) sub-pixel sample positions in [0, 1) (x right, y down), default
        the pixel centre; the pixel is the mean of its samples (a box filter), as the shader
        path's passes, cast one sample of every pixel at a time (memory of one frame)

    Returns
    -------
    image : (H, W, 3), or (P, 3) for ``pixels``;  coverage : (H, W) or (P,) float32, the
    fraction of the samples that hit the object
    """
    dev = model.device
    off = torch.full((1, 2), 0.5, dtype=torch.float64) if offsets is None else offsets
    off = torch.as_tensor(off, dtype=torch.float64).cpu()
    if off.ndim != 2 or off.shape[1] != 2 or off.shape[0] < 1:
        raise InputError("offsets", f"expected (S, 2) sub-pixel positions, got {tuple(off.shape)}")
    px = None if pixels is None else torch.as_tensor(pixels).long().cpu()
    caster = RayCaster(model.mesh, offset=0.0) if caster is None else caster
    vd = vertex_stage(model, lighting, camera.origin, rot)  # the same for every sample
    img = cov = None
    for i, offset in enumerate(off):
        o, d = camera.rays(width, height, offsets=offset.expand(height, width, 2))  # (H, W, 3)
        if px is not None:
            o, d = o[px[:, 0], px[:, 1]], d[px[:, 0], px[:, 1]]
        shape = d.shape[:-1]
        o, d = o.reshape(-1, 3).to(dev), d.reshape(-1, 3).to(dev)
        tri, _, bary = caster.first_hit(o, d)
        hit = tri >= 0
        one = torch.zeros(o.shape[0], 3, device=dev)
        if background:
            one[~hit.to(dev)] = lighting.background(d[~hit].to(dev), rot).to(dev, torch.float32)
        one[hit.to(dev)] = pixel_stage(
            model, lighting, vd, tri[hit], bary[hit], rot, diffuse=diffuse, glossy=glossy,
            caster=caster, taps=sample_taps(i, off.shape[0]),
        )  # fmt: skip
        if img is None:
            img, cov = one, hit.float()
        else:
            img, cov = img + one, cov + hit.float()
    n = off.shape[0]
    if n > 1:  # the sum of the samples over their count (exact for one sample)
        img, cov = img / n, cov / n
    return img.reshape(*shape, 3), cov.reshape(shape)
