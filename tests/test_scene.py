"""Scenes: mesh loading and cleaning, normals, adjacency, materials, scene files, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
import trimesh

from conftest import SPOT
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


def _flat_box():
    """A unit box stored as 36 split corners with each face's flat normal."""
    tm = trimesh.creation.box()
    v = tm.vertices[tm.faces].reshape(-1, 3)  # (36, 3)
    return v, np.arange(36).reshape(-1, 3), np.repeat(tm.face_normals, 3, 0)


def test_weld_keeps_hard_edges_where_normals_differ():
    """Weld policy: split vertices merge only where position and normal agree. A box with
    flat normals keeps 4 vertices per face (24), each with its face's normal; the same corners
    given one shared normal each (the corner's diagonal) weld to 8 and keep that normal."""
    v, f, n = _flat_box()
    m = scene.mesh_from_arrays(v, f, normals=n)
    assert m.n_vertices == 24
    corner_normal = m.normals[m.faces.reshape(-1)].reshape(-1, 3, 3)  # (F, 3, 3)
    assert torch.allclose(corner_normal, m.face_normals[:, None].expand(-1, 3, -1), atol=1e-6)
    diag = v / np.linalg.norm(v, axis=1, keepdims=True)
    m = scene.mesh_from_arrays(v, f, normals=diag)
    assert m.n_vertices == 8
    assert torch.allclose(m.normals, m.vertices / m.vertices.norm(dim=1, keepdim=True), atol=1e-6)
    # a vertex without a normal (NaN row) gets the area-weighted normal of its faces
    half = diag.copy()
    half[:18] = np.nan
    m = scene.mesh_from_arrays(v, f, normals=half)
    assert bool(torch.isfinite(m.normals).all())
    assert torch.allclose(m.normals.norm(dim=1), torch.ones(m.n_vertices), atol=1e-6)


@pytest.mark.parametrize("ext", ["ply", "obj"])
def test_load_mesh_keeps_the_files_split_normals(tmp_path, ext):
    """Regression: every mesh was welded by position, so a box stored with flat normals got
    averaged corner normals (and banding on its faces). Files with vertex normals keep their
    hard edges; a box's STL (facet normals only) welds to 8 corners."""
    v, f, n = _flat_box()
    tm = trimesh.Trimesh(v, f, vertex_normals=n, process=False)
    p = tmp_path / f"box.{ext}"
    if ext == "obj":
        p.write_text(trimesh.exchange.obj.export_obj(tm, include_normals=True))
    else:
        p.write_bytes(trimesh.exchange.ply.export_ply(tm, vertex_normal=True))
    m = scene.load_mesh(p)
    assert m.n_vertices == 24 and m.n_faces == 12
    corner_normal = m.normals[m.faces.reshape(-1)].reshape(-1, 3, 3)
    assert torch.allclose(corner_normal, m.face_normals[:, None].expand(-1, 3, -1), atol=1e-6)
    stl = tmp_path / "box.stl"
    tm.export(stl)
    assert scene.load_mesh(stl).n_vertices == 8


@pytest.mark.parametrize("ext", ["ply", "stl", "glb", "obj", "off"])
def test_load_formats(tmp_path, ext):
    tm = trimesh.creation.icosphere(2)
    p = tmp_path / f"m.{ext}"
    tm.export(p)
    m = scene.load_mesh(p)
    assert m.n_vertices == len(tm.vertices) and m.n_faces == len(tm.faces)
    sc = scene.load(p)
    # a bare mesh's grey GGX; a glTF brings its own materials (here the specification's
    # default one: trimesh writes none)
    model = "ggx_schlick" if ext == "glb" else "ggx"
    assert sc.materials.model == model and sc.materials.n_vertices == m.n_vertices


def _edge_face_counts(faces: torch.Tensor) -> np.ndarray:
    """How many faces use each undirected edge."""
    f = faces.numpy()
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    return np.unique(e, axis=0, return_counts=True)[1]


def test_load_spot():
    # Spot (examples/, public domain): 2,930 positions stored with 3,225 UV corners, so the OBJ's
    # seams must weld back to one vertex per position; the mesh is closed
    m = scene.load_mesh(SPOT)
    assert (m.n_vertices, m.n_faces) == (2930, 5856)
    assert torch.allclose(m.normals.norm(dim=1), torch.ones(m.n_vertices), atol=1e-5)
    assert bool((_edge_face_counts(m.faces) == 2).all())  # watertight, edge-manifold
    # wound outwards (positive enclosed volume), and the vertex normals follow the winding
    t = m.vertices.double()[m.faces]
    cross = torch.linalg.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    assert float((t[:, 0] * cross).sum()) / 6 > 0
    agree = (m.normals.double()[m.faces].mean(1) * cross).sum(1) > 0
    assert float(agree.double().mean()) > 0.99


def _untidy_obj() -> str:
    """An OBJ like the ones artists export: off-centre, quads and triangles, texture and normal
    indices, a vertex stored twice (a seam), an open boundary, a fin on a non-manifold edge,
    and a separate small part (an "eye")."""
    lines = []
    for j in range(4):  # a 5 x 4 grid of vertices, bent into a shallow trough
        for i in range(5):
            x = i * 0.5
            lines.append(f"v {x - 3.0:.4f} {0.2 * (x - 1.0) ** 2:.4f} {4.0 + 0.5 * j:.4f}")
    lines += ["v -2.0 1.0 4.5"]  # 21: the fin's apex
    lines += ["v -1.0 2.0 5.0", "v -0.8 2.0 5.0", "v -0.9 2.2 5.0", "v -0.9 2.1 5.2"]  # 22-25
    lines += [lines[2].replace("v ", "v  ")]  # 26: vertex 3 again (the same position)
    lines += [f"vt {u / 4:.3f} {w / 3:.3f}" for w in range(4) for u in range(5)] + ["vn 0 1 0"]
    for j in range(3):
        for i in range(4):
            a = 1 + i + 5 * j
            quad = [a, a + 1, a + 6, a + 5]
            uv = list(quad)
            if (i, j) == (2, 0):
                quad[0] = 26  # this quad uses the seam's copy of vertex 3
            lines.append("f " + " ".join(f"{v}/{t}/1" for v, t in zip(quad, uv, strict=True)))
    lines.append("f 2 8 21")  # on the edge 2-8, already shared by two quads' triangles
    lines += ["f 22 23 24", "f 22 25 23", "f 23 25 24", "f 24 25 22"]  # the eye
    return "\n".join(lines) + "\n"


def test_load_an_untidy_obj(tmp_path):
    p = tmp_path / "untidy.obj"
    p.write_text(_untidy_obj())
    m = scene.load_mesh(p)
    # quads split in two, the seam welded (26 stored), nothing dropped: 5 x 4 + 1 + 4 vertices
    assert (m.n_vertices, m.n_faces) == (25, 12 * 2 + 1 + 4)
    assert torch.allclose(m.normals.norm(dim=1), torch.ones(m.n_vertices), atol=1e-5)
    counts = _edge_face_counts(m.faces)
    assert (counts == 1).sum() > 0 and (counts == 3).sum() >= 1  # open, and the fin is kept
    # positions as stored (not centred or rescaled)
    torch.testing.assert_close(m.vertices.amin(0), torch.tensor([-3.0, 0.0, 4.0]))
    torch.testing.assert_close(m.vertices.amax(0), torch.tensor([-0.8, 2.2, 5.5]))


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
    with pytest.raises(InputError, match="more than the 10 bytes"):
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
