"""The diffuse albedo and diffuse light at surface points, for both of a model's kinds: per
vertex (interpolated), or read per pixel from its textures (:attr:`lobelight.model.Model.albedo`,
whose diffuse transfer is per unit albedo)."""

from __future__ import annotations

import torch

__all__ = [
    "F0_MIN",
    "diffuse_albedo",
    "diffuse_light",
    "hit_diffuse_light",
    "specular_f0",
    "specular_ratio",
]

#: The least per-vertex F0 a ratio divides by (glTF's dielectric F0 is 0.04).
F0_MIN = 1e-3


def diffuse_albedo(model, corners: torch.Tensor, bary: torch.Tensor) -> torch.Tensor:
    """The diffuse albedo at points of triangle corners ``(P, 3)`` and barycentrics
    ``(P, 3)``: (P, 3), the texture's where the model has one, else the interpolated vertices'."""
    if model.albedo is not None:
        return model.albedo.at(corners, bary)
    b = bary.to(model.materials.diffuse)[..., None]
    return (model.materials.diffuse.to(corners.device)[corners] * b).sum(1)


def diffuse_light(
    model, vertex_light: torch.Tensor, corners: torch.Tensor, bary: torch.Tensor
) -> torch.Tensor:
    """The diffuse light leaving points (corners and barycentrics as :func:`diffuse_albedo`'s)
    from each vertex's ``vertex_light (V, 3)``, the transfer times the lighting: interpolated,
    and times the albedo read at the point where the model's transfer is per unit albedo."""
    light = (vertex_light[corners] * bary.to(vertex_light)[..., None]).sum(1)
    return light if model.albedo is None else light * model.albedo.at(corners, bary)


def hit_diffuse_light(
    model, vertex_light: torch.Tensor, corners: torch.Tensor, bary: torch.Tensor
) -> torch.Tensor:
    """The diffuse light of the object seen in a sharp reflection, at points as
    :func:`diffuse_light`'s: interpolated from the vertices, each with its own albedo
    (``materials.diffuse``, a texture's average over the vertex's one-ring) where the model's
    transfer is per unit albedo. A texture's detail in a reflection of the object is second
    order, and the shader path reads the hit points' vertices from the vertex stage's capture
    alone."""
    if model.albedo is not None:
        vertex_light = vertex_light * model.materials.diffuse.to(vertex_light)
    return (vertex_light[corners] * bary.to(vertex_light)[..., None]).sum(1)


def specular_f0(model) -> torch.Tensor | None:
    """The bake's per-vertex F0 the textures' F0 is measured against, ``(V, 3)``: the specular
    BRDF's Schlick ``f0`` (:class:`lobelight.brdf.GGXSchlick`), None where the model has no
    F0 texture (:attr:`lobelight.scene.AlbedoTexture.specular`) or its BRDF no ``f0``."""
    a, spec = model.albedo, model.materials.specular
    if a is None or a.specular is None or spec is None or "f0" not in spec.params:
        return None
    f0 = spec.params["f0"].detach().float()
    return f0.reshape(-1, 3).expand(model.mesh.n_vertices, 3)


def specular_ratio(model, corners: torch.Tensor, bary: torch.Tensor) -> torch.Tensor | None:
    """The glossy light's per-pixel factor, the texel's F0 over the interpolated vertices'
    (:class:`lobelight.scene.AlbedoTexture`; exact at normal incidence): (P, 3), 1 where
    the point has no texture; None where the model has no F0 texture."""
    f0 = specular_f0(model)
    if f0 is None:
        return None
    tex = model.albedo.specular_at(corners, bary)
    b = bary.to(tex)[..., None]
    vert = (f0.to(tex.device)[corners.to(tex.device)] * b).sum(1)
    ratio = tex / vert.clamp_min(F0_MIN)
    return torch.where(torch.isnan(tex), torch.ones_like(ratio), ratio)
