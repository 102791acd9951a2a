"""A sharp glossy reflection placed per pixel: the material's own lobe at the pixel's reflected
direction, with the environment's visibility read there.

Per-vertex Gaussians blended from three vertices and three of the 92 stored views cannot place
a mirror's reflection between vertices: a reflected direction turns by twice the view's angle,
so the stored views sample an occluder's edge in the reflection some 40 degrees apart, and a
fitted Gaussian has a GGX lobe's light but not its long tails. For a sharp lobe
(:func:`lobelight.brdf.sharp_lobe`) the renderers shade the *direct* glossy light per pixel
instead:

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
with parameters constant over the mesh and a lobe at least as sharp as
:data:`lobelight.brdf.SHARP_LAM`; other materials keep the fitted Gaussians.
``shaders/reflection.glsl`` is the shader's twin.
"""

from __future__ import annotations

import torch

from .._tol import DIVISOR_F32
from ..brdf import SharpLobe
from ..geometry import octahedral

__all__ = ["INDIRECT_SCALE_MAX", "OCCLUDED_FLOOR", "indirect_scale", "shade", "visible_fraction"]

#: The pixel's occluded fraction over the stored views' may rescale the indirect Gaussians by
#: at most this: where the stored views saw no occlusion the indirect Gaussians hold no light
#: to rescale, and a small ``1 - v_fit`` amplifies their noise.
INDIRECT_SCALE_MAX = 4.0
#: ``1 - v_fit`` floor of the rescaling's divisor.
OCCLUDED_FLOOR = 0.05


def shade(sharp: SharpLobe, lighting, r: torch.Tensor, nv: torch.Tensor, vis: torch.Tensor,
          rot, *, rest: bool) -> torch.Tensor:  # fmt: skip
    """``E(n.v) sum_i a_i L(R; lam_i) V``: (P, 3) for reflected directions ``r (P, 3)``,
    ``nv (P,)``, visible fractions ``vis (P,)``; ``rest``: the map without its sun."""
    lam = sharp.sharpness(nv)  # (P, M)
    m = lam.shape[-1]
    look = lighting.lookup(r[:, None].expand(-1, m, 3), lam, rot, rest=rest)  # (P, M, 3)
    mixed = (look * sharp.weights.to(r.device)[:, None]).sum(1)
    return sharp.directional_albedo(nv) * mixed * vis[:, None]


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
