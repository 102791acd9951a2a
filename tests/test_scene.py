"""Scenes: mesh loading and cleaning, normals, adjacency, materials, scene files, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
import trimesh

from conftest import SHARED, needs_shared
from lobelight import scene
from lobelight.errors import InputError
from lobelight.scene import _mesh


def test_builtin_sphere_tessellation():
    for s in (1, 3):
        sc = scene.builtin("sphere", subdivisions=s)
        assert sc.mesh.n_vertices == 10 * 4**s + 2
        # on a unit sphere the area-weighted normal of a vertex is its position (symmetry), to
        # the faceting's first order: 1e-2 at 2 subdivisions' coarsest triangles
        assert torch.allclose(sc.mesh.normals, sc.mesh.vertices, atol=2e-2)
    assert scene.load("sphere:2").mesh.n_vertices == 162


def test_builtin_knot_is_glossy_varying_and_grounded():
    sc = scene.builtin("knot")
    m = sc.materials
    exp = m.specular.params["exponent"]
    col = m.specular.params["specular"]
    assert exp.shape == (sc.mesh.n_vertices,)
    knot = col.amax(1) > 0
    # spatially varying: from diffuse (no specular colour, exponent 30) to glossy (1500)
    assert float(exp[knot].max()) > 1000 and float(exp.min()) == pytest.approx(30.0)
    assert float(m.diffuse[knot].max(1).values.min()) < float(m.diffuse[~knot].max())
    # ground plane below the knot, facing up
    ground = sc.mesh.normals[:, 1] > 0.999
    assert int(ground.sum()) >= 17 * 17
    assert float(sc.mesh.vertices[ground, 1].max()) < float(sc.mesh.vertices[knot, 1].min())


def _brute_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    n = np.zeros_like(v)
    for tri in f:  # a loop over faces: fine for a test on a few hundred triangles
        a, b, c = v[tri]
        n[tri] += np.cross(b - a, c - a)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def test_normals_are_area_weighted_and_adjacency_matches_trimesh():
    tm = trimesh.creation.capsule(height=1.0, radius=0.4, count=[8, 8])
    m = scene.mesh_from_arrays(tm.vertices, tm.faces)
    v, f = m.vertices.double().numpy(), m.faces.numpy()
    np.testing.assert_allclose(m.normals.numpy(), _brute_normals(v, f), atol=1e-6)
    ref = trimesh.Trimesh(v, f, process=False)
    off, nb = m.adjacency
    for i in range(0, m.n_vertices, 7):
        assert sorted(nb[off[i] : off[i + 1]].tolist()) == sorted(ref.vertex_neighbors[i])


def test_weld_merges_split_vertices_and_drops_degenerate_faces():
    tm = trimesh.creation.box()
    # split every face's vertices (as an OBJ with per-face UVs would), add a degenerate face
    v = tm.vertices[tm.faces].reshape(-1, 3)
    f = np.arange(len(v)).reshape(-1, 3)
    f = np.concatenate([f, [[0, 0, 1]]])
    m = scene.mesh_from_arrays(v, f)
    assert m.n_vertices == 8 and m.n_faces == 12
    # one smooth normal per corner, pointing out of the box into the corner's octant (unsplit
    # faces would have given three axis-aligned normals at each corner position)
    assert bool((torch.sign(m.normals) == torch.sign(m.vertices)).all())


@pytest.mark.parametrize("ext", ["ply", "stl", "glb", "obj", "off"])
def test_load_formats(tmp_path, ext):
    tm = trimesh.creation.icosphere(2)
    p = tmp_path / f"m.{ext}"
    tm.export(p)
    m = scene.load_mesh(p)
    assert m.n_vertices == len(tm.vertices) and m.n_faces == len(tm.faces)
    sc = scene.load(p)
    assert sc.materials.model == "ggx" and sc.materials.n_vertices == m.n_vertices


@needs_shared
def test_load_shared_meshes():
    for name in ("spot_triangulated.obj", "suzanne.obj"):
        m = scene.load_mesh(SHARED / "data" / "meshes" / name)
        assert m.n_faces > 100
        assert torch.allclose(m.normals.norm(dim=1), torch.ones(m.n_vertices), atol=1e-5)


def test_bad_meshes(tmp_path, monkeypatch):
    with pytest.raises(InputError, match="no such file"):
        scene.load_mesh(tmp_path / "missing.obj")
    empty = tmp_path / "empty.obj"
    empty.write_text("")
    with pytest.raises(InputError, match="empty"):
        scene.load_mesh(empty)
    verts_only = tmp_path / "points.obj"
    verts_only.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    with pytest.raises(InputError, match="no triangles"):
        scene.load_mesh(verts_only)
    nan = tmp_path / "nan.obj"
    nan.write_text("v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(InputError, match="NaN"):
        scene.load_mesh(nan)
    flat = tmp_path / "flat.obj"
    flat.write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n")
    with pytest.raises(InputError, match="non-zero area"):
        scene.load_mesh(flat)
    junk = tmp_path / "junk.ply"
    junk.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 99999\n\x00\x01")
    with pytest.raises(InputError, match=r"junk\.ply"):
        scene.load_mesh(junk)
    with pytest.raises(InputError, match="unknown mesh format"):
        (tmp_path / "m.xyz").write_text("1 2 3")
        scene.load_mesh(tmp_path / "m.xyz")
    monkeypatch.setattr(_mesh, "MAX_MESH_BYTES", 10)
    big = tmp_path / "big.obj"
    big.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(InputError, match="2 GB"):
        scene.load_mesh(big)
    with pytest.raises(InputError, match="index out of range"):
        scene.mesh_from_arrays(np.eye(3), [[0, 1, 5]])


def test_scene_file_with_gradient(tmp_path):
    trimesh.creation.icosphere(2).export(tmp_path / "ball.ply")
    (tmp_path / "s.toml").write_text(
        """
name = "ball"
mesh = "ball.ply"
environment = "builtin"
[gradient]
axis = [0, 1, 0]
from = { diffuse = [0.8, 0.7, 0.1] }
to = { diffuse = [0.05, 0.3, 0.05], model = "phong", specular = [0.3, 0.8, 0.3], exponent = 2000 }
[camera]
origin = [0, 0, 4]
target = [0, 0, 0]
fov = 30
"""
    )
    sc = scene.load(tmp_path / "s.toml")
    y = sc.mesh.vertices[:, 1]
    spec = sc.materials.specular
    top, bottom = int(y.argmax()), int(y.argmin())
    assert torch.allclose(sc.materials.diffuse[bottom], torch.tensor([0.8, 0.7, 0.1]))
    assert torch.allclose(spec.params["specular"][top], torch.tensor([0.3, 0.8, 0.3]))
    assert float(spec.params["specular"][bottom].abs().max()) == 0
    # shape parameters blend geometrically: halfway up the exponent is sqrt(2000 * 2000) = 2000
    # (both ends share it) and the specular colour is half
    mid = int((y - 0.5 * (y.max() + y.min())).abs().argmin())
    t = float((y[mid] - y.min()) / (y.max() - y.min()))
    assert float(spec.params["exponent"][mid]) == pytest.approx(2000.0, rel=1e-5)
    assert float(spec.params["specular"][mid, 1]) == pytest.approx(0.8 * t, rel=1e-5)
    assert sc.camera.fov == 30
    # the same scene as JSON
    d = {
        "mesh": "ball.ply",
        "material": {
            "diffuse": [0.5, 0.5, 0.5],
            "model": "ggx",
            "specular": [1, 1, 1],
            "alpha": 0.1,
        },
    }
    (tmp_path / "s.json").write_text(json.dumps(d))
    assert scene.load(tmp_path / "s.json").materials.model == "ggx"


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ('mesh = "ball.ply"\ncolour = 3\n', "unknown key 'colour'"),
        ('mesh = "nope.ply"\n', "no such file"),
        ('mesh = "ball.ply"\n[material]\nmodel = "glass"\n', "unknown model"),
        ('mesh = "ball.ply"\n[material]\ndiffuse = [2, 0, 0]\n', r"material\.diffuse"),
        ('mesh = "ball.ply"\n[material]\nmodel = "ggx"\nalpha = -1\n', r"material\.alpha"),
        ('mesh = "ball.ply"\n[camera]\norigin = [0, 0, 0]\ntarget = [0, 0, 0]\n', "origin"),
        ("mesh = [\n", "not a valid scene file"),
        ("material = {}\n", "needs a 'mesh'"),
    ],
)
def test_bad_scene_files(tmp_path, text, match):
    trimesh.creation.icosphere(1).export(tmp_path / "ball.ply")
    p = tmp_path / "s.toml"
    p.write_text(text)
    with pytest.raises(InputError, match=match):
        scene.load(p)


def test_unknown_builtin():
    with pytest.raises(InputError, match="no built-in scene"):
        scene.builtin("teapot")
    with pytest.raises(InputError, match="no such file"):
        scene.load("no_such_scene.toml")
