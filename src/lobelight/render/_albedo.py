"""The diffuse albedo and diffuse light at surface points, for both of a model's kinds: per
vertex (interpolated), or read per pixel from its textures (:attr:`lobelight.model.Model.albedo`,
whose diffuse transfer is per unit albedo)."""

from __future__ import annotations

import torch

__all__ = ["diffuse_albedo", "diffuse_light", "hit_diffuse_light"]


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
    order, and the shader path reads the hit points' vertices from its vertex table alone."""
    if model.albedo is not None:
        vertex_light = vertex_light * model.materials.diffuse.to(vertex_light)
    return (vertex_light[corners] * bary.to(vertex_light)[..., None]).sum(1)
