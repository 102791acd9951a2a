"""The bake mesh refined where an edge's ends see the environment differently
(lobelight.fit.refine_scene): the split keeps the surface, its winding and the materials, a
convex mesh is left alone, and the refined mesh's per-vertex visibility, interpolated as the
renderers interpolate transport, is closer to the visibility ray-cast at the surface's points
than the coarse mesh's."""

from __future__ import annotations

import math

import torch
import trimesh

from lobelight import scene
from lobelight.fit import refine_scene
from lobelight.geometry.raycast import RayCaster
from lobelight.model import visibility_tiles


def _shaded_quad() -> scene.Scene:
    """A 2 x 2 ground quad of two triangles, and a box floating just above one corner: that
    corner sees little of the sky, the other three most of it."""
    ground = trimesh.Trimesh(
        [[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]], [[0, 2, 1], [0, 3, 2]], process=False
    )
    box = trimesh.creation.box(extents=(0.8, 0.5, 0.8))
    box.apply_translation((-1.0, 0.3, -1.0))
    tm = trimesh.util.concatenate([ground, box])
    mesh = scene.mesh_from_arrays(tm.vertices, tm.faces, name="quad")
    v = mesh.n_vertices
    diffuse = torch.linspace(0.1, 0.9, v)[:, None].expand(v, 3).contiguous()
    return scene.Scene(mesh, scene.Materials(diffuse, None), name="quad")


def _ground(mesh: scene.Mesh) -> torch.Tensor:
    """The faces of the ground plane (y = 0): (G, 3)."""
    return mesh.faces[(mesh.vertices[mesh.faces][..., 1].abs() < 1e-6).all(1)]


def test_a_split_keeps_the_surface_its_winding_and_the_materials():
    sc = _shaded_quad()
    one, record = refine_scene(sc, rounds=1)
    assert record["rounds"] == 1 and record["edges_split"][0] > 0
    v0, m = sc.mesh.n_vertices, one.mesh
    assert m.n_vertices == v0 + record["edges_split"][0]
    # each new vertex is the midpoint of an edge of the old mesh, in position and material
    old = sc.mesh.vertices
    pairs = torch.cat(
        [sc.mesh.faces[:, [0, 1]], sc.mesh.faces[:, [1, 2]], sc.mesh.faces[:, [2, 0]]]
    )
    mids = 0.5 * (old[pairs[:, 0]] + old[pairs[:, 1]])
    mid_albedo = 0.5 * (sc.materials.diffuse[pairs[:, 0]] + sc.materials.diffuse[pairs[:, 1]])
    for i in range(v0, m.n_vertices):
        j = int((mids - m.vertices[i]).norm(dim=-1).argmin())
        assert float((mids[j] - m.vertices[i]).norm()) < 1e-6
        torch.testing.assert_close(one.materials.diffuse[i], mid_albedo[j])
    # the ground's area and its faces' facing are kept: every piece faces +y as the quad did
    tri = m.vertices[_ground(m)]
    n = torch.linalg.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    assert bool((n[:, 1] > 0).all())
    assert math.isclose(float(n.norm(dim=-1).sum() / 2), 4.0, rel_tol=1e-5)


def test_a_convex_mesh_is_left_as_it_is():
    tm = trimesh.creation.icosphere(subdivisions=2)
    mesh = scene.mesh_from_arrays(tm.vertices, tm.faces, name="sphere")
    sc = scene.Scene(mesh, scene.Materials(torch.full((mesh.n_vertices, 3), 0.5), None))
    same, record = refine_scene(sc)
    assert record == {"rounds": 0, "vertices": [mesh.n_vertices] * 2, "edges_split": []}
    assert same.mesh is mesh


def _sky_fraction(caster: RayCaster, points: torch.Tensor, n: int = 1024) -> torch.Tensor:
    """The fraction of the upper hemisphere's directions (uniform in solid angle, a fixed
    stratified set) in which points on the ground see the sky: (P,)."""
    k = math.isqrt(n)
    g = (torch.arange(k) + 0.5) / k
    u, w = torch.meshgrid(g, g, indexing="ij")
    cos = u.flatten()  # uniform in solid angle over the hemisphere
    phi = 2 * math.pi * w.flatten()
    s = (1 - cos**2).sqrt()
    d = torch.stack([s * phi.cos(), cos, s * phi.sin()], -1)  # (D, 3), +y up
    o = (points + torch.tensor([0.0, 1e-4, 0.0]))[:, None].expand(-1, d.shape[0], 3)
    hit = caster.occluded(o.reshape(-1, 3), d[None].expand(points.shape[0], -1, 3).reshape(-1, 3))
    return (~hit).float().reshape(points.shape[0], -1).mean(-1)


def _interpolated(mesh: scene.Mesh, points: torch.Tensor) -> torch.Tensor:
    """Each vertex's sky fraction (its visibility tile's mean over its upper hemisphere),
    interpolated at the ground points with the barycentrics of the triangle under them."""
    tiles = visibility_tiles(mesh).float().reshape(mesh.n_vertices, -1) / 255.0
    per_vertex = tiles.sum(-1) / (tiles.shape[-1] / 2)  # the tiles hold the sphere, half above
    caster = RayCaster(mesh)
    down = torch.tensor([0.0, -1.0, 0.0]).expand(points.shape[0], 3)
    tri, _, bary = caster.first_hit(points + torch.tensor([0.0, 1e-3, 0.0]), down)
    assert bool((tri >= 0).all())
    return (per_vertex[mesh.faces[tri]] * bary.float()).sum(-1)


def test_refined_visibility_is_closer_to_the_ray_cast_one():
    # the ground's sky fraction at a grid of points not under the box, ray-cast (the truth),
    # against each mesh's per-vertex values interpolated over its triangles: the coarse quad
    # blends its shaded corner across both triangles; the refined mesh confines the blend to
    # small triangles near the box (measured: mean error 0.061 coarse, 0.0095 refined, with
    # room for two new vertices per vertex: this mesh has 12; the default, one half, stops
    # after one round at 0.034)
    sc = _shaded_quad()
    refined, record = refine_scene(sc, max_growth=2.0)
    assert record["rounds"] >= 2
    g = torch.linspace(-0.95, 0.95, 24)
    x, z = torch.meshgrid(g, g, indexing="ij")
    pts = torch.stack([x.flatten(), torch.zeros(x.numel()), z.flatten()], -1)
    pts = pts[~((pts[:, 0] < -0.55) & (pts[:, 2] < -0.55))]  # not under the box
    truth = _sky_fraction(RayCaster(sc.mesh), pts)
    coarse = (_interpolated(sc.mesh, pts) - truth).abs().mean()
    fine = (_interpolated(refined.mesh, pts) - truth).abs().mean()
    assert float(fine) < 0.3 * float(coarse), (float(fine), float(coarse))
