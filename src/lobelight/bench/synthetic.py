"""Synthetic models for the renderer's benchmarks and tests: a sphere or a torus with analytic
Gaussians, no bake needed."""

from __future__ import annotations

import torch
import trimesh

from ..errors import InputError
from ..fit import Gaussians
from ..geometry import sphere as sph
from ..model import Model
from ..scene import mesh_from_arrays, uniform

__all__ = ["SHAPES", "synthetic_model"]

#: The shapes :func:`synthetic_model` builds: a convex sphere, and a torus whose inner side sees
#: the object itself (non-trivial visibility and hit tiles, as a real model has).
SHAPES = ("sphere", "torus")


def _mesh(vertices: int, shape: str):
    """A ``shape`` mesh of about ``vertices`` vertices (module :data:`SHAPES`)."""
    if shape == "sphere":
        # trimesh's UV sphere has about 4 rows^2 vertices for count = (rows + 2, 2 rows)
        rows = max(3, round((vertices / 4) ** 0.5))
        tm = trimesh.creation.uv_sphere(radius=1.0, count=[rows + 2, 2 * rows])
        name = "sphere"
    elif shape == "torus":
        # major x minor sections, in the ratio 5:3 of the circumferences' lengths
        minor = max(3, round((vertices * 3 / 5) ** 0.5))
        major = max(3, round(vertices / minor))
        tm = trimesh.creation.torus(1.0, 0.4, major_sections=major, minor_sections=minor)
        name = "torus"
    else:
        raise InputError("shape", f"must be one of {SHAPES}, got {shape!r}")
    return mesh_from_arrays(tm.vertices, tm.faces, name=f"{name}{len(tm.vertices)}")


def synthetic_model(vertices: int, n_gaussians: int, *, shape: str = "sphere", vary: bool = False):
    """A ``shape`` of about ``vertices`` vertices with analytic Gaussians (a mirror-direction lobe
    and broad ones about the normal): rendering cost does not depend on fitted values.

    ``vary``: the weights and sharpness vary smoothly with the view's angle to the normal, so
    that every record holds its own floats and the model file compresses as a fitted one does
    (a file of constant values reads faster than a real one).
    """
    mesh = _mesh(vertices, shape)
    n = mesh.normals
    views = sph.geodesic_views()
    cos = n @ views.T  # (V, 92)
    refl = torch.nn.functional.normalize(2 * cos[..., None] * n[:, None] - views[None], dim=-1)
    mus = [refl] + [n[:, None].expand_as(refl)] * (n_gaussians - 1)
    mu = torch.stack(mus, 2)  # (V, 92, N, 3)
    lam = torch.tensor([300.0, 5.0, 2.0][:n_gaussians]).expand(*cos.shape, n_gaussians).clone()
    w = (
        (cos > 0).float()[..., None, None]
        * torch.full((n_gaussians, 3), 0.3)
        * lam[..., None]
        / 6.3
    )
    if vary:
        w = w * (0.6 + 0.4 * cos.clamp_min(0))[..., None, None]
        lam = lam * (1.0 + 0.2 * cos.abs())[..., None]
    diffuse = torch.zeros(n.shape[0], 25, 3)
    diffuse[:, 0] = 0.2
    if vary:
        diffuse[:, 1:4] = 0.1 * n[:, None, [1, 2, 0]].transpose(1, 2)  # (V, 3 bands, 3 channels)
    # a Phong material as sharp as the mirror lobe, so that ``--sun`` shades the sun's glossy
    # reflection per pixel too (render/_sun_glossy.py), as for a real glossy model
    mats = uniform(
        {"diffuse": [0.5, 0.5, 0.5], "model": "phong", "specular": 0.3, "exponent": 600.0},
        mesh.n_vertices,
    )
    return Model(mesh, views, Gaussians(w.contiguous(), mu, lam), diffuse, mats, {})
