"""A synthetic model for the renderer's benchmarks and tests: a sphere with analytic Gaussians, no
bake needed."""

from __future__ import annotations

import torch
import trimesh

from ..fit import Gaussians
from ..geometry import sphere as sph
from ..model import Model
from ..scene import mesh_from_arrays, uniform

__all__ = ["synthetic_model"]


def synthetic_model(vertices: int, n_gaussians: int):
    """A sphere of about ``vertices`` vertices with analytic Gaussians (a mirror-direction lobe
    and broad ones about the normal): rendering cost does not depend on fitted values."""

    # trimesh's UV sphere has about 4 rows^2 vertices for count = (rows + 2, 2 rows)
    rows = max(3, round((vertices / 4) ** 0.5))
    tm = trimesh.creation.uv_sphere(radius=1.0, count=[rows + 2, 2 * rows])
    mesh = mesh_from_arrays(tm.vertices, tm.faces, name=f"sphere{len(tm.vertices)}")
    n = mesh.normals
    views = sph.geodesic_views()
    cos = n @ views.T
    refl = torch.nn.functional.normalize(2 * cos[..., None] * n[:, None] - views[None], dim=-1)
    mus = [refl] + [n[:, None].expand_as(refl)] * (n_gaussians - 1)
    mu = torch.stack(mus, 2)
    lam = torch.tensor([300.0, 5.0, 2.0][:n_gaussians]).expand(*cos.shape, n_gaussians).clone()
    w = (
        (cos > 0).float()[..., None, None]
        * torch.full((n_gaussians, 3), 0.3)
        * lam[..., None]
        / 6.3
    )
    diffuse = torch.zeros(n.shape[0], 25, 3)
    diffuse[:, 0] = 0.2
    # a Phong material as sharp as the mirror lobe, so that ``--sun`` shades the sun's glossy
    # reflection per pixel too (render/_sun_glossy.py), as for a real glossy model
    mats = uniform(
        {"diffuse": [0.5, 0.5, 0.5], "model": "phong", "specular": 0.3, "exponent": 600.0},
        mesh.n_vertices,
    )
    return Model(mesh, views, Gaussians(w.contiguous(), mu, lam), diffuse, mats, {})
