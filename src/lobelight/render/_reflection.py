"""A sharp glossy reflection placed per pixel: the material's own lobe at the pixel's reflected
direction, with the environment's visibility read there and the object seen there.

Per-vertex Gaussians blended from three vertices and three of the 92 stored views cannot place
a mirror's reflection between vertices: a reflected direction turns by twice the view's angle,
so the stored views sample an occluder's edge in the reflection some 40 degrees apart, and a
fitted Gaussian has a GGX lobe's light but not its long tails. For a sharp lobe
(:func:`lobelight.brdf.sharp_lobe`) the renderers shade the *direct* glossy light per pixel
instead:

    E(n.v) * sum_i a_i L(R; lam_i / n.v) * V(R)

``R`` the pixel's view reflected about its interpolated normal; ``E(n.v)`` the lobe's
directional albedo (RGB, Fresnel included; a table over ``n.v`` integrated once from the BRDF);
``a_i, lam_i`` a mixture of five Gaussians fitted once to the lobe's shape at normal incidence;
``L(R; lam)`` the prefiltered lookup (a Phong lobe keeps its width at every view). A microfacet
lobe reflected about the normal is anisotropic: a tilt of the microfacet normal by ``d`` turns
``R`` by ``2 d`` within the plane of incidence and by ``2 (n.v) d`` across it, so the lobe keeps
its width along the plane and narrows by ``n.v`` across it (Wang et al. 2009's warp,
``lam_i / n.v``, is the isotropic lobe of the same solid angle). It is read as two lookups of
the narrow sharpness ``lam_i / (n.v)^2`` at ``R +- s_i t``, ``t`` the plane of incidence's
direction across ``R`` and ``s_i^2 = (1 - (n.v)^2) / lam_i`` the variance the plane's width
adds: the two points carry that variance exactly.

``V`` the visible fraction of the environment in direction ``R``. What the lobe does not see
of the environment is the object itself, shaded where it is seen (:func:`object_light`): each
corner's hit tile (:meth:`lobelight.model.Model.hits`) names the triangle its ray along ``R``'s
texel hits and how far away. The tile's ray leaves from the corner along a texel 6 degrees
wide, the pixel's from the pixel's point along ``R``: the pixel's own ray is walked from the
named triangle across the edge beyond which it crosses each triangle's plane
(:func:`walk_to_hit`, over :attr:`lobelight.scene.Mesh.face_neighbours`) to the triangle it
meets (a corner whose texel finds nothing starts from a triangle its bilinear footprint's
texels find, :func:`footprint_face`: along the silhouette of the object seen in the lobe). Where
a walk arrives (from the corners' triangles in turn, until one does), the pixel's ray meets the
object there, exactly: ``V = 0``, and the hit point is ``q = p + t R``, so that a
reflected edge of the object falls where the pixel's ray puts it. Where none arrives (the ray
runs nearly along a plane, leaves a boundary, or needs more than :data:`HIT_WALK_STEPS`
triangles), where a corner's tile finds the object at ``R``'s texel ``V`` is the share of the
corners' hit-tile texels around ``R`` that find none (bilinear, blended with the
barycentrics), 1 where no corner finds a hit, and each corner's hit point is placed from the
pixel itself, ``q = p + t R`` with ``t`` where the pixel's ray meets the named triangle's plane
(the tile's distance where the ray runs nearly along the plane or crosses it off the
triangle), projected onto the triangle;
there the object's radiance towards the pixel is its direct sharp reflection for the view
``-R`` (as above, with the hit's own visible fraction ``V_hit`` read bilinearly from its
corners' octahedral visibility tiles,
:meth:`lobelight.model.Model.visibility`; each lookup widened by the spread of the directions
the pixel's lobe sees the hit from, :func:`hit_spread`: the pixel integrates the hit's
reflection over its lobe, and a curved hit surface widens that spread further), its diffuse
colour, the sun's light (shadowed) and
its indirect Gaussians, taken from the current view's, re-based on the hit's reflected
direction and rescaled to the hit's occluded fraction ``(1 - V_hit) / (1 - v_fit)``
(:func:`indirect_scale`; ``v_fit`` the stored views' visible fraction, their direct
Gaussians' light over ``E``). The pixel adds ``E(n.v) (1 - V) L_hit``, ``L_hit`` the walked
hit's light, or the corners' hits' light blended with the barycentrics of the corners that
found one.

Supported: the BRDFs the sun is shaded with per pixel (:attr:`lobelight.brdf.BRDF.sun_model`)
with parameters constant over the mesh and a lobe at least as sharp as
:data:`lobelight.brdf.SHARP_LAM`, and the glTF lobe (:class:`lobelight.brdf.GGXSchlick`) whose
roughness and F0 vary per vertex: a pixel is shaded so in the share of its corners that are
that sharp (their lobes blended, :meth:`lobelight.brdf.SharpLobe.at`), by the fitted Gaussians
in the rest, and a hit by its own corners' lobes, sharp or not. Other materials keep the
fitted Gaussians. ``shaders/reflection.glsl`` is the shader's twin.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from .._tol import DIVISOR_F32
from ..brdf import (
    MIXTURE,
    SPLIT_ALPHA_RANGE,
    SPLIT_ALPHAS,
    VARYING_ALPHA_REF,
    SharpLobe,
    varying_reference,
)
from ..geometry import octahedral
from ..model import blend_lobes
from ._albedo import hit_diffuse_light
from ._sun_glossy import sun_glossy, sun_through
from ._sun_shadow import ALL_TAPS, disc_radius, disc_visibility

__all__ = [
    "INDIRECT_SCALE_MAX",
    "OCCLUDED_FLOOR",
    "SHARP_DEFINES",
    "SHARP_NV_MIN",
    "SPREAD_GAUSSIAN",
    "SUN_RESOLVED",
    "face_curvature",
    "hit_free_fraction",
    "hit_spread",
    "indirect_light",
    "indirect_scale",
    "lobe_points",
    "object_light",
    "shade",
    "sharp_shader_defines",
    "sun_shape_resolved",
    "sun_sharp",
    "varying_lobe_arrays",
    "visible_fraction",
    "walk_to_hit",
]

#: The pixel's occluded fraction over the stored views' may rescale the indirect Gaussians by
#: at most this: where the stored views saw no occlusion the indirect Gaussians hold no light
#: to rescale, and a small ``1 - v_fit`` amplifies their noise.
INDIRECT_SCALE_MAX = 4.0
#: The smallest ``n.v`` a microfacet lobe's widths are taken at (a grazing view's lobe does not
#: become a line; :meth:`lobelight.brdf.SharpLobe.sharpness`'s floor).
SHARP_NV_MIN = 0.02
#: A Gaussian of a sharp lobe's mixture resolves the sun's shape where ``lam sigma^2`` is at
#: least this (the Gaussian narrower than twice the disc's RMS angle); a wider one sees a
#: disc and the sun's shape alike (:func:`sun_sharp`).
SUN_RESOLVED = 0.25
#: The Gaussian of a sharp lobe's mixture (sharpest first) whose spread stands for the
#: pixel's lobe where it sees the object (:func:`hit_spread`): the one of the lobe's
#: half-maximum sharpness ``lam0`` (:data:`lobelight.brdf.MIXTURE`).
SPREAD_GAUSSIAN = 1
#: ``1 - v_fit`` floor of the rescaling's divisor.
OCCLUDED_FLOOR = 0.05
#: The pixel's reflected ray meets the plane of the triangle its corner's hit tile names where
#: it crosses the plane at least this steeply (the cosine between ray and plane normal); a ray
#: more nearly along the plane keeps the tile's distance.
HIT_PLANE_COS_MIN = 0.1
#: ... and where that crossing lies on the triangle or near it: no barycentric below minus this.
HIT_PLANE_MARGIN = 0.25
#: Triangles a hit is walked over at most, from the one its corner's hit tile names to the one
#: the pixel's own ray meets (:func:`walk_to_hit`).
HIT_WALK_STEPS = 8
#: Shadow rays from a hit point are lifted off its triangle by this fraction of the mesh's
#: diagonal (as the pixel's own, render/_torch.py).
HIT_SHADOW_OFFSET = 1e-4
#: The constants ``reflection.glsl`` takes as defines, by name: numbers, and the index
#: ``SPREAD_GAUSSIAN`` (an int); :func:`sharp_shader_defines` writes them as shader text.
SHARP_DEFINES = {
    "HIT_PLANE_COS_MIN": HIT_PLANE_COS_MIN,
    "HIT_PLANE_MARGIN": HIT_PLANE_MARGIN,
    "OCCLUDED_FLOOR": OCCLUDED_FLOOR,
    "SHARP_NV_MIN": SHARP_NV_MIN,
    "SUN_RESOLVED": SUN_RESOLVED,
    "INDIRECT_SCALE_MAX": INDIRECT_SCALE_MAX,
    "SPREAD_GAUSSIAN": SPREAD_GAUSSIAN,
    "HIT_WALK_STEPS": HIT_WALK_STEPS,
}


def sharp_shader_defines(
    sharp: SharpLobe | None = None, *, hit_tiles: bool = True
) -> dict[str, str | int]:
    """:data:`SHARP_DEFINES` as a shader loader's defines: numbers in exponent notation,
    the index as it is, and the mixture's size (``MIXTURE``); with the material's lobe
    ``sharp``, also whether it varies per vertex (``SHARP_VARYING``), the split table's
    roughness axis, and the Gaussians of non-zero weight (``SHARP_LIVE``, their indices,
    ``MIXTURE_LIVE`` of them: a Phong lobe is one of the five); ``hit_tiles``: whether any
    vertex's hit tile finds the object (``HIT_TILES``; without, the hits' shading is compiled
    out). The loops over the live Gaussians alone, and the hits' code left out, matter on a
    rasteriser that runs every branch of a shader for every pixel (SwiftShader, llvmpipe)."""
    out = {k: x if isinstance(x, int) else f"{x:.6e}" for k, x in SHARP_DEFINES.items()}
    out["MIXTURE"] = MIXTURE
    out["HIT_TILES"] = int(hit_tiles)
    live = list(range(MIXTURE))
    if sharp is not None:
        out["SHARP_VARYING"] = int(sharp.sharp is not None)
        out["VARYING_ALPHA_REF"] = f"{VARYING_ALPHA_REF:.6e}"
        out["SPLIT_ALPHAS"] = SPLIT_ALPHAS
        out["SPLIT_ALPHA_MIN"] = f"{SPLIT_ALPHA_RANGE[0]:.6e}"
        out["SPLIT_ALPHA_MAX"] = f"{SPLIT_ALPHA_RANGE[1]:.6e}"
        live = [i for i, w in enumerate(sharp.weights.tolist()) if w != 0.0] or [0]
    out["MIXTURE_LIVE"] = len(live)
    out["SHARP_LIVE"] = ", ".join(str(i) for i in live)
    return out


def sun_shape_resolved(sharp: SharpLobe, spread: float) -> bool:
    """Whether a Gaussian of the mixture's of non-zero weight resolves a sun of RMS angle
    ``spread`` (radians) at some point (``lam_i sigma^2 >=`` :data:`SUN_RESOLVED`; a lobe
    varying per vertex at its sharpest vertex, which bounds every point's): then the renderers
    read the sun's shape from the whole map's chain (:func:`sun_sharp`; the shaders' ``sun_shape``
    compiled with ``SUN_SHAPE``), else its disc alone."""
    live = sharp.weights != 0
    return bool((sharp.lam[..., live] * spread**2 >= SUN_RESOLVED).any())


def varying_lobe_arrays(sharp: SharpLobe) -> tuple[list[float], np.ndarray, np.ndarray]:
    """What the shaders read of a lobe varying per vertex (``reflection.glsl`` ``lobe_at``):
    the mixture's sharpness at :data:`lobelight.brdf.VARYING_ALPHA_REF` (M floats), each
    vertex's roughness (negative where the fitted Gaussians shade it) and F0, ``(V, 4)``
    float32, and the albedo's split table by roughness, ``(S, T, 2)`` float32."""
    lam = varying_reference().lam
    sign = torch.where(sharp.sharp, 1.0, -1.0)
    lobe = torch.cat([(sign * sharp.alpha)[:, None], sharp.f0], 1).cpu().numpy()
    split = sharp.split.permute(1, 0, 2).contiguous().cpu().numpy()
    return [float(x) for x in lam], lobe.astype(np.float32), split.astype(np.float32)


def lobe_points(sharp: SharpLobe, r: torch.Tensor, n: torch.Tensor, nv: torch.Tensor,
                blur: torch.Tensor | None = None):  # fmt: skip
    """Where and how sharply :func:`shade` reads the lighting (module docstring); ``blur``
    (P,), where given, a variance added to every lookup's (a Gaussian spread of the
    directions the lobe is seen from: :func:`hit_spread`).

    Returns
    -------
    dirs : (K, P, M, 3) unit directions, K = 2 points across the plane of incidence for a
        microfacet lobe, 1 for a lobe that keeps its width about ``R``
    lam : (P, M) their sharpness
    weights : (M,) the mixture's weights; each of the K points carries ``1 / K`` of them
    """
    w = sharp.weights.to(r.device)
    m = w.shape[0]
    if not sharp.warp:
        return r[None, :, None].expand(1, -1, m, 3), _blurred(sharp.sharpness(nv), blur), w
    lam0 = sharp.lam.to(r.device)  # (M,), or (P, M) for a lobe per point
    c = nv.clamp_min(SHARP_NV_MIN)[:, None]  # (P, 1)
    lam = lam0 / c**2  # (P, M) the width across the plane of incidence
    s = ((1 - c**2).clamp_min(0) / lam0).sqrt()  # (P, M)
    t = torch.nn.functional.normalize(n - (n * r).sum(-1, keepdim=True) * r, dim=-1)  # (P, 3)
    step = s[..., None] * t[:, None]  # (P, M, 3)
    d = torch.nn.functional.normalize(torch.stack([r[:, None] + step, r[:, None] - step]), dim=-1)
    return d, _blurred(lam, blur), w


def _blurred(lam: torch.Tensor, blur: torch.Tensor | None) -> torch.Tensor:
    """Sharpness ``lam (P, M)`` of Gaussians convolved with one of variance ``blur (P,)``:
    ``1 / (1 / lam + blur)`` (small-angle Gaussians' variances add)."""
    if blur is None:
        return lam
    return 1 / (1 / lam.clamp_min(DIVISOR_F32) + blur[:, None])


def hit_spread(sharp: SharpLobe, nv: torch.Tensor, dist: torch.Tensor,
               curvature: torch.Tensor) -> torch.Tensor:  # fmt: skip
    """The variance of the directions a hit's own reflection is seen from (P,): the pixel's
    lobe spreads its rays about ``R`` by the variance of its core Gaussian (the mixture's
    :data:`SPREAD_GAUSSIAN`, widened by ``1 / n.v`` for a microfacet lobe, its isotropic
    equivalent); a flat mirror at the hit keeps that spread in the rays it reflects, and a
    curved one turns them further, by twice its normal's turn over the footprint,
    ``2 curvature dist`` per radian: ``var (1 + 2 curvature dist)^2``. ``sharp`` the pixel's
    lobe (one, or one per pixel: :meth:`lobelight.brdf.SharpLobe.at`), ``nv (P,)`` the pixel's
    ``n.v``, ``dist (P,)`` the hit's distance, ``curvature (P,)`` the hit's (radians per unit
    length, :func:`face_curvature`)."""
    var = 1 / sharp.lam[..., SPREAD_GAUSSIAN].to(nv.device)
    if sharp.warp:
        var = var / nv.clamp_min(SHARP_NV_MIN)
    return var * (1 + 2 * curvature * dist) ** 2


def face_curvature(pos: torch.Tensor, nrm: torch.Tensor) -> torch.Tensor:
    """A triangle's curvature (P,), radians per unit length: the mean over its edges of the
    corners' normals' turn over the edge's length; ``pos, nrm (P, 3, 3)`` its corners'
    positions and unit normals (zero on a flat triangle)."""
    k = pos.new_zeros(pos.shape[0])
    for i, j in ((0, 1), (1, 2), (2, 0)):
        turn = (nrm[:, i] - nrm[:, j]).norm(dim=-1)
        k = k + turn / (pos[:, i] - pos[:, j]).norm(dim=-1).clamp_min(DIVISOR_F32)
    return k / 3


def shade(sharp: SharpLobe, lighting, r: torch.Tensor, n: torch.Tensor, nv: torch.Tensor,
          vis: torch.Tensor, rot, *, rest: bool,
          blur: torch.Tensor | None = None) -> torch.Tensor:  # fmt: skip
    """``E(n.v) sum_i a_i L(R; lam_i) V`` (module docstring: two lookups across the plane of
    incidence for a microfacet lobe): (P, 3) for reflected directions ``r (P, 3)`` about
    shading normals ``n (P, 3)``, ``nv (P,)``, visible fractions ``vis (P,)``; ``rest``: the
    map without its sun; ``blur`` as :func:`lobe_points`'."""
    d, lam, w = lobe_points(sharp, r, n, nv, blur)
    look = lighting.lookup(d, lam.expand(d.shape[0], -1, -1), rot, rest=rest)  # (K, P, M, 3)
    mixed = (look.mean(0) * w[:, None]).sum(1)
    return sharp.directional_albedo(nv) * mixed * vis[:, None]


def sun_sharp(sharp: SharpLobe, lighting, r: torch.Tensor, n: torch.Tensor, nv: torch.Tensor,
              rot, analytic: torch.Tensor, tail: float) -> torch.Tensor:  # fmt: skip
    """The sun's glossy light off a sharp lobe, before its visibility: (P, 3), docs/method.md
    equation 12, ``[tail (A - D) + S]+``.

    A sun taken out of the map is a disc to the shadows and to rough lobes, but a sharp lobe
    sees its shape: a studio's softbox or a window is a rectangle with hard edges, and the
    lobe is narrower than it. ``A (P, 3)`` is the BRDF's analytic highlight of the widened
    disc (:func:`lobelight.render._sun_glossy.sun_glossy`), whose long tail the mixture lacks,
    ``tail`` its tail's factor (:func:`lobelight.render._sun_glossy.tail_scale`). ``D`` is what
    :func:`shade`'s lookups would read of the sun were it the Gaussian disc: per lookup of
    sharpness ``lam`` at ``d``, ``E lam' / (2 pi) exp(lam' (d.l - 1))``, ``1 / lam' = 1 / lam +
    sigma^2 / 2`` (two small-angle Gaussians convolved). ``S`` is what they read of the sun's
    own pixels: the whole map's chain less the chain without the sun (the chains are linear in
    the map: the sun's excess over its surroundings, prefiltered), for the mixture's Gaussians
    that resolve the disc (``lam_i sigma^2 >=`` :data:`SUN_RESOLVED`); a wider Gaussian sees
    the disc and the shape alike, and reads ``D`` for ``S`` (no lookup)."""
    d, lam, w = lobe_points(sharp, r, n, nv)
    sun = lighting.sun
    s2 = float(sun.spread) ** 2
    lw = 1 / (1 / lam.clamp_min(DIVISOR_F32) + s2 / 2)  # (P, M)
    chord = (d - lighting.sun_direction(rot).to(d.device, d.dtype)).pow(2).sum(-1)  # (K, P, M)
    disc = (lw / (2 * math.pi) * torch.exp(-0.5 * lw * chord)).mean(0) * w  # (P, M)
    albedo = sharp.directional_albedo(nv)
    e = sun.irradiance.to(d.device, d.dtype)
    res = (sharp.lam.to(d.device) * s2 >= SUN_RESOLVED).expand_as(disc)  # (P, M)
    out = tail * (analytic - albedo * disc.sum(1)[:, None] * e)
    out = out + albedo * (disc * ~res).sum(1)[:, None] * e
    cols = res.any(0)  # the Gaussians that resolve the disc at some point
    if bool(cols.any()):
        dr, lr = d[:, :, cols], lam[:, cols].expand(d.shape[0], -1, -1)
        whole = lighting.lookup(dr, lr, rot, rest=False)  # (K, P, m, 3)
        rest = lighting.lookup(dr, lr, rot, rest=True)
        shape = (whole - rest).mean(0) * (w[cols] * res[:, cols])[..., None]
        out = out + albedo * shape.sum(1).clamp_min(0)
    return out.clamp_min(0)


def visible_fraction(tiles: torch.Tensor, corners: torch.Tensor, bary: torch.Tensor,
                     r: torch.Tensor) -> torch.Tensor:  # fmt: skip
    """``V(R)``: the corners' visibility tiles read at ``r (P, 3)`` and blended with
    ``bary (P, 3)``; ``tiles (V, R, R)`` uint8, ``corners (P, 3)``: (P,) in [0, 1]."""
    v = octahedral.bilinear(tiles, corners, r[:, None].expand(-1, 3, 3)) / 255.0  # (P, 3)
    return (v * bary).sum(-1)


def footprint_face(face: torch.Tensor, tile: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
    """A triangle the texels of the hit tiles ``face (V, R, R)`` (indexed by ``tile (P,)``)
    around ``r (P, 3)`` find: the first of the bilinear footprint's four texels that finds one,
    in the order :func:`hit_free_fraction` reads them, -1 where none does: (P,) int64."""
    x, y, _, _ = octahedral.footprint(r, face.shape[-1])
    out = torch.full(r.shape[:-1], -1, dtype=torch.long, device=r.device)
    for dy, dx in ((1, 1), (1, 0), (0, 1), (0, 0)):  # the first in reading order wins
        f = face[tile, y + dy, x + dx].long()
        out = torch.where(f >= 0, f, out)
    return out


def hit_free_fraction(face: torch.Tensor, corners: torch.Tensor, bary: torch.Tensor,
                      r: torch.Tensor) -> torch.Tensor:  # fmt: skip
    """``V(R)`` where the lobe finds the object: the share of the corners' hit tiles' texels
    around ``r (P, 3)`` that find no hit, bilinear and blended with ``bary (P, 3)``; ``face
    (V, R, R)`` the hit tiles' triangle ids (-1: none), ``corners (P, 3)``: (P,) in [0, 1]."""
    free = octahedral.bilinear(face, corners, r[:, None].expand(-1, 3, 3), lambda t: t < 0)
    return (free * bary).sum(-1)


def indirect_scale(direct_light: torch.Tensor, albedo: torch.Tensor, vis: torch.Tensor):
    """The indirect Gaussians' factor ``(1 - V) / (1 - v_fit)`` (module docstring), (P,).

    direct_light : (P, 3) the blended direct Gaussians' carried light;  albedo : (P, 3)
    ``E(n.v)``;  vis : (P,) the pixel's visible fraction
    """
    v_fit = (direct_light.mean(-1) / albedo.mean(-1).clamp_min(DIVISOR_F32)).clamp(0, 1)
    return ((1 - vis) / (1 - v_fit).clamp_min(OCCLUDED_FLOOR)).clamp(0, INDIRECT_SCALE_MAX)


def indirect_light(model, lighting, e, mu, sigma, rot, *, sun_gl: bool):
    """The light of indirect Gaussians carrying ``e (P, K, 3)`` about ``mu (P, K, 3)`` of width
    ``sigma (P, K)``: (P, 3), with the sun's light through them when it is shaded per pixel."""
    lam = sigma.pow(-2)
    acc = (e * lighting.lookup(mu, lam, rot, rest=sun_gl).to(e.device)).sum(1)
    if sun_gl and e.shape[1]:
        sd = lighting.sun_direction(rot).to(e.device, torch.float32)
        acc += sun_through(e, mu, lam, sd, lighting.sun).sum(1)
    return acc


def _barycentrics(tri: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
    """Barycentrics ``(P, 3)`` of points ``q (P, 3)`` projected onto the planes of triangles
    ``tri (P, 3, 3)``, unclamped (negative off the triangle)."""
    a = tri[:, 0]
    e1, e2, w = tri[:, 1] - a, tri[:, 2] - a, q - a
    n = torch.linalg.cross(e1, e2)
    inv = 1 / (n * n).sum(-1).clamp_min(DIVISOR_F32)
    b1 = (torch.linalg.cross(w, e2) * n).sum(-1) * inv
    b2 = (torch.linalg.cross(e1, w) * n).sum(-1) * inv
    return torch.stack([1 - b1 - b2, b1, b2], -1)


def _project(tri: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
    """Barycentrics ``(P, 3)`` of points ``q (P, 3)`` projected onto triangles ``tri (P, 3, 3)``,
    clamped to the triangle (a hit placed from the pixel may fall just past its edge)."""
    b = _barycentrics(tri, q).clamp_min(0)
    return b / b.sum(-1, keepdim=True).clamp_min(DIVISOR_F32)


def _plane_distance(mesh, tri, p, r, t):
    """How far the rays from ``p (P, 3)`` along ``r (P, 3)`` go to the planes of triangles
    ``tri (P,)``: ``(P,)``; the tiles' distances ``t (P,)`` where a ray runs nearly along its
    plane (:data:`HIT_PLANE_COS_MIN`), meets it behind ``p``, or crosses it off the triangle
    (:data:`HIT_PLANE_MARGIN`: the ray hits another triangle there). A tile's texel is 6 degrees
    wide and its distance the ray's from the corner along the texel's centre: the hit point
    placed by the pixel's own ray moves over the triangle as the pixel's reflection does,
    where a distance held over the texel would place it in blocks."""
    v = mesh.vertices[mesh.faces[tri]]  # (P, 3, 3)
    n = torch.linalg.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    rn = (r * n).sum(-1)
    t_plane = ((v[:, 0] - p) * n).sum(-1) / torch.where(rn.abs() > 0, rn, 1.0)
    steep = rn.abs() >= HIT_PLANE_COS_MIN * r.norm(dim=-1) * n.norm(dim=-1)
    # the crossing on the triangle or near it
    near = _barycentrics(v, p + t_plane[:, None] * r).amin(-1) >= -HIT_PLANE_MARGIN
    return torch.where(steep & (t_plane > 0) & near, t_plane, t)


def walk_to_hit(mesh, neighbours: torch.Tensor, f: torch.Tensor, p: torch.Tensor,
                r: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:  # fmt: skip
    """The triangles the rays from ``p (P, 3)`` along ``r (P, 3)`` meet, found by walking from
    triangles ``f (P,)`` across the edge beyond which each ray crosses the current triangle's
    plane (``neighbours (F, 3)``, :func:`lobelight.geometry.adjacency.face_neighbours`), at most
    :data:`HIT_WALK_STEPS` triangles. A corner's hit tile names the triangle its own ray along
    the tile texel's centre hits; the pixel's ray, from another point and 3 degrees off at
    most, meets that triangle or one a few triangles away on the same surface.

    Returns
    -------
    arrived : (P,) bool, where the walk arrived: not where a ray runs nearly along a plane
        (:data:`HIT_PLANE_COS_MIN`) or meets it behind ``p``, an edge has no neighbour, the
        steps run out, or the triangle arrived at faces away from the ray (its corners'
        normals summed on the ray's side)
    tri : (P,) the triangle arrived at (where ``arrived``)
    t : (P,) the distance along the ray to it (where ``arrived``)
    """
    g = f.to(torch.long, copy=True)
    t = torch.zeros(p.shape[0], dtype=p.dtype, device=p.device)
    arrived = torch.zeros(p.shape[0], dtype=torch.bool, device=p.device)
    live = torch.arange(p.shape[0], device=p.device)
    for _ in range(HIT_WALK_STEPS):
        if live.numel() == 0:
            break
        c = mesh.faces[g[live]]
        v = mesh.vertices[c]  # (L, 3, 3)
        rl, pl = r[live], p[live]
        n = torch.linalg.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        rn = (rl * n).sum(-1)
        # (a triangle of no area has no plane to cross)
        steep = (rn != 0) & (rn.abs() >= HIT_PLANE_COS_MIN * rl.norm(dim=-1) * n.norm(dim=-1))
        tl = ((v[:, 0] - pl) * n).sum(-1) / torch.where(rn != 0, rn, 1.0)
        ok = steep & (tl > 0)
        m, i = _barycentrics(v, pl + tl[:, None] * rl).min(-1)  # the first minimum, as GLSL
        inside = ok & (m >= 0)
        front = (mesh.normals[c].sum(1) * rl).sum(-1) < 0
        arrived[live[inside & front]] = True
        t[live] = tl
        step = ok & ~inside
        nb = neighbours[g[live[step]], i[step]]
        g[live[step]] = nb
        live = live[step][nb >= 0]
    return arrived, g, t


def _hit_light(model, lighting, vd, sharp, tri, q, r, rot, *, sun_gl, caster, blur, taps):
    """The object's radiance towards ``-r`` at points ``q`` near triangles ``tri`` (module
    docstring), its own sharp reflection blurred by the pixel's lobe (:func:`hit_spread`;
    ``blur`` the pixel's lobe, its ``n.v (P,)`` and the hit's distance ``(P,)``): (P, 3)."""
    mesh = model.mesh
    c = mesh.faces[tri]  # (P, 3)
    corner_pos = mesh.vertices[c]
    corner_nrm = mesh.normals[c]
    b = _project(corner_pos, q)
    pos = (corner_pos * b[..., None]).sum(1)
    n = torch.nn.functional.normalize((corner_nrm * b[..., None]).sum(1), dim=-1)
    v = -r
    nv = (n * v).sum(-1)
    rh = 2 * nv[:, None] * n - v
    nv = nv.clamp_min(0)
    vis = visible_fraction(model.visibility(), c, b, rh)
    lobe = sharp.at(c, b)  # the hit's own lobe
    albedo = lobe.directional_albedo(nv)
    spread = hit_spread(*blur, face_curvature(corner_pos, corner_nrm))
    out = shade(lobe, lighting, rh, n, nv, vis, rot, rest=sun_gl, blur=spread)
    out += hit_diffuse_light(model, vd.diffuse, c, b)
    e, mu, sigma = blend_lobes(vd.e[c], vd.mu[c], vd.sigma[c], b, frame=(vd.mirror[c], rh))
    k = slice(model.n_gaussians - model.indirect_gaussians, None)
    e = e[:, k] * indirect_scale(e[:, : model.direct_gaussians].sum(1), albedo, vis)[:, None, None]
    out += indirect_light(model, lighting, e, mu[:, k], sigma[:, k], rot, sun_gl=sun_gl)
    if lighting.sun is not None:
        out += _hit_sun(model, lighting, c, b, pos, n, v, rot, sun_gl=sun_gl, caster=caster,
                        taps=taps)  # fmt: skip
    return out


def _hit_sun(model, lighting, c, b, pos, n, v, rot, *, sun_gl, caster, taps):
    """The sun's light leaving hit points towards ``v (P, 3)``: its diffuse part, and its glossy
    part where it is shaded per pixel, times the disc's visible fraction: (P, 3)."""
    l = lighting.sun_direction(rot).to(pos.device, torch.float32)
    cos = (n @ l).clamp_min(0)
    out = torch.zeros_like(pos)
    lit = cos > 0
    if not bool(lit.any()):
        return out
    t = model.mesh.vertices[c[lit]]
    ng = torch.nn.functional.normalize(
        torch.linalg.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), dim=-1
    )
    vis = disc_visibility(caster, pos[lit], ng, l, disc_radius(lighting.sun),
                          offset=HIT_SHADOW_OFFSET, taps=taps)  # fmt: skip
    albedo = (model.materials.diffuse.to(pos.device)[c[lit]] * b[lit][..., None]).sum(1)
    light = albedo / math.pi * (lighting.sun.irradiance.to(pos.device) * cos[lit, None])
    if sun_gl:
        # the viewer of a hit is the pixel: eye = hit + v
        light = light + sun_glossy(
            model, lighting, pos[lit], n[lit], pos[lit] + v[lit], c[lit], b[lit], rot
        )
    out[lit] = light * vis[:, None]
    return out


def object_light(model, lighting, vd, sharp, pixel, pos, r, nv, corners, bary, rot, *, sun_gl,
                 caster, taps=ALL_TAPS):  # fmt: skip
    """The object's radiance seen along the reflected directions ``r (P, 3)`` from points
    ``pos (P, 3)`` (``n.v`` ``nv (P,)``) of triangles with ``corners (P, 3)`` and barycentrics
    ``bary (P, 3)``, from the corners' hit tiles (module docstring). ``sharp`` the material's
    lobe (:func:`lobelight.brdf.sharp_lobe`; one per vertex for a glTF lobe varying over the
    mesh: each hit's taken from the hit's corners), ``pixel`` the points' own
    (``sharp.at(corners, bary, sharp_only=True)``), whose spread blurs the hits; the hits' sun
    shadows take the directions over its disc in ``taps`` (the sample's share).

    Where the pixel's own ray, walked from a corner's hit triangle (:func:`walk_to_hit`; the
    corners in turn, until a walk arrives), arrives at a triangle, the object is seen there,
    and the pixel sees the object in the whole lobe; elsewhere the corners' hits are blended.

    Returns
    -------
    light : (P, 3), the exact hit's light where ``exact``, else the corners' hits' light
        weighted by their barycentrics, summed
    weight : (P,), 1 where ``exact``, else the barycentric weight of the corners that found
        a hit
    exact : (P,) bool, where the pixel's own ray meets the object (its lobe sees no
        environment)
    """
    tiles, dist = model.hits()
    res = tiles.shape[-1]
    texel = octahedral.nearest_texel(r, res)  # (P,)
    face, dist = tiles.reshape(tiles.shape[0], -1), dist.reshape(dist.shape[0], -1)
    light = torch.zeros_like(pos)
    weight = torch.zeros(pos.shape[0], device=pos.device)
    found = [face[corners[:, i], texel].long() for i in range(3)]
    exact = torch.zeros(pos.shape[0], dtype=torch.bool, device=pos.device)
    tri = torch.zeros(pos.shape[0], dtype=torch.long, device=pos.device)
    near = torch.zeros(pos.shape[0], dtype=pos.dtype, device=pos.device)
    neighbours = model.mesh.face_neighbours
    for i in range(3):  # the pixel's own ray, walked from each corner's triangle in turn
        # a corner whose texel at r finds nothing starts from a triangle its neighbouring
        # texels find: along the silhouette of the object seen in the lobe
        start = found[i].clone()
        m = (start < 0) & (bary[:, i] > 0)
        if bool(m.any()):
            start[m] = footprint_face(tiles, corners[m, i], r[m])
        h = ((start >= 0) & (bary[:, i] > 0) & ~exact).nonzero().squeeze(-1)
        if h.numel() == 0:
            continue
        arrived, g, t = walk_to_hit(model.mesh, neighbours, start[h], pos[h], r[h])
        exact[h[arrived]], tri[h[arrived]], near[h[arrived]] = True, g[arrived], t[arrived]
    e = exact.nonzero().squeeze(-1)
    if e.numel():
        light[e] = _hit_light(
            model, lighting, vd, sharp, tri[e], pos[e] + near[e, None] * r[e], r[e], rot,
            sun_gl=sun_gl, caster=caster, blur=(pixel.take(e), nv[e], near[e]), taps=taps,
        )  # fmt: skip
        weight[e] = 1.0
    for i in range(3):  # the triangle's corners, where no walk arrived
        f = found[i]
        h = ((f >= 0) & (bary[:, i] > 0) & ~exact).nonzero().squeeze(-1)
        if h.numel() == 0:
            continue
        t = _plane_distance(model.mesh, f[h], pos[h], r[h], dist[corners[h, i], texel[h]].float())
        q = pos[h] + t[:, None] * r[h]
        blur = (pixel.take(h), nv[h], t)
        hit = _hit_light(
            model, lighting, vd, sharp, f[h], q, r[h], rot, sun_gl=sun_gl, caster=caster,
            blur=blur, taps=taps,
        )  # fmt: skip
        light[h] += bary[h, i, None] * hit
        weight[h] += bary[h, i]
    return light, weight.clamp(0, 1), exact
