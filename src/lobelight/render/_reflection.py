"""A sharp glossy reflection placed per pixel: the material's own lobe at the pixel's reflected
direction, with the environment's visibility read there.

Per-vertex Gaussians blended from three vertices and three of the 92 stored views cannot place
a mirror's reflection between vertices: a reflected direction turns by twice the view's angle,
so the stored views sample an occluder's edge in the reflection some 40 degrees apart, and a
fitted Gaussian has a GGX lobe's light but not its long tails. For a sharp lobe
(:func:`sharp_reflection`) the renderers shade the *direct* glossy light per pixel instead:

    E(n.v) * sum_i a_i L(R; lam_i / n.v) * V(R)

``R`` the pixel's view reflected about its interpolated normal; ``E(n.v)`` the lobe's
directional albedo (RGB, Fresnel included; a table over ``n.v`` integrated once from the BRDF);
``a_i, lam_i`` a mixture of four Gaussians fitted once to the lobe's shape at normal incidence
and widened with ``1 / n.v`` as a microfacet lobe widens towards grazing angles (Wang et al.
2009's warp; a Phong lobe keeps its width); ``L(R; lam)`` the prefiltered lookup; ``V(R)`` the
visible fraction of the environment in direction ``R``, read bilinearly from each corner's
octahedral visibility tile (:meth:`lobelight.model.Model.visibility`) and blended with the
barycentrics. What the lobe does not see is the object itself: the model's indirect Gaussians
carry that light, fitted where the stored views' visible fraction ``v_fit`` (their direct
Gaussians' light over ``E``) left it; :func:`indirect_scale` rescales them to the pixel's own
occluded fraction ``(1 - V) / (1 - v_fit)``.

Supported: the BRDFs the sun is shaded with per pixel (:attr:`lobelight.brdf.BRDF.sun_model`)
with parameters constant over the mesh and a lobe at least as sharp as :data:`SHARP_LAM`;
other materials keep the fitted Gaussians. ``shaders/reflection.glsl`` is the shader's twin.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import torch

from .._tol import DIVISOR_F32
from ..geometry import octahedral

__all__ = [
    "ALBEDO_SAMPLES",
    "ALBEDO_STEPS",
    "INDIRECT_SCALE_MAX",
    "MIXTURE",
    "OCCLUDED_FLOOR",
    "SHARP_LAM",
    "SharpReflection",
    "indirect_scale",
    "sharp_reflection",
    "sharp_reflection_for",
    "visible_fraction",
]

#: Gaussians in the lobe's shape mixture, sharpness ``lam0 * 4, lam0, lam0 / 4, lam0 / 16``:
#: a GGX lobe's tail holds a third of its light beyond where one Gaussian of its width reaches.
MIXTURE = 4
#: The sharpest lobe kept in fitted Gaussians: lobes whose half-maximum sharpness ``lam0`` is
#: at least this (a GGX or Beckmann alpha up to about 0.065) are shaded per pixel. Measured
#: better per pixel at alpha 0.03 (docs/results.md); wider lobes keep the fitted Gaussians,
#: which match the references there.
SHARP_LAM = 200.0
#: Entries of the directional-albedo table over ``n.v`` in ``(0, 1]``.
ALBEDO_STEPS = 64
#: Importance samples per table entry (a stratified grid: the table's error is far below a
#: percent for the lobes shaded here).
ALBEDO_SAMPLES = 64
#: The pixel's occluded fraction over the stored views' may rescale the indirect Gaussians by
#: at most this: where the stored views saw no occlusion the indirect Gaussians hold no light
#: to rescale, and a small ``1 - v_fit`` amplifies their noise.
INDIRECT_SCALE_MAX = 4.0
#: ``1 - v_fit`` floor of the rescaling's divisor.
OCCLUDED_FLOOR = 0.05


@dataclass(frozen=True)
class SharpReflection:
    """The per-pixel lobe of one material (module docstring).

    Attributes
    ----------
    weights : (M,) the shape mixture's share of light per Gaussian (sum 1)
    lam : (M,) their sharpness at normal incidence
    warp : whether the sharpness divides by ``n.v`` (microfacet and Blinn-Phong lobes)
    albedo : (T, 3) directional albedo at ``n.v = (k + 0.5) / T``
    """

    weights: torch.Tensor
    lam: torch.Tensor
    warp: bool
    albedo: torch.Tensor

    def directional_albedo(self, nv: torch.Tensor) -> torch.Tensor:
        """``E(n.v)``: (..., 3), linear in the table (clamped at its ends)."""
        t = self.albedo.shape[0]
        x = (nv.clamp(0, 1) * t - 0.5).clamp(0, t - 1)
        i0 = x.floor().long().clamp(max=t - 2)
        f = (x - i0)[..., None]
        a = self.albedo.to(nv.device)
        return a[i0] * (1 - f) + a[i0 + 1] * f

    def sharpness(self, nv: torch.Tensor) -> torch.Tensor:
        """(..., M) the mixture's sharpness at ``n.v`` (floored at 0.02: a grazing view's lobe
        does not become a point)."""
        lam = self.lam.to(nv.device)
        if not self.warp:
            return lam.expand(*nv.shape, -1)
        return lam / nv.clamp_min(0.02)[..., None]

    def shade(self, lighting, r: torch.Tensor, nv: torch.Tensor, vis: torch.Tensor, rot, *,
              rest: bool) -> torch.Tensor:  # fmt: skip
        """``E(n.v) sum_i a_i L(R; lam_i) V``: (P, 3) for reflected directions ``r (P, 3)``,
        ``nv (P,)``, visible fractions ``vis (P,)``; ``rest``: the map without its sun."""
        lam = self.sharpness(nv)  # (P, M)
        m = lam.shape[-1]
        look = lighting.lookup(r[:, None].expand(-1, m, 3), lam, rot, rest=rest)  # (P, M, 3)
        mixed = (look * self.weights.to(r.device)[:, None]).sum(1)
        return self.directional_albedo(nv) * mixed * vis[:, None]


def sharp_reflection(spec) -> SharpReflection | None:
    """The per-pixel lobe of a specular BRDF, or None where it is not supported (module
    docstring): no BRDF, no shader formula, parameters varying over the mesh, or a lobe
    wider than :data:`SHARP_LAM`."""
    if spec is None or spec.sun_model is None or spec.per_element_params:
        return None
    spec = spec.to("cpu", torch.float64)
    lam0 = _half_max_sharpness(spec)
    if lam0 < SHARP_LAM:
        return None
    lam = torch.tensor([lam0 * 4.0 ** (1 - i) for i in range(MIXTURE)], dtype=torch.float64)
    weights = _shape_mixture(spec, lam)
    return SharpReflection(
        weights=weights.float(),
        lam=lam.float(),
        warp=spec.sun_model != 2,  # modified Phong's lobe keeps its width about R
        albedo=_albedo_table(spec).float(),
    )


#: :func:`sharp_reflection_for`'s results by material (a frame must not integrate the tables
#: again; materials are few).
_CACHE: dict[str, SharpReflection | None] = {}


def sharp_reflection_for(spec) -> SharpReflection | None:
    """:func:`sharp_reflection`, kept per material (by its parameters) for later frames."""
    if spec is None:
        return None
    key = json.dumps(spec.to_dict(), sort_keys=True)
    if key not in _CACHE:
        _CACHE[key] = sharp_reflection(spec)
    return _CACHE[key]


def _profile(spec, theta: torch.Tensor) -> torch.Tensor:
    """``f_s(w, n) cos`` (luminance-like mean over RGB) at normal incidence for ``w`` at angles
    ``theta`` from the normal (the mirror direction): (T,)."""
    z = torch.zeros_like(theta)
    w = torch.stack([torch.sin(theta), z, torch.cos(theta)], -1)
    n = torch.tensor([0.0, 0.0, 1.0], dtype=theta.dtype).expand_as(w)
    return spec.eval(w, n, n).mean(-1) * torch.cos(theta)


def _half_max_sharpness(spec) -> float:
    """The sharpness of the Gaussian with the lobe's half-maximum angle at normal incidence,
    ``ln 2 / (1 - cos theta_half)``."""
    theta = torch.linspace(0, math.pi / 2, 20001, dtype=torch.float64)
    f = _profile(spec, theta)
    half = int((f >= 0.5 * f[0]).nonzero().max())
    th = float(theta[max(half, 1)])
    return math.log(2) / (1 - math.cos(th))


def _shape_mixture(spec, lam: torch.Tensor) -> torch.Tensor:
    """Non-negative shares of light ``a_i`` (sum 1) of Gaussians of sharpness ``lam`` whose sum
    best matches the lobe's profile at normal incidence, weighted by solid angle."""
    theta = torch.linspace(0, math.pi / 2, 8001, dtype=torch.float64)
    f = _profile(spec, theta)
    sw = torch.sin(theta).sqrt()[:, None]
    basis = torch.exp(lam[None] * (torch.cos(theta)[:, None] - 1))  # (T, M)
    active = torch.ones(lam.shape[0], dtype=torch.bool)
    c = torch.zeros(lam.shape[0], dtype=torch.float64)
    for _ in range(lam.shape[0]):  # least squares, dropping negative terms (at most M rounds)
        sol = torch.linalg.lstsq(basis[:, active] * sw, (f[:, None] * sw)).solution[:, 0]
        c = torch.zeros_like(c)
        c[active] = sol
        if bool((sol >= 0).all()):
            break
        active &= c > 0
    light = c.clamp_min(0) * 2 * math.pi * (1 - torch.exp(-2 * lam)) / lam
    return light / light.sum().clamp_min(DIVISOR_F32)


def _albedo_table(spec) -> torch.Tensor:
    """``E(n.v) = int f_s cos`` at :data:`ALBEDO_STEPS` cosines by stratified importance
    sampling of the BRDF: (T, 3)."""
    t, s = ALBEDO_STEPS, ALBEDO_SAMPLES
    nv = (torch.arange(t, dtype=torch.float64) + 0.5) / t
    wo = torch.stack([(1 - nv**2).sqrt(), torch.zeros_like(nv), nv], -1)  # (T, 3)
    g = (torch.arange(s, dtype=torch.float64) + 0.5) / s
    u1, u2 = torch.meshgrid(g, g, indexing="ij")
    u = torch.stack([u1, u2, torch.full_like(u1, 0.5)], -1).reshape(-1, 3)  # (S^2, 3)
    n = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    wo_b = wo[:, None].expand(-1, u.shape[0], 3)
    _, weight, _ = spec.sample(wo_b, n.expand_as(wo_b), u[None].expand(t, -1, 3))
    return weight.mean(1)  # (T, 3)


def visible_fraction(tiles: torch.Tensor, corners: torch.Tensor, bary: torch.Tensor,
                     r: torch.Tensor) -> torch.Tensor:  # fmt: skip
    """``V(R)``: the corners' visibility tiles read at ``r (P, 3)`` and blended with
    ``bary (P, 3)``; ``tiles (V, R, R)`` uint8, ``corners (P, 3)``: (P,) in [0, 1]."""
    v = octahedral.bilinear(tiles, corners, r[:, None].expand(-1, 3, 3)) / 255.0  # (P, 3)
    return (v * bary).sum(-1)


def indirect_scale(direct_light: torch.Tensor, albedo: torch.Tensor, vis: torch.Tensor):
    """The indirect Gaussians' factor ``(1 - V) / (1 - v_fit)`` (module docstring), (P,).

    direct_light : (P, 3) the blended direct Gaussians' carried light;  albedo : (P, 3)
    ``E(n.v)``;  vis : (P,) the pixel's visible fraction
    """
    v_fit = (direct_light.mean(-1) / albedo.mean(-1).clamp_min(DIVISOR_F32)).clamp(0, 1)
    return ((1 - vis) / (1 - v_fit).clamp_min(OCCLUDED_FLOOR)).clamp(0, INDIRECT_SCALE_MAX)
