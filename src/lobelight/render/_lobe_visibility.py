"""The direct Gaussians of a rough lobe corrected, per vertex and frame, for what the object
blocks of the lighting.

A Gaussian fitted to a glossy lobe that the object cuts (a claw across a leg's reflection)
cannot follow the cut: its light spills across the occluder's edge, and the spill is lit by
whatever the lighting has there. Where a third of a rough lobe is blocked the fitted lobes are
14-30 % too bright under a map whose glow the occluder hides (docs/results.md). The error depends
on the lighting, so no fit made once can remove it; a renderer can, per vertex and frame, with
the vertex's visibility tile (:meth:`lobelight.model.Model.visibility`) and the material's own
BRDF, both of which the model holds.

At a vertex seen from ``v`` the renderers scale the light its direct Gaussians carry by

    rho = Q[f cos V L] / Q[G L]        (per RGB channel)

``Q`` one fixed quadrature over directions around the Gaussians: :data:`SAMPLES` directions
drawn from a spherical Gaussian (vMF) of half the direct lobes' smallest sharpness, centred on
their light-weighted mean, by one fixed lattice of the unit square (the same for every vertex
and frame: no noise, no flicker); at each direction the lighting averaged over the sample's
share of the sphere (filtered importance sampling: a prefiltered lookup of sharpness
``2 pi S pdf``); ``f cos V`` the material's BRDF times the cosine times the tile's bilinear
visibility, ``G`` the vertex's direct Gaussians at ``v``. The same samples in the numerator and
denominator: where the Gaussians fit the lobe the quadrature's own error cancels and ``rho`` is
1; where they spill into blocked directions it is below 1 by what the spill carries. ``rho`` is
clamped to ``[0, RHO_MAX]`` and is 1 where the Gaussians carry no light the quadrature sees.

The lighting is the map the Gaussians integrate: without its sun where one is taken out (the
sun is shaded per pixel with its shadow). The factor multiplies the light the direct Gaussians
carry at the vertex, after the blend across views and before the blend across the triangle, so
the pixel stage is unchanged; the indirect Gaussians are left as they are.

Applies to models whose BRDF the renderers evaluate per pixel for the sun
(:func:`lobelight.render._sun_glossy.sun_glossy_supported`) and whose lobe is not sharp (a sharp
lobe is shaded per pixel with its own visibility, :mod:`._reflection`). The desktop shader and
the web page compute it once per frame in the vertex stage of a pass captured by transform
feedback (``shaders/lobe_visibility.glsl``, the twin of :func:`lobe_visibility`), and the
shading pass reads it as a vertex attribute.
"""

from __future__ import annotations

import math

import torch

from ..brdf import sharp_lobe
from ..geometry import octahedral, sphere
from ..lobes import sg
from ..model import LIVE_FLOOR
from ._sun_glossy import sun_glossy_supported

__all__ = [
    "LAM_MIN",
    "LAM_SCALE",
    "MOVING_SAMPLES",
    "RHO_MAX",
    "SAMPLES",
    "lobe_visibility",
    "lobe_visibility_applies",
    "shader_defines",
]

#: Quadrature directions per vertex.
SAMPLES = 128
#: The directions of the web page's frames drawn while the view moves (as it draws fewer pixels
#: then): the still frame takes :data:`SAMPLES`.
MOVING_SAMPLES = 32
#: The proposal's sharpness is this share of the widest live direct lobe's: wider than every
#: lobe, so that it covers both the material's lobe and a fitted lobe's spill.
LAM_SCALE = 0.5
#: The proposal's sharpness is at least this (a lobe wider than a hemisphere's is sampled as one).
LAM_MIN = 1.0
#: The largest factor the correction may scale a vertex's direct light by.
RHO_MAX = 4.0


def shader_defines() -> dict[str, str | int]:
    """The constants of ``lobe_visibility.glsl``."""
    return {
        "LV_LAM_SCALE": f"{LAM_SCALE:.6e}",
        "LV_LAM_MIN": f"{LAM_MIN:.6e}",
        "LV_RHO_MAX": f"{RHO_MAX:.6e}",
    }


def lobe_visibility_applies(model) -> bool:
    """Whether the renderers correct the model's direct Gaussians (module docstring): not for
    a model fitted without visibility (``shadows=False`` in its provenance, e.g. the
    ``no_visibility`` baseline of :func:`lobelight.studies.compare`), whose transport is meant
    to ignore what the object blocks."""
    spec = model.materials.specular
    return (
        spec is not None
        and model.direct_gaussians > 0
        and sun_glossy_supported(spec)
        and sharp_lobe(spec) is None
        and (model.provenance or {}).get("shadows", True) is not False
    )


def _frame(c: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Two unit vectors ``(..., 3)`` completing ``c`` to an orthonormal frame."""
    a = torch.where(
        c[..., 2:3].abs() < 0.9, c.new_tensor([0.0, 0.0, 1.0]), c.new_tensor([1.0, 0.0, 0.0])
    )
    t1 = torch.nn.functional.normalize(torch.linalg.cross(a, c), dim=-1)
    return t1, torch.linalg.cross(c, t1)


def lobe_visibility(model, lighting, vid, view, e, mu, lam, rot, *, rest: bool) -> torch.Tensor:
    """``rho (V', 3)`` for the vertices ``vid (V',)`` seen along unit ``view (V', 3)``, whose
    direct Gaussians carry light ``e (V', Nd, 3)`` (weight times integral) with unit means
    ``mu (V', Nd, 3)`` and sharpness ``lam (V', Nd)`` (module docstring; a lobe is live where
    its light's mean over colour is at least :data:`lobelight.model.LIVE_FLOOR`, as
    :func:`lobelight.model.blend_lobes` decides); ``rest``: the lighting without its sun."""
    dev = e.device
    vid = vid.to(dev)
    n = model.mesh.normals.to(dev)[vid]  # (V', 3)
    grey = e.mean(-1)  # (V', Nd)
    live = grey >= LIVE_FLOOR
    w = torch.where(live[..., None], e / sg.integral(lam)[..., None], 0.0)  # peak weights
    # centred on the lobes' light-weighted mean, wider than the widest
    c = (torch.where(live, grey, 0.0)[..., None] * mu).sum(1)
    norm2 = (c * c).sum(-1, keepdim=True)
    c = torch.where(norm2 > 0, c * norm2.clamp_min(1e-30).rsqrt(), n)
    lam_min = torch.where(live, lam, torch.full_like(lam, math.inf)).amin(1)  # (V',)
    any_live = torch.isfinite(lam_min)
    lp = torch.where(any_live, lam_min * LAM_SCALE, 1.0).clamp_min(LAM_MIN)[:, None]  # (V', 1)
    u = sphere.fibonacci_lattice(SAMPLES, device=dev)  # (S, 2)
    om = -torch.expm1(-2 * lp)  # 1 - exp(-2 lam)
    cos_t = (1 + torch.log1p(-u[:, 0] * om) / lp).clamp(-1, 1)  # (V', S)
    sin_t = (1 - cos_t * cos_t).clamp_min(0).sqrt()
    phi = 2 * math.pi * u[:, 1]
    t1, t2 = _frame(c)
    d = (
        cos_t[..., None] * c[:, None]
        + (sin_t * torch.cos(phi))[..., None] * t1[:, None]
        + (sin_t * torch.sin(phi))[..., None] * t2[:, None]
    )  # (V', S, 3)
    pdf = lp / (2 * math.pi * om) * torch.exp(lp * (cos_t - 1))  # (V', S)
    # the lighting over each sample's share of the sphere, 1 / (S pdf), over the pdf
    light = lighting.lookup(d, 2 * math.pi * SAMPLES * pdf, rot, rest=rest).to(dev)
    light = light / pdf[..., None]  # (V', S, 3)
    g = torch.einsum("vsk,vkc->vsc", torch.exp(lam[:, None] * ((d @ mu.transpose(1, 2)) - 1)), w)

    def per_vertex(t: torch.Tensor, kind: int) -> torch.Tensor:
        if t.ndim <= kind:
            return t
        return t[vid].reshape(vid.shape[0], 1, *t.shape[1:])

    s = model.materials.specular.to(dev).map_params(per_vertex)
    cos = (d * n[:, None]).sum(-1).clamp_min(0)  # (V', S)
    f = s.eval(d, view[:, None].expand_as(d), n[:, None].expand_as(d))  # (V', S, 3)
    vis = octahedral.bilinear(model.visibility().to(dev), vid[:, None].expand(-1, SAMPLES), d)
    num = (f * (cos * vis / 255.0)[..., None] * light).sum(1)
    den = (g * light).sum(1)
    rho = (num / den.clamp_min(1e-30)).clamp(0, RHO_MAX)
    return torch.where((den > 0) & any_live[:, None], rho, torch.ones_like(rho))
