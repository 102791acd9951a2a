"""Bad input at every loader's door: one InputError that names the file, never a traceback.

The plain cases every loader must handle (missing file, a directory, an empty file, a file it
may not read), then the cases the fuzzing in ``test_fuzz.py`` found: each names an input that
must give that one error, not another exception type, and that must not load.
"""

from __future__ import annotations

import io
import json
import math
import os
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

from conftest import tiny_table_params
from lobelight import cosine, envmap, model, scene
from lobelight.errors import InputError
from lobelight.fit import Gaussians, MeshFit
from lobelight.geometry import sphere

LOADERS = {
    "model": (model.load, "m.npz"),
    "scene_toml": (scene.load, "s.toml"),
    "scene_json": (scene.load, "s.json"),
    "mesh_obj": (scene.load_mesh, "m.obj"),
    "mesh_ply": (scene.load_mesh, "m.ply"),
    "mesh_stl": (scene.load_mesh, "m.stl"),
    "mesh_off": (scene.load_mesh, "m.off"),
    "envmap_hdr": (envmap.load, "e.hdr"),
    "envmap_exr": (envmap.load, "e.exr"),
    "tables": (cosine.load_tables, "t.npz"),
}


def assert_input_error(loader, path, match: str | None = None) -> InputError:
    """``loader(path)`` raises one InputError whose message names ``path`` (and ``match``)."""
    with pytest.raises(InputError) as err:
        loader(path)
    msg = str(err.value)
    assert str(path) in msg, msg
    if match is not None:
        assert match in msg, msg
    assert err.type is InputError
    return err.value


@pytest.mark.parametrize("kind", LOADERS)
def test_missing_file(tmp_path, kind):
    loader, name = LOADERS[kind]
    assert_input_error(loader, tmp_path / name)


@pytest.mark.parametrize("kind", LOADERS)
def test_directory_instead_of_file(tmp_path, kind):
    loader, name = LOADERS[kind]
    (tmp_path / name).mkdir()
    assert_input_error(loader, tmp_path / name)


@pytest.mark.parametrize("kind", LOADERS)
def test_empty_file(tmp_path, kind):
    loader, name = LOADERS[kind]
    (tmp_path / name).write_bytes(b"")
    assert_input_error(loader, tmp_path / name)


@pytest.mark.parametrize("kind", LOADERS)
@pytest.mark.parametrize("content", [b"\x00" * 64, b"hello\n", bytes(range(256)) * 4])
def test_other_content(tmp_path, kind, content):
    loader, name = LOADERS[kind]
    (tmp_path / name).write_bytes(content)
    assert_input_error(loader, tmp_path / name)


@pytest.mark.skipif(
    not hasattr(os, "geteuid") or os.geteuid() == 0, reason="root reads any file: no unreadable"
)
@pytest.mark.parametrize("kind", LOADERS)
def test_unreadable_file(tmp_path, kind):
    loader, name = LOADERS[kind]
    p = tmp_path / name
    p.write_bytes(b"something")
    p.chmod(0)
    try:
        assert_input_error(loader, p)
    finally:
        p.chmod(0o600)


def test_plain_npy_is_not_a_table_archive(tmp_path):
    # np.load returns a bare array for a .npy file: used to escape as TypeError (``with``)
    p = tmp_path / "t.npz"
    with open(p, "wb") as f:
        np.save(f, np.zeros(3))
    assert_input_error(cosine.load_tables, p, "not a lobe-table file")


def test_pickled_npz_member_is_refused(tmp_path):
    # an object array needs pickle: allow_pickle=False refuses it; reported as a bad file
    p = tmp_path / "t.npz"
    np.savez(p, format_version=np.array([{"a": 1}], dtype=object))
    assert_input_error(cosine.load_tables, p)


# --------------------------------------------------------------------------------------------
# scene files (fixes in lobelight/scene/_scene.py and _materials.py)

_BALL_OBJ = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"


def _scene_file(tmp_path: Path, doc: dict, fmt: str = "json") -> Path:
    (tmp_path / "ball.obj").write_text(_BALL_OBJ)
    p = tmp_path / f"s.{fmt}"
    p.write_text(json.dumps({"mesh": "ball.obj", **doc}))
    return p


@pytest.mark.parametrize(
    ("doc", "match"),
    [
        # used to escape as TypeError / ValueError from torch.as_tensor
        ({"material": {"diffuse": "red"}}, "material.diffuse"),
        ({"material": {"diffuse": [[0.5, 0.5], [0.5]]}}, "material.diffuse"),
        ({"material": {"diffuse": [[0.5, 0.5, 0.5]] * 2}}, "material.diffuse"),
        ({"gradient": {"axis": "up", "from": {}, "to": {}}}, "gradient.axis"),
        ({"gradient": {"axis": {"x": 1}, "from": {}, "to": {}}}, "gradient.axis"),
        # used to escape as OverflowError from the BRDF parameters
        ({"material": {"model": "phong", "specular": [0.5] * 3, "exponent": 10**400}}, "range"),
        # used to escape as ValueError from the camera
        ({"camera": {"origin": [0, 0, 4], "target": [0, 0, 0], "fov": "wide"}}, "camera"),
        ({"camera": {"origin": "here", "target": [0, 0, 0]}}, "camera"),
        # used to be accepted: a NaN axis gave NaN materials, non-strings were str()-ed
        ({"gradient": {"axis": [math.nan, 1, 0], "from": {}, "to": {}}}, "gradient.axis"),
        ({"mesh": 5}, "mesh"),
        ({"mesh": ["ball.obj"]}, "mesh"),
        ({"mesh": "ball.obj\x00"}, "mesh"),
        ({"name": ["ball"]}, "name"),
        ({"environment": 1}, "environment"),
        # material errors used to name only the key, not the scene file
        ({"material": {"diffuse": [2, 0, 0]}}, "material.diffuse"),
        ({"material": {"model": "glass"}}, "material.model"),
    ],
)
def test_bad_scene_entries_name_the_file(tmp_path, doc, match):
    assert_input_error(scene.load, _scene_file(tmp_path, doc), match)


def test_scene_names_the_mesh_file_it_cannot_read(tmp_path):
    (tmp_path / "flat.obj").write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n")
    p = tmp_path / "s.toml"
    p.write_text('mesh = "flat.obj"\n')
    err = assert_input_error(scene.load, p, "flat.obj")
    assert "non-zero area" in err.problem


# --------------------------------------------------------------------------------------------
# meshes (fixes in lobelight/scene/_mesh.py)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        # coordinates beyond float32 used to load as +-inf vertices
        ("v 0 0 0\nv 1e39 0 0\nv 0 1 0\nf 1 2 3\n", "beyond"),
        ("v 0 0 0\nv 1e300 0 0\nv 0 1 0\nf 1 2 3\n", "beyond"),
        # extents float32 cannot hold
        ("v 0 0 0\nv 1e-30 0 0\nv 0 1e-30 0\nf 1 2 3\n", "its size (bounding-box diagonal)"),
        ("v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n", "NaN"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", None),
    ],
)
def test_bad_mesh_geometry_names_the_whole_path(tmp_path, text, match):
    # messages from the geometry checks used to name only the file name, not its path
    p = tmp_path / "m.obj"
    p.write_text(text)
    assert_input_error(scene.load_mesh, p, match)


def test_mesh_off_with_bad_indices(tmp_path):
    p = tmp_path / "m.off"
    p.write_text("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n")
    assert_input_error(scene.load_mesh, p)


# --------------------------------------------------------------------------------------------
# cosine lobe tables (fixes in lobelight/cosine/_tables.py)

TINY = tiny_table_params()


@pytest.fixture(scope="module")
def table_arrays(tiny_table_path):
    with np.load(tiny_table_path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def _zip_members(path: Path, members: dict[str, bytes]) -> None:
    with zipfile.ZipFile(path, "w") as zf:
        for k, v in members.items():
            zf.writestr(k + ".npy", v)


def _npy(a) -> bytes:
    buf = io.BytesIO()
    np.save(buf, a)
    return buf.getvalue()


def test_tables_member_without_npy_magic(tmp_path, table_arrays):
    # np.load hands such a member back as bytes: used to escape as AttributeError
    p = tmp_path / "t.npz"
    members = {k: _npy(a) for k, a in table_arrays.items()}
    members["product"] = b"X" + members["product"][1:]
    _zip_members(p, members)
    assert_input_error(cosine.load_tables, p, "not an array")


def test_tables_unknown_compression_method(tmp_path, table_arrays):
    # zipfile raises NotImplementedError for it: used to escape
    p = tmp_path / "t.npz"
    np.savez(p, **table_arrays)
    b = bytearray(p.read_bytes())
    i = b.rfind(b"PK\x01\x02")  # the last central-directory entry; method at +10
    b[i + 10] = 99
    p.write_bytes(bytes(b))
    assert_input_error(cosine.load_tables, p)


def test_tables_encrypted_flag(tmp_path, table_arrays):
    # zipfile raises RuntimeError ("password required"): used to escape
    p = tmp_path / "t.npz"
    np.savez(p, **table_arrays)
    b = bytearray(p.read_bytes())
    i = b.find(b"PK\x01\x02")
    b[i + 8] |= 1
    p.write_bytes(bytes(b))
    assert_input_error(cosine.load_tables, p)


@pytest.mark.parametrize(
    "change",
    [
        {"format_version": np.array(np.inf)},  # int(inf): OverflowError
        {"params": np.array(json.dumps({**TINY.to_dict(), "e_max": math.inf}))},
        {"params": np.array(json.dumps({**TINY.to_dict(), "e_offset": math.inf}))},
        {"params": np.array(json.dumps({**TINY.to_dict(), "per_decade": 1e308}))},
        {"params": np.array(json.dumps({**TINY.to_dict(), "angle_uniform": "many"}))},
    ],
)
def test_tables_absurd_header_values(tmp_path, table_arrays, change):
    p = tmp_path / "t.npz"
    np.savez(p, **{**table_arrays, **change})
    assert_input_error(cosine.load_tables, p)


# --------------------------------------------------------------------------------------------
# model files: model.load itself is the lead's (these are reported to be fixed there); the
# materials entry goes through Materials.from_dict (fixed in lobelight/scene/_materials.py)


def _tiny_fit(v: int, j: int = 92, n: int = 2) -> MeshFit:
    g = torch.Generator().manual_seed(1)
    w = torch.rand(v, j, n, 3, generator=g)
    mu = torch.nn.functional.normalize(torch.randn(v, j, n, 3, generator=g), dim=-1)
    lam = torch.rand(v, j, n, generator=g) * 100 + 1
    views = sphere.geodesic_views()[:j]  # a model's views are the 92 geodesic ones
    return MeshFit(Gaussians(w, mu, lam), torch.rand(v, 9, 3, generator=g), views, torch.zeros(v))


@pytest.fixture(scope="module")
def model_file(tmp_path_factory):
    p = tmp_path_factory.mktemp("model") / "m.npz"
    sc = scene.builtin("sphere", subdivisions=0)
    model.save(p, sc.mesh, sc.materials, _tiny_fit(sc.mesh.n_vertices))
    with np.load(p, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    return p.read_bytes(), arrays


def _with_meta(arrays: dict, **changes) -> dict:
    meta = json.loads(bytes(arrays["meta"]).decode())
    meta.update(changes)
    return {**arrays, "meta": np.frombuffer(json.dumps(meta).encode(), np.uint8)}


@pytest.mark.parametrize(
    "materials",
    [
        {"diffuse": "red"},  # used to escape as ValueError
        {"diffuse": [[0.5, 0.5, 0.5]] * 5},  # 5 rows for 12 vertices: RuntimeError (expand)
        {"diffuse": [[0.5, 0.5]] * 12},
        [0.5, 0.5, 0.5],  # not a mapping: AttributeError
        {"diffuse": [0.5] * 3, "specular": {"type": "ggx", "alpha": 10**400}},
        {"diffuse": [0.5] * 3, "specular": {"type": "sum"}},
        {"diffuse": [0.5] * 3, "specular": {"type": ["ggx"]}},
    ],
)
def test_model_bad_materials_entry(tmp_path, model_file, materials):
    p = tmp_path / "m.npz"
    np.savez(p, **_with_meta(model_file[1], materials=materials))
    assert_input_error(model.load, p, "materials")


def _member_without_magic(data: bytes, arrays: dict) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for k, a in arrays.items():
            v = _npy(a)
            zf.writestr(k + ".npy", b"X" + v[1:] if k == "keep" else v)
    return buf.getvalue()


def _zip_flag(data: bytes, offset: int, value: int | None = None, bit: int = 0) -> bytes:
    b = bytearray(data)
    i = b.find(b"PK\x01\x02")
    if value is None:
        b[i + offset] |= bit
    else:
        b[i + offset] = value
    return bytes(b)


def _npz(arrays: dict) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def _huge_count(arrays: dict) -> dict:
    # a 5 kB file whose counts ask for ~10^16 bytes: no rows kept, 10^13 Gaussians per view
    v, j = arrays["keep"].shape
    n = 10**13
    return {
        **_with_meta(arrays, n_gaussians=n),
        "keep": np.zeros((v, j), bool),
        "gaussians": np.zeros((0, n, 7), np.float32),
    }


def _sigma(arrays: dict, value: float) -> dict:
    g = arrays["gaussians"].copy()
    g[0, 0, 6] = value
    return {**arrays, "gaussians": g}


MODEL_CASES = {
    # escapes as another exception type
    "unknown_compression_method": (
        lambda d, a: _zip_flag(_npz(a), 10, value=99), "NotImplementedError from zipfile"
    ),
    "encrypted_flag": (lambda d, a: _zip_flag(_npz(a), 8, bit=1), "RuntimeError from zipfile"),
    "member_without_npy_magic": (_member_without_magic, "AttributeError: bytes has no .shape"),
    "plain_npy_file": (lambda d, a: _npy(np.zeros(3)), "TypeError: ndarray is no context manager"),
    "provenance_is_a_list": (
        lambda d, a: _npz(_with_meta(a, provenance=[1, 2])), "AttributeError: list.get"
    ),
    "provenance_is_a_string": (
        lambda d, a: _npz(_with_meta(a, provenance="s")), "AttributeError: str.get"
    ),
    "n_vertices_infinity": (
        lambda d, a: _npz(_with_meta(a, n_vertices=math.inf)), "OverflowError: int(inf)"
    ),
    "meta_float_nan": (
        lambda d, a: _npz({**a, "meta": np.array([math.nan, 1.0])}),
        "RuntimeWarning: NaN cast to uint8 (an error under pytest)",
    ),
    "huge_counts_no_rows": (
        lambda d, a: _npz(_huge_count(a)), "RuntimeError: tries to allocate 1e16 bytes"
    ),
    # loads when it should not
    "sigma_1e-30_gives_infinite_lam": (
        lambda d, a: _npz(_sigma(a, 1e-30)), "accepted with lam = inf"
    ),
    "float_faces": (
        lambda d, a: _npz({**a, "faces": a["faces"] + 0.5}), "accepted, faces truncated"
    ),
    "no_faces": (
        lambda d, a: _npz({**a, "faces": np.zeros((0, 3), np.int32)}), "accepted: no triangles"
    ),
    "views_not_the_geodesic_set": (
        lambda d, a: _npz({**a, "views": np.roll(a["views"], 1, axis=0)}),
        "accepted by info, refused by render (its views blend by the geodesic triangles)",
    ),
    "sh_order_11": (
        lambda d, a: _npz(_with_meta(a, sh_order=11)), "accepted by info, refused by render"
    ),
    "all_vertices_coincide": (
        lambda d, a: _npz({**a, "vertices": np.zeros_like(a["vertices"])}),
        "accepted: degenerate mesh",
    ),
}  # fmt: skip


@pytest.mark.parametrize("case", [pytest.param(k, id=k) for k in MODEL_CASES])
def test_model_pinned_bad_files(tmp_path, model_file, case):
    make, _ = MODEL_CASES[case]
    p = tmp_path / "m.npz"
    p.write_bytes(make(*model_file))
    assert_input_error(model.load, p)


def test_model_every_byte_inverted_in_first_member_and_directory(tmp_path, model_file):
    # model.save compresses: an inverted byte inside deflate data raises zlib.error in zipfile
    data = model_file[0]
    info = zipfile.ZipFile(io.BytesIO(data)).infolist()
    start = info[0].header_offset
    end = info[1].header_offset  # the first member (meta): header and deflate data
    directory = int.from_bytes(data[-6:-2], "little")  # end record: central directory offset
    positions = [*range(start, end), *range(max(directory, end), len(data))]
    p = tmp_path / "m.npz"
    for i in positions:
        b = bytearray(data)
        b[i] ^= 0xFF
        p.write_bytes(bytes(b))
        try:
            model.load(p)
        except InputError as exc:
            assert str(p) in str(exc)


@pytest.mark.parametrize(
    "load, name",
    [
        (envmap.load, "sky.hdr"),
        (envmap.load, "sky.exr"),
        (scene.load_mesh, "mesh.ply"),
        (scene.load, "scene.toml"),
        (scene.load, "scene.json"),
    ],
)
@pytest.mark.parametrize("kind", ["device", "fifo"])
def test_a_device_or_a_pipe_is_refused_not_read_forever(tmp_path, load, name, kind):
    # /dev/zero under a map's, mesh's or scene's name read 4.3 GB in 13 s and went on; a FIFO
    # with no writer blocked for ever. Only regular files of a known size are read
    p = tmp_path / name
    if kind == "device":
        p.symlink_to("/dev/zero")
    else:
        os.mkfifo(p)
    with pytest.raises(InputError, match="not a regular file") as e:
        load(p)
    assert name in str(e.value)


def _ascii_ply(tmp_path) -> str:
    import trimesh

    trimesh.creation.icosphere(2).export(tmp_path / "full.ply", encoding="ascii")
    return (tmp_path / "full.ply").read_text()


def test_a_ply_cut_short_is_refused_not_loaded_in_part(tmp_path):
    # an ASCII PLY cut at 90 % (inside its face list) loaded as a partial mesh
    text = _ascii_ply(tmp_path)
    (tmp_path / "cut.ply").write_text(text[: len(text) * 9 // 10])
    with pytest.raises(InputError, match=r"cut\.ply: declares 320 faces and holds \d+"):
        scene.load_mesh(tmp_path / "cut.ply")
    assert scene.load_mesh(tmp_path / "full.ply").n_vertices == 162


def test_a_ply_header_that_declares_more_faces_than_it_holds_is_refused(tmp_path):
    # within the size limit: the faces it lacks are found once it is parsed
    text = _ascii_ply(tmp_path).replace("element face 320", "element face 1000000")
    (tmp_path / "lies.ply").write_text(text)
    with pytest.raises(InputError, match=r"lies\.ply: declares 1,000,000 faces"):
        scene.load_mesh(tmp_path / "lies.ply")
    # beyond it: refused from the header, before it is parsed
    text = _ascii_ply(tmp_path).replace("element face 320", "element face 1000000000")
    (tmp_path / "lies.ply").write_text(text)
    with pytest.raises(InputError, match=r"lies\.ply: 162 vertices and 1,000,000,000 triangles"):
        scene.load_mesh(tmp_path / "lies.ply")


def test_an_rgbe_file_of_0xff_bytes_is_refused(tmp_path):
    # every pixel decodes to 1.7e38: it passed bake --env, and render failed naming no file
    head = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 8 +X 16\n"
    (tmp_path / "hot.hdr").write_bytes(head + b"\xff" * (8 * 16 * 4))
    with pytest.raises(InputError, match=r"hot\.hdr: radiance up to 1.69e\+38"):
        envmap.load(tmp_path / "hot.hdr")


def test_a_scene_whose_environment_is_not_a_map_is_refused(tmp_path):
    # environment = "/etc/passwd" baked with exit 0; the error names the scene file's entry
    # (the fuzz run found it naming only the other file)
    _ascii_ply(tmp_path)
    (tmp_path / "notes.txt").write_text("not a map")
    (tmp_path / "s.toml").write_text('mesh = "full.ply"\nenvironment = "notes.txt"\n')
    with pytest.raises(
        InputError, match=r"s\.toml: environment: .*notes\.txt is not an environment"
    ):
        scene.load(tmp_path / "s.toml")


def test_an_error_quoting_the_input_stays_one_line(tmp_path):
    """A material key holding a line break was quoted into a two-line error (the long fuzz run
    found it); names and values from the input are escaped."""
    _ascii_ply(tmp_path)
    (tmp_path / "s.json").write_text(
        '{"mesh": "full.ply", "material": {"diffuse": 0.5, "a\\nb": 1, "\\u001b[2J": 2}}'
    )
    with pytest.raises(InputError) as e:
        scene.load(tmp_path / "s.json")
    assert "\n" not in str(e.value) and "\x1b" not in str(e.value)
    assert str(tmp_path / "s.json") in str(e.value)
