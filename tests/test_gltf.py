"""glTF 2.0 loading: geometry in world space, materials and textures, welding, sampling, and
bad files named by their part.

Every asset here is written by :class:`Gltf` below from plain arrays (JSON plus one binary
buffer), so each expected value is known independently of the loader.
"""

from __future__ import annotations

import base64
import io
import json
import math
import struct
import warnings

import numpy as np
import pytest
import torch
from PIL import Image

from lobelight import scene
from lobelight.errors import InputError

# float32 positions and normals round-trip through the file exactly; the transforms are
# float64 products of float32 inputs: 1e-5 covers float32 rounding of coordinates of size ~3
ATOL = 1e-5


class Gltf:
    """A glTF document being written: accessors appended to one binary buffer."""

    def __init__(self):
        self.blob = bytearray()
        self.doc = {"asset": {"version": "2.0"}, "buffers": [], "bufferViews": [],
                    "accessors": [], "meshes": [], "nodes": [], "scenes": [{"nodes": []}],
                    "scene": 0}  # fmt: skip

    def view(self, data: bytes) -> int:
        while len(self.blob) % 4:
            self.blob.append(0)
        self.doc["bufferViews"].append(
            {"buffer": 0, "byteOffset": len(self.blob), "byteLength": len(data)}
        )
        self.blob += data
        return len(self.doc["bufferViews"]) - 1

    def accessor(self, a, kind: str, ctype: int = 5126, normalized: bool = False) -> int:
        dtype = {5126: "<f4", 5125: "<u4", 5123: "<u2", 5121: "u1"}[ctype]
        a = np.ascontiguousarray(a, dtype=dtype)
        acc = {"bufferView": self.view(a.tobytes()), "componentType": ctype,
               "count": len(a), "type": kind}  # fmt: skip
        if normalized:
            acc["normalized"] = True
        self.doc["accessors"].append(acc)
        return len(self.doc["accessors"]) - 1

    def primitive(self, v, f=None, *, normals=None, uvs=None, colors=None, material=None,
                  mode=None) -> dict:  # fmt: skip
        attrs = {"POSITION": self.accessor(v, "VEC3")}
        if normals is not None:
            attrs["NORMAL"] = self.accessor(normals, "VEC3")
        if uvs is not None:
            attrs["TEXCOORD_0"] = self.accessor(uvs, "VEC2")
        if colors is not None:
            attrs["COLOR_0"] = self.accessor(colors, f"VEC{np.shape(colors)[1]}")
        p = {"attributes": attrs}
        if f is not None:
            p["indices"] = self.accessor(np.asarray(f).reshape(-1), "SCALAR", 5125)
        if material is not None:
            p["material"] = material
        if mode is not None:
            p["mode"] = mode
        return p

    def mesh(self, *prims, **node) -> int:
        self.doc["meshes"].append({"primitives": list(prims)})
        self.doc["nodes"].append({"mesh": len(self.doc["meshes"]) - 1, **node})
        self.doc["scenes"][0]["nodes"].append(len(self.doc["nodes"]) - 1)
        return len(self.doc["nodes"]) - 1

    def image(self, rgb: np.ndarray, *, uri: str | None = None, sampler: dict | None = None):
        """Add a PNG texture (in the buffer, or as file ``uri``); returns (texture index, png)."""
        buf = io.BytesIO()
        Image.fromarray(rgb).save(buf, format="PNG")
        png = buf.getvalue()
        img = {"uri": uri} if uri else {"bufferView": self.view(png), "mimeType": "image/png"}
        self.doc.setdefault("images", []).append(img)
        tex = {"source": len(self.doc["images"]) - 1}
        if sampler is not None:
            self.doc.setdefault("samplers", []).append(sampler)
            tex["sampler"] = len(self.doc["samplers"]) - 1
        self.doc.setdefault("textures", []).append(tex)
        return len(self.doc["textures"]) - 1, png

    def write(self, path, how: str = "glb") -> None:
        """``glb``, ``datauri`` (.gltf, the buffer inline) or ``external`` (.gltf + .bin)."""
        doc = json.loads(json.dumps(self.doc))
        blob = bytes(self.blob)
        if how == "glb":
            doc["buffers"] = [{"byteLength": len(blob)}]
            js = json.dumps(doc).encode()
            js += b" " * (-len(js) % 4)
            blob += b"\0" * (-len(blob) % 4)
            body = struct.pack("<II", len(js), 0x4E4F534A) + js
            body += struct.pack("<II", len(blob), 0x004E4942) + blob
            path.write_bytes(b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body)
            return
        if how == "datauri":
            uri = "data:application/octet-stream;base64," + base64.b64encode(blob).decode()
        else:
            uri = path.stem + ".bin"
            (path.parent / uri).write_bytes(blob)
        doc["buffers"] = [{"uri": uri, "byteLength": len(blob)}]
        path.write_text(json.dumps(doc))


def _quad(x0=0.0):
    v = np.array([[x0, 0, 0], [x0 + 1, 0, 0], [x0 + 1, 1, 0], [x0, 1, 0]], np.float32)
    uv = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], np.float32)  # glTF: V down the image
    return v, np.array([[0, 1, 2], [0, 2, 3]]), uv


def _checker(n=4) -> np.ndarray:
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    c = np.where((i + j) % 2 == 0, 255, 0).astype(np.uint8)
    return np.stack([c, np.full_like(c, 128), np.full_like(c, 64)], -1)  # (n, n, 3)


def _srgb(c):
    c = np.asarray(c, np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def two_material_quads(g: Gltf) -> None:
    """Two unit quads side by side: material 0 textured (base colour + metallic-roughness,
    clamp/mirror sampler), material 1 plain factors with vertex colours."""
    tex, _ = g.image(_checker(), sampler={"wrapS": 33071, "wrapT": 33648, "magFilter": 9728})
    mr = np.zeros((2, 2, 3), np.uint8)
    mr[..., 1], mr[..., 2] = 51, 204  # G = rough 0.2, B = metal 0.8
    mrt, _ = g.image(mr)
    g.doc["materials"] = [
        {"name": "painted", "pbrMetallicRoughness": {
            "baseColorFactor": [1.0, 0.5, 1.0, 1.0], "baseColorTexture": {"index": tex},
            "metallicFactor": 0.5, "roughnessFactor": 1.0,
            "metallicRoughnessTexture": {"index": mrt}}, "doubleSided": True},
        {"name": "plain", "pbrMetallicRoughness": {
            "baseColorFactor": [0.2, 0.4, 0.6, 1.0], "metallicFactor": 0.0,
            "roughnessFactor": 0.7}},
    ]  # fmt: skip
    v, f, uv = _quad()
    n = np.tile([0, 0, 1], (4, 1))
    g.mesh(
        g.primitive(v, f, normals=n, uvs=uv, material=0),
        g.primitive(_quad(1.0)[0], f, normals=n, uvs=uv, material=1,
                    colors=np.tile([0.5, 1.0, 1.0], (4, 1))),
    )  # fmt: skip


@pytest.mark.parametrize("how", ["glb", "datauri", "external"])
def test_two_material_textured_quads(tmp_path, how):
    g = Gltf()
    two_material_quads(g)
    p = tmp_path / ("a.glb" if how == "glb" else "a.gltf")
    g.write(p, how)
    a = scene.load_gltf(p)
    # the shared edge's vertices differ in material (and UV): split, 4 + 4 vertices
    assert a.mesh.n_vertices == 8 and a.mesh.n_faces == 4
    assert [m.name for m in a.materials] == ["painted", "plain", "default"]
    painted, plain = a.materials[:2]
    assert painted.double_sided and not plain.double_sided
    assert painted.metallic == 0.5 and plain.roughness == pytest.approx(0.7)
    assert painted.base_color_texture.sampler == scene.Sampler("clamp", "mirror", "nearest")
    assert painted.metallic_roughness_texture.sampler == scene.Sampler()  # the defaults
    # colour textures are sRGB-decoded, data textures not (PNG 8-bit values / 255)
    img = painted.base_color_texture.image
    assert img.shape == (4, 4, 4)
    assert float(img[0, 0, 0]) == pytest.approx(1.0)
    assert float(img[0, 0, 1]) == pytest.approx(float(_srgb(128 / 255)), abs=1e-6)
    mr = painted.metallic_roughness_texture.image
    assert float(mr[0, 0, 1]) == pytest.approx(51 / 255) and mr.shape[-1] == 3
    assert torch.equal(a.face_material.sort().values, torch.tensor([0, 0, 1, 1]))
    # every vertex keeps its UV and material: position x in [0, 1] is material 0
    x = a.mesh.vertices[:, 0]
    left = a.material == 0
    assert bool((x[left] <= 1).all()) and bool((x[~left] >= 1).all())
    fac = scene.vertex_factors(a)
    # material 1: factor x COLOR_0 (0.5, 1, 1); no textures
    want = torch.tensor([0.1, 0.4, 0.6])
    assert torch.allclose(fac.base_color[~left], want.expand(4, 3), atol=1e-6)
    assert torch.allclose(fac.roughness[~left], torch.tensor(0.7), atol=1e-6)
    # material 0: metallic = 0.5 x B (0.8), roughness = 1 x G (0.2)
    assert torch.allclose(fac.metallic[left], torch.tensor(0.5 * 204 / 255), atol=1e-6)
    assert torch.allclose(fac.roughness[left], torch.tensor(51 / 255), atol=1e-6)


def test_formats_agree(tmp_path):
    g = Gltf()
    two_material_quads(g)
    out = []
    for how, name in (("glb", "a.glb"), ("datauri", "b.gltf"), ("external", "c.gltf")):
        g.write(tmp_path / name, how)
        out.append(scene.load_gltf(tmp_path / name))
    for a in out[1:]:
        assert torch.equal(a.mesh.vertices, out[0].mesh.vertices)
        assert torch.equal(a.uvs, out[0].uvs)


def _box(g: Gltf, *, normals: bool, **node):
    """A unit cube as 6 faces of 4 vertices with face-flat normals (24 vertices)."""
    tm = __import__("trimesh").creation.box()
    v = tm.vertices[tm.faces].reshape(-1, 3).astype(np.float32)  # (36, 3) split corners
    n = np.repeat(tm.face_normals, 3, 0).astype(np.float32)
    return g.mesh(g.primitive(v, np.arange(36), normals=n if normals else None), **node)


def test_box_hard_edges_stay_hard(tmp_path):
    """Regression: every mesh was welded by position, so a box's corners got averaged
    normals. With the file's flat normals its 8 corners stay 24 vertices, each with its face's
    normal; without normals it welds to 8 vertices with area-weighted (diagonal) normals."""
    for normals, count in ((True, 24), (False, 8)):
        g = Gltf()
        _box(g, normals=normals)
        g.write(tmp_path / "box.glb")
        for m in (
            scene.load_gltf(tmp_path / "box.glb").mesh,
            scene.load_mesh(tmp_path / "box.glb"),
        ):
            assert m.n_vertices == count
            # each vertex normal against the normals of the faces around it
            fn = m.face_normals[:, None].expand(-1, 3, -1).reshape(-1, 3)
            cos = (m.normals[m.faces.reshape(-1)] * fn).sum(-1)
            if normals:  # flat: equal to every adjacent face's normal
                assert torch.allclose(cos, torch.ones_like(cos), atol=1e-6)
            else:  # the sum of the adjacent triangles' cross products, written out
                v, want = m.vertices.double(), torch.zeros(8, 3, dtype=torch.float64)
                for a, b, c in m.faces.tolist():
                    for k in (a, b, c):
                        want[k] += torch.linalg.cross(v[b] - v[a], v[c] - v[a])
                want /= want.norm(dim=1, keepdim=True)
                assert torch.allclose(m.normals.double(), want, atol=1e-6)


def _rotation_z(deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def test_node_transforms_compose(tmp_path):
    """A parent's matrix times a child's T * R * S, against the transforms written out."""
    g = Gltf()
    q = [0, 0, math.sin(math.radians(45)), math.cos(math.radians(45))]  # 90 deg about z
    child = _box(g, normals=True, translation=[1, 2, 3], rotation=q, scale=[2, 1, 1])
    g.doc["scenes"][0]["nodes"].remove(child)
    parent = np.eye(4)
    parent[:3, 3] = [10, 0, 0]
    g.doc["nodes"].append({"children": [child], "matrix": parent.T.reshape(-1).tolist()})
    g.doc["scenes"][0]["nodes"].append(len(g.doc["nodes"]) - 1)
    g.write(tmp_path / "t.glb")
    geom, _ = scene.read_gltf(tmp_path / "t.glb")
    tm = __import__("trimesh").creation.box()
    local = tm.vertices[tm.faces].reshape(-1, 3)
    want = (local * [2, 1, 1]) @ _rotation_z(90).T + [1, 2, 3] + [10, 0, 0]
    assert np.allclose(geom.positions, want, atol=ATOL)
    # normals: inverse transpose of R * S, normalised (the +x face stays along R's x axis)
    n_local = np.repeat(tm.face_normals, 3, 0)
    want_n = (n_local / [2, 1, 1]) @ _rotation_z(90).T
    want_n /= np.linalg.norm(want_n, axis=1, keepdims=True)
    assert np.allclose(geom.normals, want_n, atol=ATOL)


def test_mirrored_node_flips_winding(tmp_path):
    """A scale of -1 mirrors the box; its faces' geometric normals (from the winding) must
    still point outwards, along the file's transformed normals."""
    g = Gltf()
    _box(g, normals=True, scale=[-1, 1, 1], translation=[5, 0, 0])
    g.write(tmp_path / "m.glb")
    m = scene.load_gltf(tmp_path / "m.glb").mesh
    centre = m.vertices.mean(0)
    assert torch.allclose(centre, torch.tensor([5.0, 0, 0]), atol=ATOL)
    tri = m.vertices[m.faces].mean(1)  # (F, 3) face centres
    assert bool(((tri - centre) * m.face_normals).sum(-1).gt(0).all())  # outward
    assert bool((m.normals[m.faces[:, 0]] * m.face_normals).sum(-1).gt(0.999).all())


def test_strip_and_fan_match_triangles(tmp_path):
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0, 2, 0], [1, 2, 0]], np.float32)
    g = Gltf()
    g.mesh(g.primitive(v, mode=5))  # strip: (0 1 2) (2 1 3) (2 3 4) (4 3 5)
    g.write(tmp_path / "s.glb")
    geom, _ = scene.read_gltf(tmp_path / "s.glb")
    assert geom.faces.tolist() == [[0, 1, 2], [2, 1, 3], [2, 3, 4], [4, 3, 5]]
    fan = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float32)
    g = Gltf()
    g.mesh(g.primitive(fan, mode=6))
    g.write(tmp_path / "f.glb")
    geom, _ = scene.read_gltf(tmp_path / "f.glb")
    assert geom.faces.tolist() == [[0, 1, 2], [0, 2, 3]]
    # both wound counter-clockwise about +z
    m = scene.load_gltf(tmp_path / "s.glb").mesh
    assert bool((m.face_normals[:, 2] > 0.999).all())


def test_unsupported_features_named_in_one_warning(tmp_path):
    g = Gltf()
    v, f, uv = _quad()
    tex, _ = g.image(_checker())
    g.doc["materials"] = [{
        "emissiveFactor": [1, 0, 0], "alphaMode": "BLEND", "occlusionTexture": {"index": tex},
        "extensions": {"KHR_materials_clearcoat": {}},
        "pbrMetallicRoughness": {"baseColorTexture": {
            "index": tex, "extensions": {"KHR_texture_transform": {"scale": [2, 2]}}}},
    }]  # fmt: skip
    g.doc["extensionsUsed"] = [
        "KHR_materials_clearcoat", "KHR_texture_transform", "KHR_lights_punctual"
    ]  # fmt: skip
    g.mesh(g.primitive(v, f, uvs=uv, material=0))
    g.write(tmp_path / "w.glb")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        a = scene.load_gltf(tmp_path / "w.glb")
    lines = [str(w.message) for w in caught]
    assert len(lines) == 1 and "\n" not in lines[0], lines
    for name in ("emissive", "alphaMode BLEND", "occlusionTexture", "KHR_materials_clearcoat",
                 "KHR_lights_punctual", str(tmp_path / "w.glb")):  # fmt: skip
        assert name in lines[0]
    assert "KHR_texture_transform" not in lines[0]  # read, not ignored
    assert "emissive" in a.materials[0].unsupported
    # a plain file warns about nothing
    g = Gltf()
    g.mesh(g.primitive(v, f))
    g.write(tmp_path / "plain.glb")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scene.load_gltf(tmp_path / "plain.glb")


def test_texture_transform(tmp_path):
    """KHR_texture_transform: UVs go through offset * rotation * scale before the read; the
    rotation turns (1, 0) towards (0, -1) in UV space (V down), the sense of the sample model
    TextureTransformTest and of the viewers."""
    g = Gltf()
    v, f, uv = _quad()
    tex, _ = g.image(_checker())
    r = 0.3
    ext = {"offset": [0.25, 0.5], "rotation": r, "scale": [0.5, 2.0]}
    info = {"index": tex, "extensions": {"KHR_texture_transform": ext}}
    g.doc["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": info}}]
    g.mesh(g.primitive(v, f, uvs=uv, material=0))
    g.write(tmp_path / "t.glb")
    t = scene.load_gltf(tmp_path / "t.glb").materials[0].base_color_texture
    plain = scene.Texture(t.image, t.sampler, "plain")
    q = torch.rand(50, 2, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    su, sv = 0.5 * q[:, 0], 2.0 * q[:, 1]
    c, s = math.cos(r), math.sin(r)
    moved = torch.stack([c * su + s * sv + 0.25, -s * su + c * sv + 0.5], -1)
    assert torch.allclose(scene.sample_texture(t, q), scene.sample_texture(plain, moved), atol=1e-6)


# --------------------------------------------------------------------------------------------
# texture sampling, against a direct reading of the texel grid


def _texture(img, **sampler) -> scene.Texture:
    return scene.Texture(torch.as_tensor(img, dtype=torch.float32), scene.Sampler(**sampler), "t")


def _reference_bilinear(img, u, v, wrap):
    """Bilinear filtering written out texel by texel (numpy, float64)."""
    h, w = img.shape[:2]
    x, y = u * w - 0.5, v * h - 0.5
    x0, y0 = math.floor(x), math.floor(y)

    def at(i, n):
        if wrap == "clamp":
            return min(max(i, 0), n - 1)
        if wrap == "mirror":
            j = i % (2 * n)
            return 2 * n - 1 - j if j >= n else j
        return i % n

    out = 0.0
    for dx, dy in ((0, 0), (1, 0), (0, 1), (1, 1)):
        wx = (x - x0) if dx else (1 - (x - x0))
        wy = (y - y0) if dy else (1 - (y - y0))
        out = out + wx * wy * img[at(y0 + dy, h), at(x0 + dx, w)]
    return out


@pytest.mark.parametrize("wrap", ["repeat", "clamp", "mirror"])
def test_sample_texture_bilinear_and_wraps(wrap):
    rng = np.random.default_rng(3)
    img = rng.random((3, 5, 2))
    uv = rng.uniform(-2.5, 2.5, (200, 2))
    got = scene.sample_texture(_texture(img, wrap_s=wrap, wrap_t=wrap), torch.as_tensor(uv))
    want = np.array([_reference_bilinear(img, u, v, wrap) for u, v in uv])
    assert np.allclose(got.numpy(), want, atol=1e-5)  # float32 texels and weights


@pytest.mark.parametrize("wrap", ["repeat", "clamp", "mirror"])
def test_sample_texture_at_huge_uvs_is_finite(wrap):
    """A UV a file may hold, -1.7e38 (float32, an even integer): times the texture's height it
    overflows float32. It reads as its wrapped equivalent, 0 for repeat and mirror (a whole
    number of periods) and the edge for clamp (which is where 0 reads)."""
    img = np.random.default_rng(4).random((4, 4, 3))
    t = _texture(img, wrap_s=wrap, wrap_t=wrap)
    uv = torch.tensor([[0.3, -1.7014118e38], [1.7014118e38, 0.6]], dtype=torch.float32)
    got = scene.sample_texture(t, uv)
    want = scene.sample_texture(t, torch.tensor([[0.3, 0.0], [0.0, 0.6]]))
    assert bool(torch.isfinite(got).all())
    if wrap == "clamp":  # the far side's edge for +1.7e38
        want[1] = scene.sample_texture(t, torch.tensor([[1.0, 0.6]]))[0]
    torch.testing.assert_close(got, want)


def test_sample_texture_texel_centres_and_nearest():
    img = np.arange(12, dtype=np.float64).reshape(3, 4, 1)
    t = _texture(img)
    centres = torch.tensor([[(j + 0.5) / 4, (i + 0.5) / 3] for i in range(3) for j in range(4)])
    assert torch.allclose(scene.sample_texture(t, centres)[:, 0], torch.arange(12.0))
    near = _texture(img, mag_filter="nearest")
    off = centres + torch.tensor([0.1 / 4, -0.2 / 3])  # within each texel
    assert torch.equal(scene.sample_texture(near, off)[:, 0], torch.arange(12.0))


def test_one_ring_average_of_linear_texture_is_its_value():
    """A texture linear in U (clamped, bilinear: linear between texel centres) averaged over
    a symmetric one-ring with the hat weight gives the vertex's own value (the hat-weighted
    mean of a linear function over a centrally symmetric ring is the centre's value); on a
    checkerboard finer than the mesh the two readings differ."""
    n = 4
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    v = np.stack([i.ravel(), j.ravel(), np.zeros(i.size)], 1) / n
    q = (i[:-1, :-1] * (n + 1) + j[:-1, :-1]).ravel()
    f = np.concatenate([np.stack([q, q + n + 1, q + n + 2], 1), np.stack([q, q + n + 2, q + 1], 1)])
    w = 64
    ramp = np.broadcast_to(np.linspace(0.5 / w, 1 - 0.5 / w, w)[None, :, None], (8, w, 3))
    uvs = torch.as_tensor(v[:, :2] * 0.5 + 0.25, dtype=torch.float32)  # well inside the texture
    mesh = scene.mesh_from_arrays(v, f, weld=False)
    tex = _texture(np.ascontiguousarray(ramp), wrap_s="clamp", wrap_t="clamp")
    mat = scene.GltfMaterial("ramp", metallic=0.0, base_color_texture=tex)
    asset = scene.GltfAsset(mesh, uvs, torch.ones(len(v), 4), torch.zeros(len(v), dtype=torch.long),
                            (mat,))  # fmt: skip
    at = scene.vertex_factors(asset)
    ring = scene.vertex_factors(asset, average="one_ring")
    interior = torch.as_tensor(((i > 0) & (i < n) & (j > 0) & (j < n)).ravel())
    assert torch.allclose(at.base_color[:, 0], uvs[:, 0], atol=1e-5)
    assert torch.allclose(ring.base_color[interior, 0], uvs[interior, 0], atol=1e-5)
    fine = _texture(np.kron(_checker(16)[..., :1] / 255.0, np.ones((1, 1, 3))))
    asset = scene.GltfAsset(mesh, uvs, torch.ones(len(v), 4), torch.zeros(len(v), dtype=torch.long),
                            (scene.GltfMaterial("c", base_color_texture=fine),))  # fmt: skip
    ring = scene.vertex_factors(asset, average="one_ring").base_color[interior, 0]
    # the one-ring average of a fine checker tends to its mean 0.5 (16 samples per face)
    assert float((ring - 0.5).abs().max()) < 0.2


# --------------------------------------------------------------------------------------------
# bad files: one InputError naming the file and the part


def _base() -> Gltf:
    g = Gltf()
    two_material_quads(g)
    return g


def _bad(g: Gltf, tmp_path, how="glb"):
    p = tmp_path / ("x.glb" if how == "glb" else "x.gltf")
    g.write(p, how)
    return p


BAD = {
    "count exceeds view": (lambda d: d["accessors"][0].update(count=10),
                           r"meshes\[0\]\.primitives\[0\]: POSITION accessor 0: count 10 exceeds"),
    "huge count": (lambda d: d["accessors"][0].update(count=2**40), r"POSITION accessor 0"),
    "count mismatch": (lambda d: d["accessors"][1].update(count=3), r"NORMAL.*3 items"),
    "index out of range": (lambda d: d["accessors"][3].update(
        bufferView=d["accessors"][3]["bufferView"]) or d["meshes"][0]["primitives"][0].update(
        indices=99), r"primitives\[0\].*index 99 out of range"),
    "points": (lambda d: d["meshes"][0]["primitives"][1].update(mode=0),
               r"primitives\[1\]: mode POINTS"),
    "lines": (lambda d: d["meshes"][0]["primitives"][0].update(mode=1), r"mode LINES"),
    "no position": (lambda d: d["meshes"][0]["primitives"][0]["attributes"].pop("POSITION"),
                    r"no POSITION"),
    "material index": (lambda d: d["meshes"][0]["primitives"][0].update(material=7),
                       r"material: index 7 out of range"),
    "texture not an image": (lambda d: d["images"][0].update(bufferView=2),
                             r"images\[0\]: not an image"),
    "node cycle": (lambda d: d["nodes"][0].update(children=[0]), r"nodes\[0\].*twice"),
    "required extension": (lambda d: d.update(extensionsRequired=["KHR_draco_mesh_compression"]),
                           r"KHR_draco_mesh_compression"),
    "version": (lambda d: d["asset"].update(version="1.0"), r"asset.version"),
    "view past buffer": (lambda d: d["bufferViews"][0].update(byteLength=10**9),
                         r"bufferViews\[0\].*exceed"),
    "sparse": (lambda d: d["accessors"][0].update(sparse={"count": 1}), r"sparse"),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_file_names_file_and_part(tmp_path, case):
    change, match = BAD[case]
    g = _base()
    change(g.doc)
    p = _bad(g, tmp_path)
    with pytest.raises(InputError, match=match) as e:
        scene.load_gltf(p)
    assert str(p) in str(e.value) and "\n" not in str(e.value)


def test_missing_buffer_and_image_files(tmp_path):
    g = _base()
    p = _bad(g, tmp_path, "external")
    (tmp_path / "x.bin").unlink()
    with pytest.raises(InputError, match=r"buffers\[0\].*x\.bin.*no such file"):
        scene.load_gltf(p)
    g = Gltf()
    v, f, uv = _quad()
    tex, _ = g.image(_checker(), uri="albedo.png")
    g.doc["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": tex}}}]
    g.mesh(g.primitive(v, f, uvs=uv, material=0))
    p = _bad(g, tmp_path, "external")
    with pytest.raises(InputError, match=r"images\[0\].*albedo\.png.*no such file"):
        scene.load_gltf(p)
    # geometry alone does not need the image
    assert scene.load_mesh(p).n_vertices == 4


def test_external_bin_and_png(tmp_path):
    g = Gltf()
    v, f, uv = _quad()
    tex, png = g.image(_checker(), uri="albedo%20map.png")  # URIs are percent-encoded
    (tmp_path / "albedo map.png").write_bytes(png)
    g.doc["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": tex}}}]
    g.mesh(g.primitive(v, f, uvs=uv, material=0))
    p = _bad(g, tmp_path, "external")
    a = scene.load_gltf(p)
    want = _srgb(_checker() / 255.0)
    got = a.materials[0].base_color_texture.image[..., :3].numpy()
    assert np.allclose(got, want, atol=1e-6)


@pytest.mark.parametrize(
    "data,match",
    [(b"glTF\x02\0\0\0\xff\0\0\0", "cut short"), (b"glTF" + struct.pack("<II", 2, 999) + bytes(20),
      "declares 999"), (b"{}", "asset.version"), (b"[1, 2]", "not a glTF document"),
     (b"\xff\xfe", "not a glTF document")],
)  # fmt: skip
def test_bad_containers(tmp_path, data, match):
    p = tmp_path / "c.glb"
    p.write_bytes(data)
    with pytest.raises(InputError, match=match):
        scene.load_gltf(p)
