"""Meshes refused or repaired instead of collapsed: stray vertices, welds that would collapse
the surface, positions float32 cannot hold, inside-out closed meshes, and files over the size
limit refused before they are parsed."""

from __future__ import annotations

import struct
import warnings

import numpy as np
import pytest
import trimesh

from lobelight import scene
from lobelight.cli import main
from lobelight.errors import InputError
from lobelight.scene import _mesh


def _obj(path, v, f, normals=None):
    """An OBJ file of ``v`` (N, 3) and ``f`` (F, 3) (0-based), full float64 precision."""
    lines = [f"v {x:.17g} {y:.17g} {z:.17g}" for x, y, z in np.asarray(v, np.float64)]
    if normals is not None:
        lines += [f"vn {x:.17g} {y:.17g} {z:.17g}" for x, y, z in normals]
        lines += [f"f {a}//{a} {b}//{b} {c}//{c}" for a, b, c in np.asarray(f) + 1]
    else:
        lines += [f"f {a} {b} {c}" for a, b, c in np.asarray(f) + 1]
    path.write_text("\n".join(lines) + "\n")
    return path


def _ico(subdivisions=3):
    m = trimesh.creation.icosphere(subdivisions=subdivisions)
    return np.asarray(m.vertices), np.asarray(m.faces)


def _one_line_exit_2(capsys, argv, *needles):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    for needle in needles:
        assert needle in err, err
    return err


def test_stray_vertex_does_not_collapse_the_mesh(tmp_path):
    # an icosphere (642 vertices) and one vertex no face uses at x = 1e6 baked as 26 vertices:
    # the weld's tolerance came from the bounding box of every vertex
    v, f = _ico(3)
    path = _obj(tmp_path / "stray.obj", np.vstack([v, [[1e6, 0, 0]]]), f)
    mesh = scene.load_mesh(path)
    assert mesh.n_vertices == 642 and mesh.n_faces == len(f)
    # the stray vertex sets neither the extent nor the weld: the mesh is the sphere's own
    np.testing.assert_allclose(mesh.bounds.numpy(), [[-1, -1, -1], [1, 1, 1]], atol=1e-6)


def test_a_weld_that_would_collapse_the_surface_is_refused(tmp_path, capsys):
    # a unit icosphere with a tiny triangle at 1e7: the weld's tolerance (1e-6 of a 1.7e7
    # bounding box, 17 units) collapsed the sphere: "no triangle with non-zero area"
    v, f = _ico(2)
    tiny = np.array([[1e7, 0, 0], [1e7 + 1e-3, 0, 0], [1e7, 1e-3, 0]])
    path = _obj(
        tmp_path / "far_part.obj",
        np.vstack([v, tiny]),
        np.vstack([f, [[len(v), len(v) + 1, len(v) + 2]]]),
    )
    out = tmp_path / "m.npz"
    needles = ("would collapse 100% of its surface area (at most 1%)", "stray parts")
    _one_line_exit_2(capsys, ["bake", str(path), "-o", str(out)], str(path), *needles)
    assert not out.exists()


def test_a_weld_of_split_vertices_is_not_refused():
    # an OBJ with every face's corners split (UV seams) welds back whole, losing no area
    v, f = _ico(2)
    soup = v[f].reshape(-1, 3)  # (3F, 3) three vertices per face
    mesh = scene.mesh_from_arrays(soup, np.arange(len(soup)).reshape(-1, 3))
    assert mesh.n_vertices == len(v) and mesh.n_faces == len(f)


@pytest.mark.parametrize("offset", [1e7, 1e5, 4e3])
def test_a_mesh_far_from_the_origin_is_refused_naming_the_offset(tmp_path, offset, capsys):
    # a unit sphere offset by 1e7 baked with half its diffuse light and a mangled shape, by
    # 1e4 (2,900 sizes) with none: rays from the surface hit it where float32 cannot hold the
    # ray caster's step off the surface
    v, f = _ico(2)
    path = _obj(tmp_path / "far.obj", v + offset, f)
    needles = (f"it lies {offset:.3g} from the origin", f"translate it by ({-offset:.9g}, ")
    _one_line_exit_2(
        capsys, ["bake", str(path), "-o", str(tmp_path / "m.npz")], str(path), *needles
    )


def test_a_mesh_at_the_offset_limit_bakes_the_light_it_bakes_at_the_origin(tmp_path):
    # 100 sizes from the origin (the limit) the bake is the origin's: float32 positions there
    # are 1.2e-5 sizes apart, 8 to the ray caster's step off the surface
    v, f = _ico(2)
    diag = float(np.linalg.norm(v.max(0) - v.min(0)))
    dc = []
    for name, offset in (("near", 0.0), ("far", 0.999 * _mesh.MAX_OFFSET * diag / 3**0.5)):
        path = _obj(tmp_path / f"{name}.obj", v + offset, f)
        argv = ["bake", str(path), "-o", str(tmp_path / f"{name}.npz"), "-q"]
        argv += ["--bounces", "0", "--indirect-paths", "0", "--material", "diffuse:color=0.7"]
        assert main(argv) == 0
        dc.append(np.load(tmp_path / f"{name}.npz")["diffuse"][:, 0].astype(np.float64))
    # each vertex's DC term averages its visibility over the transport's rays: rounding the
    # positions by 1.2e-5 sizes moves a ray's hit by as much, which flips no ray of this
    # convex sphere's (no self-hits); 1e-4 leaves room for float32 sums in another order
    np.testing.assert_allclose(dc[1], dc[0], rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize(("scale", "factor"), [(1e-15, "scale it by 2.89e+14"), (1e15, "2.89e-16")])
def test_extreme_scales_are_refused_naming_the_scale(tmp_path, scale, factor, capsys):
    # a unit sphere scaled by 1e-15 rendered black, by 1e15 rendered nothing
    v, f = _ico(2)
    path = _obj(tmp_path / "scaled.obj", v * scale, f)
    needles = ("its size (bounding-box diagonal) is", factor)
    _one_line_exit_2(
        capsys, ["bake", str(path), "-o", str(tmp_path / "m.npz")], str(path), *needles
    )


def test_inside_out_mesh_is_flipped_with_a_warning(tmp_path):
    # every face's winding reversed baked with exit 0 and rendered dark (diffuse 0.009
    # against 0.113): the area-weighted normals pointed inward
    v, f = _ico(2)
    right = scene.load_mesh(_obj(tmp_path / "right.obj", v, f))
    with pytest.warns(UserWarning, match=r"lobelight: flipped\.obj: the mesh is closed and "):
        flipped = scene.load_mesh(_obj(tmp_path / "flipped.obj", v, f[:, ::-1]))
    np.testing.assert_array_equal(flipped.faces.numpy(), right.faces.numpy())
    np.testing.assert_array_equal(flipped.normals.numpy(), right.normals.numpy())
    # outward: every normal of a sphere about the origin points along its position
    assert float((flipped.normals * flipped.vertices).sum(-1).min()) > 0.9


def test_inside_out_mesh_bakes_the_light_of_the_right_one(tmp_path, capsys):
    # the reproducer: a flipped sphere baked with exit 0 and a diffuse of 0.009 against 0.113
    v, f = _ico(2)
    dc = {}
    for name, faces in (("right", f), ("flipped", f[:, ::-1])):
        path = _obj(tmp_path / f"{name}.obj", v, faces)
        out = tmp_path / f"{name}.npz"
        argv = ["bake", str(path), "-o", str(out), "--bounces", "0", "--indirect-paths", "0"]
        assert main([*argv, "--material", "diffuse:color=0.7", "-q"]) == 0
        dc[name] = np.load(out)["diffuse"][:, 0].astype(np.float64)
    err = capsys.readouterr().err
    assert "lobelight: flipped.obj: the mesh is closed and inside out" in err, err
    # the same mesh once turned: the same rays, the same transfer (float32 round-off only)
    np.testing.assert_allclose(dc["flipped"], dc["right"], rtol=1e-5, atol=1e-7)


def test_inside_out_mesh_with_inward_normals_gets_outward_normals(tmp_path):
    # the file's own normals follow its winding inward: both turned
    v, f = _ico(2)
    path = _obj(tmp_path / "inward.obj", v, f[:, ::-1], normals=-v)
    with pytest.warns(UserWarning, match="inside out"):
        mesh = scene.load_mesh(path)
    assert float((mesh.normals * mesh.vertices).sum(-1).min()) > 0.99


def test_open_mesh_is_left_alone(tmp_path):
    # an open bowl (the lower half of a sphere) wound either way: no signed volume to judge
    v, f = _ico(2)
    lower = f[(v[f][:, :, 1] < 0).all(1)]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mesh = scene.load_mesh(_obj(tmp_path / "bowl.obj", v, lower[:, ::-1]))
    used = np.unique(lower)
    # its faces as written (renumbered), whose normals point to the centre
    assert float((mesh.normals * mesh.vertices).sum(-1).max()) < 0
    assert mesh.n_vertices == len(used)


def test_hollow_shell_keeps_its_inner_surface():
    # a ball with a cavity: the inner sphere's faces face the cavity (negative volume of its
    # own), the whole has positive volume: nothing is turned
    v, f = _ico(2)
    verts = np.vstack([v, 0.5 * v])
    faces = np.vstack([f, f[:, ::-1] + len(v)])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mesh = scene.mesh_from_arrays(verts, faces)
    r = mesh.vertices.norm(dim=-1)
    dots = (mesh.normals * mesh.vertices).sum(-1)
    assert bool((dots[r > 0.75] > 0).all()) and bool((dots[r < 0.75] < 0).all())


def test_a_mesh_over_the_triangle_limit_is_refused_before_it_is_parsed(tmp_path, monkeypatch):
    # a 2M-vertex OBJ reached 14.7 GB before any progress; the limit is checked on the file's
    # own counts, before the parser allocates anything
    monkeypatch.setattr(_mesh, "MAX_FACES", 100)

    def parse(*_):
        raise AssertionError("parsed")

    monkeypatch.setattr(_mesh, "_trimesh_arrays", parse)
    v, f = _ico(2)  # 320 triangles
    path = _obj(tmp_path / "big.obj", v, f)
    with pytest.raises(InputError, match=r"big\.obj: 162 vertices and 320 triangles: over "):
        scene.load_mesh(path)
    stl = tmp_path / "big.stl"  # binary STL: 80-byte header, count, 50 bytes a triangle
    stl.write_bytes(bytes(80) + struct.pack("<I", 200) + bytes(50 * 200))
    with pytest.raises(InputError, match=r"big\.stl: 600 vertices and 200 triangles: over "):
        scene.load_mesh(stl)


@pytest.mark.parametrize(
    ("name", "text"),
    [
        ("claims.ply", "ply\nformat ascii 1.0\nelement vertex 3000000000\nproperty float x\n"
                       "property float y\nproperty float z\nelement face 1\n"
                       "property list uchar int vertex_indices\nend_header\n0 0 0\n"),
        ("claims.off", "OFF\n10 9000000000 0\n0 0 0\n"),
    ],
)  # fmt: skip
def test_a_header_claiming_a_huge_mesh_is_refused_before_it_is_parsed(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(InputError, match=r"claims\.(ply|off): .* over lobelight's limit"):
        scene.load_mesh(path)


def test_parts_too_small_for_float32_at_their_position_are_refused():
    """A 1e-6 icosahedron 0.58 from the origin beside a like one 1 away (the long fuzz run's
    case): float32 positions move its corners by up to 6 % of its edges and change the area by
    2 %, which the weld never touched; refused naming the cause, as a weld that collapses area
    is. Parts of 1e-3 at the same places are kept (float32 moves their corners by 6e-5 of an
    edge)."""
    ico = np.asarray(trimesh.creation.icosphere(0).vertices)
    f = np.vstack([np.asarray(trimesh.creation.icosphere(0).faces), [[12, 13, 14]]])

    def parts(size: float) -> np.ndarray:
        tri = 1.0 + size * np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
        return np.vstack([ico * size + 0.5773502691896258, tri])

    with pytest.raises(InputError, match="float32"):
        scene.mesh_from_arrays(parts(1e-6), f, name="tiny")
    assert scene.mesh_from_arrays(parts(1e-3), f, name="fine").n_faces == 21
