"""glTF assets as scenes: their metallic-roughness materials per vertex (bare, or named by a
scene file with overrides by material name), the records in the model's provenance, and
``lobelight bake`` / ``lobelight info`` of a glTF end to end.

Every asset is written here by :func:`write_glb` from plain arrays, so each expected value
follows from the glTF specification's formulas, independently of the loader.
"""

from __future__ import annotations

import base64
import io
import json
import struct
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from lobelight import scene
from lobelight.cli import main
from lobelight.errors import InputError
from lobelight.model import load as load_model

try:
    import tomllib
except ImportError:  # Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]

# float32 storage of factors and colours, and the one-ring's float32 sums: 1e-5
ATOL = 1e-5


def _srgb_to_linear(c):
    c = np.asarray(c, np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _png(rgb: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(np.asarray(rgb, np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


def write_glb(path, prims, materials, images=(), samplers=()) -> None:
    """A ``.glb`` of one mesh (a ``.gltf`` with its buffer as a data URI where ``path`` ends
    so): ``prims`` are dicts of float32 ``POSITION``, ``NORMAL``, ``TEXCOORD_0``, ``COLOR_0``
    arrays, ``indices`` and ``material``; ``images`` PNG bytes, texture ``i`` showing image
    ``i`` with sampler ``samplers[i]`` where given."""
    blob, views, accessors = bytearray(), [], []

    def accessor(a, kind, ctype=5126):
        a = np.ascontiguousarray(a, dtype="<u4" if ctype == 5125 else "<f4")
        blob.extend(b"\0" * (-len(blob) % 4))
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": a.nbytes})
        blob.extend(a.tobytes())
        acc = {"bufferView": len(views) - 1, "componentType": ctype, "count": len(a), "type": kind}
        if kind == "VEC3" and ctype == 5126 and len(a):
            acc.update(min=a.min(0).tolist(), max=a.max(0).tolist())
        accessors.append(acc)
        return len(accessors) - 1

    kinds = {"POSITION": "VEC3", "NORMAL": "VEC3", "TEXCOORD_0": "VEC2", "COLOR_0": "VEC3"}
    gl_prims = []
    for p in prims:
        attrs = {k: accessor(p[k], kinds[k]) for k in kinds if k in p}
        gl_prims.append({"attributes": attrs, "material": p["material"],
                         "indices": accessor(np.ravel(p["indices"]), "SCALAR", 5125)})  # fmt: skip
    gl_images = []
    for png in images:
        blob.extend(b"\0" * (-len(blob) % 4))
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(png)})
        blob.extend(png)
        gl_images.append({"bufferView": len(views) - 1, "mimeType": "image/png"})
    textures = [{"source": i} for i in range(len(images))]
    for i in range(len(samplers)):
        textures[i]["sampler"] = i
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
           "nodes": [{"mesh": 0}], "meshes": [{"primitives": gl_prims}],
           "materials": list(materials), "accessors": accessors, "bufferViews": views,
           "buffers": [{"byteLength": len(blob)}]}  # fmt: skip
    for key, items in (("images", gl_images), ("textures", textures), ("samplers", samplers)):
        if items:
            doc[key] = list(items)
    if path.suffix == ".gltf":
        doc["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(
            bytes(blob)
        ).decode("ascii")
        path.write_text(json.dumps(doc))
        return
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    blob.extend(b"\0" * (-len(blob) % 4))
    body = struct.pack("<II", len(js), 0x4E4F534A) + js
    body += struct.pack("<II", len(blob), 0x004E4942) + bytes(blob)
    path.write_bytes(b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body)


def _quad(x0: float, **attrs) -> dict:
    """A unit quad in the plane z = 0 facing +Z, from x = x0, two triangles."""
    v = np.array([[x0, 0, 0], [x0 + 1, 0, 0], [x0 + 1, 1, 0], [x0, 1, 0]], np.float32)
    uv = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], np.float32)  # glTF: V down the image
    return {"POSITION": v, "NORMAL": np.tile(np.float32([0, 0, 1]), (4, 1)), "TEXCOORD_0": uv,
            "indices": [[0, 1, 2], [0, 2, 3]], **attrs}  # fmt: skip


#: Material "painted": base colour factor x a constant sRGB texture, metallic-roughness texture
#: (G = rough, B = metal) x factors. Material "plain": factors only, with vertex colours.
PAINTED_SRGB = (200, 120, 40)
PAINTED_FACTOR = (1.0, 0.5, 0.8)
MR_TEXELS = (51, 204)  # G 0.2, B 0.8 (linear data)
PAINTED_METAL, PAINTED_ROUGH = 0.5, 1.0
PLAIN_FACTOR = (0.2, 0.4, 0.6)
PLAIN_METAL, PLAIN_ROUGH = 0.0, 0.7
PLAIN_COLORS = np.float32([[1, 1, 1], [0.5, 1, 1], [1, 0.25, 1], [1, 1, 0.5]])


def two_material_glb(path, *, emissive: bool = False) -> None:
    """Two quads side by side: "painted" (textured) and "plain" (factors and vertex colours)."""
    mr = np.zeros((2, 2, 3), np.uint8)
    mr[..., 1], mr[..., 2] = MR_TEXELS
    materials = [
        {"name": "painted", "pbrMetallicRoughness": {
            "baseColorFactor": [*PAINTED_FACTOR, 1.0], "baseColorTexture": {"index": 0},
            "metallicFactor": PAINTED_METAL, "roughnessFactor": PAINTED_ROUGH,
            "metallicRoughnessTexture": {"index": 1}}},
        {"name": "plain", "pbrMetallicRoughness": {
            "baseColorFactor": [*PLAIN_FACTOR, 1.0], "metallicFactor": PLAIN_METAL,
            "roughnessFactor": PLAIN_ROUGH}},
    ]  # fmt: skip
    if emissive:
        materials[1]["emissiveFactor"] = [1.0, 0.5, 0.0]
    images = [_png(np.broadcast_to(np.uint8(PAINTED_SRGB), (2, 2, 3))), _png(mr)]
    prims = [_quad(0.0, material=0), _quad(1.0, material=1, COLOR_0=PLAIN_COLORS)]
    write_glb(path, prims, materials, images)


def _expected(base, metal, rough):
    """The glTF core specification's material: (diffuse, f0, alpha) of linear base colour,
    metallic and roughness."""
    base = np.asarray(base, np.float64)
    return base * (1 - metal), 0.04 * (1 - metal) + base * metal, rough**2


def _by_material(sc, records) -> dict[str, torch.Tensor]:
    """Vertex indices of each material: the painted quad is at x < 1, the plain one at x > 1
    (the shared edge's vertices are split, one copy per material, told apart by their faces)."""
    faces = sc.mesh.faces
    centre_x = sc.mesh.vertices[faces].mean(1)[:, 0]  # (F,)
    out = {}
    for name, sel in (("painted", centre_x < 1), ("plain", centre_x > 1)):
        out[name] = torch.unique(faces[sel])
    assert sorted(r["name"] for r in records) == ["painted", "plain"]
    return out


def _check_painted(sc, idx, base_factor=PAINTED_FACTOR, metal=None, rough=None, texture=True):
    tex = _srgb_to_linear(np.array(PAINTED_SRGB) / 255) if texture else np.ones(3)
    mr_g, mr_b = (np.array(MR_TEXELS) / 255) if texture else (1.0, 1.0)
    m = (PAINTED_METAL if metal is None else metal) * mr_b
    r = (PAINTED_ROUGH if rough is None else rough) * mr_g
    diffuse, f0, alpha = _expected(np.array(base_factor) * tex, m, r)
    spec = sc.materials.specular.params
    # the texture is constant: its one-ring average is its value whatever the quadrature
    assert np.allclose(sc.materials.diffuse[idx].numpy(), diffuse, atol=ATOL)
    assert np.allclose(spec["f0"][idx].numpy(), f0, atol=ATOL)
    assert np.allclose(spec["alpha"][idx].numpy(), alpha, atol=ATOL)


def _check_plain(sc, idx, base_factor=PLAIN_FACTOR, metal=PLAIN_METAL, rough=PLAIN_ROUGH):
    # each vertex's own COLOR_0 (found by position: the quad's corners are distinct)
    corners = _quad(1.0)["POSITION"]
    pos = sc.mesh.vertices[idx].numpy()
    k = np.argmin(np.abs(pos[:, None, :] - corners[None]).sum(-1), axis=1)
    diffuse, f0, alpha = _expected(np.array(base_factor) * PLAIN_COLORS[k], metal, rough)
    spec = sc.materials.specular.params
    assert np.allclose(sc.materials.diffuse[idx].numpy(), diffuse, atol=ATOL)
    assert np.allclose(spec["f0"][idx].numpy(), f0, atol=ATOL)
    assert np.allclose(spec["alpha"][idx].numpy(), np.broadcast_to(alpha, len(idx)), atol=ATOL)


@pytest.fixture
def glb(tmp_path):
    p = tmp_path / "two.glb"
    two_material_glb(p)
    return p


@pytest.mark.parametrize("suffix", [".glb", ".gltf"])
def test_a_bare_gltf_scene_has_its_materials_per_vertex(tmp_path, suffix):
    glb = tmp_path / f"two{suffix}"
    two_material_glb(glb)
    sc = scene.load(glb)
    assert sc.materials.model == "ggx_schlick" and sc.name == "two"
    # the mesh is the loader's: the shared edge split by material, 4 + 4 vertices
    assert sc.mesh.n_vertices == scene.load_gltf(glb).mesh.n_vertices == 8
    records = {r["name"]: r for r in sc.material_records}
    idx = _by_material(sc, sc.material_records)
    _check_painted(sc, idx["painted"])
    _check_plain(sc, idx["plain"])
    assert records["painted"] == {
        "name": "painted",
        "model": "ggx_schlick",
        "vertices": 4,
        "textures": ["baseColorTexture", "metallicRoughnessTexture"],
        "override": "",
    }
    assert records["plain"]["textures"] == [] and records["plain"]["vertices"] == 4
    # the camera frames the mesh, as a bare mesh's does
    assert sc.camera == scene.default_camera(sc.mesh)


def test_uv_seams_and_hard_edges_stay_split(tmp_path):
    """Two triangles of one material sharing an edge with one normal but different UVs on it
    (a UV seam): the scene keeps 6 vertices, as the glTF loader gives them (a bare mesh welded
    by position and normal would have 4); a fold with different normals stays hard."""
    v = np.float32([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    uv = np.float32([[0, 0], [0.5, 0], [0, 0.5], [0.6, 0], [1, 1], [0, 0.6]])
    n = np.tile(np.float32([0, 0, 1]), (6, 1))
    prim = {"POSITION": v, "NORMAL": n, "TEXCOORD_0": uv, "indices": [[0, 1, 2], [3, 4, 5]],
            "material": 0}  # fmt: skip
    tex = _png(np.random.default_rng(0).integers(0, 255, (8, 8, 3)))
    mat = {"name": "m", "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}
    p = tmp_path / "seam.glb"
    write_glb(p, [prim], [mat], [tex])
    assert scene.load(p).mesh.n_vertices == 6
    assert scene.load_mesh(p).n_vertices == 4  # the seam welded where UVs are dropped


def test_a_fine_checker_keeps_its_mean_over_the_surface(tmp_path):
    """A 15 x 15 black-and-white checker (nearest filtering) on one quad: its four corners
    are all white, so read at the vertices the quad would be white; the scene's per-vertex
    albedo, interpolated over the quad, keeps the checker's mean 113/225."""
    i, j = np.meshgrid(np.arange(15), np.arange(15), indexing="ij")
    checker = np.where((i + j) % 2 == 0, 255, 0).astype(np.uint8)
    tex = _png(np.repeat(checker[..., None], 3, axis=2))
    mat = {"name": "c", "pbrMetallicRoughness": {"baseColorTexture": {"index": 0},
                                                 "metallicFactor": 0.0}}  # fmt: skip
    p = tmp_path / "checker.glb"
    write_glb(p, [_quad(0.0, material=0)], [mat], [tex], samplers=[{"magFilter": 9728}])
    sc = scene.load(p)
    # the surface mean of the interpolated per-vertex values: each vertex weighs a third of
    # its faces' area (the integral of its hat function)
    area = scene.triangle_areas(sc.mesh).double()
    w = torch.zeros(sc.mesh.n_vertices, dtype=torch.float64)
    w.index_add_(0, sc.mesh.faces.reshape(-1), (area / 3).repeat_interleave(3))
    mean = float((sc.materials.diffuse[:, 0].double() * w).sum() / w.sum())
    # 11^2 midpoint samples per triangle (the quadrature for its 112 texels) over cells of
    # 0 and 1 miscount only slivers along the cells' edges: a few 1e-3; a vertex reading
    # would give 1
    assert abs(mean - 113 / 225) < 0.01


def _scene_file(tmp_path, text: str, name: str = "s.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


CAMERA = "[camera]\norigin = [0.5, 0.5, 4]\ntarget = [1, 0.5, 0]\nfov = 30\n"


def test_a_scene_file_overrides_materials_by_name_and_keeps_its_camera(glb, tmp_path):
    p = _scene_file(
        tmp_path,
        f"""
mesh = "{glb.name}"
name = "over"

[materials.plain]
base_color = [0.9, 0.1, 0.3]
metallic = 1.0

[materials.painted]
roughness = 0.5
textures = false

{CAMERA}""",
    )
    sc = scene.load(p)
    assert sc.name == "over" and sc.camera.fov == 30 and sc.camera.origin == (0.5, 0.5, 4.0)
    idx = _by_material(sc, sc.material_records)
    # painted: its factors (roughness replaced), no textures
    _check_painted(sc, idx["painted"], rough=0.5, texture=False)
    # plain: the new base colour and metallic, still times its vertex colours; roughness kept
    _check_plain(sc, idx["plain"], base_factor=(0.9, 0.1, 0.3), metal=1.0)
    overrides = {r["name"]: r["override"] for r in sc.material_records}
    assert overrides == {"painted": "[materials.painted]", "plain": "[materials.plain]"}
    # the same as JSON
    js = _scene_file(tmp_path, json.dumps({"mesh": glb.name, "materials": {
        "plain": {"base_color": [0.9, 0.1, 0.3], "metallic": 1.0}}}), "s.json")  # fmt: skip
    _check_plain(scene.load(js), idx["plain"], base_factor=(0.9, 0.1, 0.3), metal=1.0)


def test_a_scene_file_without_overrides_keeps_the_file_s_materials(glb, tmp_path):
    sc = scene.load(_scene_file(tmp_path, f'mesh = "{glb.name}"\n'))
    idx = _by_material(sc, sc.material_records)
    _check_painted(sc, idx["painted"])
    _check_plain(sc, idx["plain"])
    assert all(r["override"] == "" for r in sc.material_records)


def test_material_table_or_option_replaces_all_gltf_materials(glb, tmp_path):
    p = _scene_file(tmp_path, f'mesh = "{glb.name}"\n[material]\ndiffuse = 0.3\n')
    sc = scene.load(p)
    assert sc.mesh.n_vertices == 8  # still the glTF's mesh
    assert sc.materials.model == "none" and torch.allclose(sc.materials.diffuse, torch.tensor(0.3))
    assert {r["override"] for r in sc.material_records} == {"[material]"}
    sc = scene.load(glb, material="ggx:alpha=0.2,specular=0.5")
    assert sc.materials.model == "ggx" and float(sc.materials.diffuse.abs().max()) == 0
    assert {(r["model"], r["override"]) for r in sc.material_records} == {("ggx", "--material")}


def test_a_bad_material_name_names_the_scene_file_and_lists_the_names(glb, tmp_path):
    p = _scene_file(tmp_path, f'mesh = "{glb.name}"\n[materials.pianted]\nroughness = 0.5\n')
    with pytest.raises(InputError) as e:
        scene.load(p)
    assert str(p) in e.value.what and "materials.pianted" in e.value.what
    assert "no material 'pianted'" in e.value.problem
    assert "'painted', 'plain'" in e.value.problem


@pytest.mark.parametrize(
    ("text", "what", "problem"),
    [
        ("[materials.plain]\nroughness = 2\n", "materials.plain.roughness", "in [0, 1]"),
        ("[materials.plain]\nmetallic = true\n", "materials.plain.metallic", "in [0, 1]"),
        ("[materials.plain]\nalpha = 0.1\n", "materials.plain.alpha", "unknown key"),
        ('[materials.plain]\ntextures = "no"\n', "materials.plain.textures", "true or false"),
        ("[materials.plain]\nbase_color = [1, 2]\n", "materials.plain.base_color", "RGB"),
        ("[materials]\nplain = 3\n", "materials.plain", "table"),
        ("[material]\ndiffuse = 0.5\n[materials.plain]\nmetallic = 1\n", "", "not"),
    ],
)
def test_bad_overrides_are_named(glb, tmp_path, text, what, problem):
    p = _scene_file(tmp_path, f'mesh = "{glb.name}"\n{text}')
    with pytest.raises(InputError) as e:
        scene.load(p)
    assert e.value.what == f"{p}: {what}".rstrip(": ") and problem in e.value.problem


def test_materials_with_a_mesh_that_is_not_gltf(tmp_path):
    (tmp_path / "t.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    p = _scene_file(tmp_path, 'mesh = "t.obj"\n[materials.x]\nmetallic = 1\n')
    with pytest.raises(InputError, match="not a glTF file"):
        scene.load(p)


def test_the_unsupported_features_warning_reaches_the_user_once(tmp_path, capsys):
    p = tmp_path / "e.glb"
    two_material_glb(p, emissive=True)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")  # a second warning would show, not be folded
        scene.load(p)
    notes = [str(w.message) for w in caught if "not supported" in str(w.message)]
    assert notes == [f"lobelight: {p}: not supported, ignored: emissive"]
    # the command line: one line on stderr, without Python's source-line trailer
    model = tmp_path / "e.npz"
    bake = ["bake", p, "-o", model, "--indirect-paths", 0, "--bounces", 0, "--json"]
    assert main([str(a) for a in bake]) == 0
    err = capsys.readouterr().err
    assert err.count("not supported") == 1
    assert f"lobelight: {p}: not supported, ignored: emissive\n" in err
    assert "warnings.warn" not in err and "UserWarning" not in err


def test_bake_and_info_of_a_gltf(glb, tmp_path, capsys):
    """``lobelight bake x.glb`` end to end: the file's materials in the summary, the model's
    provenance and ``lobelight info``; ``--material`` replaces them and says so."""
    model = tmp_path / "two.npz"
    assert main(["bake", str(glb), "-o", str(model), "--json"]) == 0
    bake = json.loads(capsys.readouterr().out)
    assert bake["vertices"] == 8 and bake["material"] == "ggx_schlick"
    rows = {r["name"]: r for r in bake["materials"]}
    assert rows["painted"] == {"name": "painted", "model": "ggx_schlick", "vertices": 4,
                               "textures": "baseColor, metallicRoughness",
                               "override": "-"}  # fmt: skip
    assert rows["plain"]["textures"] == "-"

    assert main(["info", str(model), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["materials"] == bake["materials"]
    assert [r["name"] for r in info["provenance"]["materials"]] == ["painted", "plain"]
    # the model's own per-vertex materials are the scene's
    baked = load_model(model).materials.specular.params["f0"]
    assert torch.allclose(baked, scene.load(glb).materials.specular.params["f0"], atol=ATOL)
    # text: a table of the materials
    assert main(["info", str(model)]) == 0
    lines = [line.split() for line in capsys.readouterr().out.splitlines()]
    assert ["materials:"] in lines
    assert ["painted", "ggx_schlick", "4", "baseColor,", "metallicRoughness", "-"] in lines

    # --material replaces them: said on stderr, recorded
    out2 = tmp_path / "grey.npz"
    args = ["bake", str(glb), "-o", str(out2), "--material", "diffuse:color=0.5",
            "--indirect-paths", "0", "--bounces", "0", "--json"]  # fmt: skip
    assert main(args) == 0
    captured = capsys.readouterr()
    assert "--material replaces the materials of the glTF file ('painted', 'plain')" in (
        captured.err
    )
    rows = json.loads(captured.out)["materials"]
    assert {(r["model"], r["override"]) for r in rows} == {("none", "--material")}


def test_the_doc_describes_the_overrides():
    """docs/scene-format.md lists every override key, and its example's keys are accepted."""
    doc = (Path(__file__).resolve().parents[1] / "docs" / "scene-format.md").read_text()
    section = doc.split("## glTF materials", 1)[1].split("\n## ", 1)[0]
    for key in scene.MATERIAL_OVERRIDE_KEYS:
        assert f"| `{key}` |" in section, key
    example = tomllib.loads(section.split("```toml", 1)[1].split("```", 1)[0])
    for name, table in example["materials"].items():
        assert set(table) <= set(scene.MATERIAL_OVERRIDE_KEYS), name
    assert set(example) <= set(scene.SCENE_KEYS)


def test_an_override_reaches_every_material_of_its_name(tmp_path):
    """Two materials of one name (exporters repeat names): both get the override."""
    p = tmp_path / "same.glb"
    mats = [{"name": "same", "pbrMetallicRoughness": {"roughnessFactor": r}} for r in (0.2, 0.9)]
    write_glb(p, [_quad(0.0, material=0), _quad(1.0, material=1)], mats)
    assert sorted(set(scene.load(p).materials.specular.params["alpha"].tolist())) == pytest.approx(
        [0.04, 0.81]
    )
    s = _scene_file(tmp_path, 'mesh = "same.glb"\n[materials.same]\nroughness = 0.5\n')
    alpha = scene.load(s).materials.specular.params["alpha"]
    assert torch.allclose(alpha, torch.tensor(0.25))
