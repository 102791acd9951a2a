"""The sun's glossy reflection, shaded per pixel with the material's own BRDF.

A sun 10^5 times brighter than the sky within 0.6 degrees samples the glossy transport at one
direction, so a highlight shows the fitted Gaussian's *shape* there, not its integral: one
Gaussian per view against a GGX lobe with its long tail, interpolated from three vertices, is
where the glossy image's largest errors lie (docs/results.md). With a sun taken out of the map
(:class:`~lobelight.render.Lighting` with ``sun=True``) and a material this module can evaluate,
the Gaussians integrate the map *without* the sun, and the sun adds

    E_sun f_s(l, v) max(n.l, 0) V(l)

per pixel, ``V`` from the sun's shadow map in the shader (one shadow ray in the torch path):
the split is exact, ``int T L = int T L_rest + T(l) E_sun`` for a sun small against the lobe.

A sun is not a point: a studio's softbox taken out as the sun spans degrees, and a point-lit
sharp lobe would show it as a dot. Its disc of RMS angle ``sigma``
(:attr:`lobelight.envmap.Sun.spread`) is folded into the lobe (:func:`sun_widened`): a
microfacet lobe's slopes and the disc's half-vector offsets (``sigma / 2``) add their
variances, ``alpha'^2 = alpha^2 + sigma^2 / 4`` (Blinn-Phong through its Beckmann alpha,
``alpha^2 = 2 / (e + 2)``), and a mirror lobe's (modified Phong, about ``exp(-e theta^2 / 2)``)
``1 / e' = 1 / e + sigma^2 / 2``. Each distribution stays normalised, so the highlight keeps its
light and takes the disc's size.

Supported (``prt.glsl`` carries the same formulas; parameters constant or per vertex): the
models with a :attr:`~lobelight.brdf.BRDF.sun_model`, that is modified Phong and normalised
Blinn-Phong (:class:`lobelight.brdf.Phong`, :class:`lobelight.brdf.BlinnPhong`) and the rough
conductors built with one ``alpha`` (:class:`lobelight.brdf.GGX`,
:class:`lobelight.brdf.Beckmann`, with or without conductor Fresnel) and the glTF lobe
(:class:`lobelight.brdf.GGXSchlick`, GGX with Schlick's Fresnel); each widens itself by the
disc (:meth:`~lobelight.brdf.BRDF.sun_widened`). Other specular BRDFs keep the sun in the
Gaussians' lighting, as the paper does.

The sun's *indirect* glossy light (the sun in a mirror seen in a mirror) has no BRDF to shade
it per pixel: a model's indirect Gaussians (:attr:`lobelight.model.Model.indirect_gaussians`) carry
it, and :func:`sun_through` adds what the sun sends through them, the Gaussian widened by the
disc, ``1 / lam' = 1 / lam + sigma^2 / 2`` (the variances of two small-angle Gaussians add; a
lobe's per-axis variance is ``1 / lam``, a disc's of RMS angle ``sigma`` is ``sigma^2 / 2``),
keeping its integral: ``E w (lam' / lam) exp(lam' (mu.l - 1))``. No shadow test: that light
arrives from the object, not from the sun.
"""

from __future__ import annotations

import numpy as np
import torch

from ..lobes import sg

__all__ = [
    "sun_glossy",
    "sun_glossy_supported",
    "sun_glossy_uniforms",
    "sun_glossy_vertex_params",
    "sun_through",
    "sun_widened",
    "tail_scale",
]


def sun_glossy_supported(spec) -> bool:
    """Whether the sun's glossy reflection off ``spec`` (a specular BRDF or None) can be shaded
    per pixel: whether it has a shader formula (:attr:`lobelight.brdf.BRDF.sun_model`)."""
    return spec is not None and spec.sun_model is not None


def sun_widened(spec, spread: float):
    """``spec`` (a supported model, :func:`sun_glossy_supported`) with its lobe widened by a
    sun disc of RMS angle ``spread`` radians (module docstring); ``spec`` itself for 0."""
    if spread <= 0.0:
        return spec
    return spec.sun_widened(spread)


def tail_scale(spec, spread: float) -> float:
    """How much brighter the widened lobe's far tail is than the lobe's own: a microfacet
    distribution falls as ``alpha^2 / theta^4`` far from its peak, and a disc small against
    ``theta`` leaves that tail as it is, so the widened lobe (:func:`sun_widened`) overstates
    it by ``alpha'^2 / alpha^2``; this is the inverse, ``alpha^2 / alpha'^2`` (Blinn-Phong
    through its Beckmann alpha, ``(e' + 2) / (e + 2)``; modified Phong, whose lobe has no
    such tail, ``e' / e``, the peak's). 1 for ``spread`` 0. For a constant-parameter model
    (:func:`lobelight.brdf.sharp_lobe`'s)."""
    if spread <= 0.0:
        return 1.0
    name = spec.sun_param
    p = float(spec.params[name].detach().float().mean())
    q = float(spec.sun_widened(spread).params[name].detach().float().mean())
    if name == "alpha":
        return (p / q) ** 2
    return (q + 2) / (p + 2) if spec.sun_model == 3 else q / p


def sun_glossy_uniforms(spec) -> dict[str, float | int]:
    """The shader's per-material switches: ``sun_model`` (0 GGX, 1 Beckmann, 2 Phong,
    3 Blinn-Phong) and ``sun_fresnel`` (1 conductor Fresnel, 2 Schlick's
    (:attr:`lobelight.brdf.BRDF.schlick`), 0 none)."""
    fresnel = 2.0 if spec.schlick else float(spec.fresnel)
    return {"sun_model": spec.sun_model, "sun_fresnel": fresnel}


def sun_glossy_vertex_params(spec, n_vertices: int) -> np.ndarray:
    """Per-vertex BRDF parameters for the shader, ``(V, 10)`` float32: the model's
    :attr:`~lobelight.brdf.BRDF.sun_param` (alpha, or the exponent of the Phong models),
    specular RGB (1 where the model has none), eta RGB (``f0`` for Schlick's Fresnel term),
    k RGB (0 where the model has none)."""
    v = n_vertices

    def per_vertex(name: str, width: int) -> torch.Tensor:
        if name not in spec.params:
            return torch.full((v, width), 1.0 if name == "specular" else 0.0)
        t = spec.params[name].detach().cpu().float()
        if t.ndim == 0:  # one value (a grey colour too)
            return t.expand(v, width)
        return t.reshape(-1, width).expand(v, width)  # (3,) constant, (V,) / (V, 3) per vertex

    parts = ((spec.sun_param, 1), ("specular", 3), ("f0" if spec.schlick else "eta", 3), ("k", 3))
    cols = [per_vertex(name, w) for name, w in parts]
    return torch.cat(cols, 1).numpy().astype(np.float32)


def sun_glossy(
    model, lighting, pos: torch.Tensor, n: torch.Tensor, eye: torch.Tensor, corners, bary, rot
) -> torch.Tensor:
    """``E f_s(l, v) max(n.l, 0)`` at surface points, before visibility: (P, 3).

    Parameters
    ----------
    pos, n : (P, 3) points and interpolated (normalised) normals;  eye : (3,) camera origin
    corners : (P, 3) the triangles' vertex ids;  bary : (P, 3) barycentrics (per-vertex
        parameters are interpolated with them, as the rasteriser interpolates the shader's)
    """
    spec = sun_widened(model.materials.specular, lighting.sun.spread).to(pos.device)
    b = bary.to(pos.device, torch.float32)

    def blend(t: torch.Tensor, kind: int) -> torch.Tensor:
        if t.ndim <= kind:
            return t
        return (t[corners] * b.reshape(*b.shape, *([1] * kind))).sum(1)

    s = spec.map_params(blend)
    wo = torch.nn.functional.normalize(eye.to(pos.device, pos.dtype) - pos, dim=-1)
    l = lighting.sun_direction(rot).to(pos.device, pos.dtype).expand_as(pos)
    cos = (n * l).sum(-1).clamp_min(0)
    f = s.eval(l, wo, n)  # (P, 3)
    return f * (cos[:, None] * lighting.sun.irradiance.to(pos.device, pos.dtype))


def sun_through(
    e: torch.Tensor, mu: torch.Tensor, lam: torch.Tensor, sun_dir: torch.Tensor, sun
) -> torch.Tensor:
    """The sun's light through Gaussians carrying light ``e``, ``(..., 3)`` (module docstring).

    Parameters
    ----------
    e : (..., 3) carried light (weight times integral);  mu : (..., 3) unit means;
    lam : (...) sharpness;  sun_dir : (3,) towards the sun;  sun : lobelight.envmap.Sun
    """
    lam = lam.clamp_min(0)
    s2 = float(sun.spread) ** 2
    ratio = 1 / (1 + lam * (s2 / 2))  # lam' / lam
    lam_w = lam * ratio
    d = mu - sun_dir.to(mu.device, mu.dtype)
    g = torch.exp(-lam_w * 0.5 * (d * d).sum(-1))  # exp(lam' (mu.l - 1)), by the chord
    w = e / sg.integral(lam)[..., None]
    return w * (ratio * g)[..., None] * sun.irradiance.to(e.device, e.dtype)
