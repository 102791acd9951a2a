"""A fitted model as a glTF 2.0 binary and back (:func:`lobelight.render.export_gltf`,
:func:`lobelight.render.import_gltf`): the same renders after a round trip, the file loaded by
other libraries (pygltflib, trimesh) and accepted by the Khronos glTF validator, albedo
textures kept, the fallback material the glTF specification's formulas give, and the image-based
light's SH against a closed form."""

from __future__ import annotations

import io
import json
import math
import os
import shutil
import struct
import subprocess
from pathlib import Path

import numpy as np
import pygltflib
import pytest
import torch
import trimesh
from PIL import Image

from lobelight import brdf, envmap, fit, scene
from lobelight._io import protect_inputs, read_input
from lobelight.cli import main
from lobelight.envmap import EnvMap
from lobelight.errors import InputError
from lobelight.geometry.camera import Camera
from lobelight.lobes import sg
from lobelight.render import GLTF_EXTENSION, Renderer, export_gltf, fallback_material, import_gltf
from lobelight.scene import Materials
from test_gltf_scene import two_material_glb

CAMERA = Camera.look_at((0.0, 0.5, 3.0), (0.0, 0.0, 0.0), fov=40.0)
SIZE = 40

# float16 stores each number with a relative rounding of at most 2**-11 (4.9e-4): the light
# of a Gaussian and each SH coefficient directly, its width sigma too (so lam = sigma**-2 by
# 2**-10), and the mean by up to 4.9e-4 rad. A pixel sums a few such terms, each looked up at
# a sharpness and an axis that moved by that much on the smooth built-in map: a few times
# 2**-11 at worst (5e-3), an order less on average (5e-4).
F16_MAX, F16_MEAN = 5e-3, 5e-4
# float32 round trip: the light stored as w * integral(lam) and divided back in float64 (a
# few float32 ulps, 1e-6 relative), the rest bit for bit
F32_REL = 1e-5


def _fit(sc, n):
    return fit.fit_model(sc, n, indirect_paths=0, bounces=0, progress=None)


@pytest.fixture(scope="module")
def diffuse_model():
    """The small rough sphere (ggx alpha 0.1), one Gaussian per view."""
    return _fit(scene.builtin("sphere", subdivisions=1), 1)


@pytest.fixture(scope="module")
def sharp_model():
    """A sharp sphere (ggx alpha 0.03: its lobe is shaded per pixel), two Gaussians."""
    sc = scene.builtin("sphere", subdivisions=1, roughness=0.03)
    assert brdf.sharp_lobe(sc.materials.specular) is not None
    return _fit(sc, 2)


@pytest.fixture(scope="module")
def textured_model(tmp_path_factory):
    """Two quads from a glTF, one with a base colour texture: a model with albedo textures."""
    p = tmp_path_factory.mktemp("tex") / "two.glb"
    two_material_glb(p)
    m = _fit(scene.load(str(p)), 1)
    assert m.albedo is not None and len(m.albedo.images) == 2
    return m


def _render(model, **kw):
    r = Renderer(model, envmap.builtin(), SIZE, SIZE, backend="torch", samples=1)
    return r.render(CAMERA, return_mask=True, **kw)


def _rel(a, b, mask):
    return ((a - b).abs() / a.abs().clamp_min(1e-3))[mask]


@pytest.mark.parametrize("which", ["diffuse_model", "sharp_model"])
def test_float16_round_trip_renders_the_same_images(which, request, tmp_path):
    m = request.getfixturevalue(which)
    p = tmp_path / "m.glb"
    info = export_gltf(m, p)
    assert info["bytes"] == p.stat().st_size
    back = import_gltf(p)
    assert back.n_gaussians == m.n_gaussians and back.sh_order == m.sh_order
    assert torch.equal(back.mesh.faces, m.mesh.faces)
    assert torch.equal(back.mesh.vertices, m.mesh.vertices)
    assert back.materials.to_dict() == m.materials.to_dict()
    a, mask = _render(m)
    b, _ = _render(back)
    assert mask.sum() > 100
    rel = _rel(a, b, mask)
    assert float(rel.max()) < F16_MAX and float(rel.mean()) < F16_MEAN


def test_float16_records_are_the_models_rounded_to_half(sharp_model, tmp_path):
    """The kept records read back as the model's light, mean and width rounded to float16, the
    left-out ones with zero weight.

    Light and width: each read back within half a float16 step of the model's value computed
    in float64, plus 2e-6 of it, because the exporter forms them in float32 before rounding.
    A value that lies within float32's error of a float16 rounding boundary may round either
    way, so comparing against numpy's rounding of the float64 value would be fragile there.
    Truncating instead of rounding, or one step off, exceeds the bound."""
    m = sharp_model
    p = tmp_path / "m.glb"
    export_gltf(m, p)
    back = import_gltf(p)
    g, gb = m.gaussians, back.gaussians
    live = gb.w.amax((-1, -2)) > 0  # (V, J)
    assert live.sum() > 0

    def light_sigma(x):
        lam = x.lam.double()
        return (x.w.double() * sg.integral(lam)[..., None]).numpy(), lam.rsqrt().numpy()

    for got, exact in zip(light_sigma(gb), light_sigma(g), strict=True):
        got, exact = got[live.numpy()], exact[live.numpy()]
        with np.errstate(divide="ignore"):
            e = np.maximum(np.floor(np.log2(np.abs(exact))), -14)  # float16's subnormals below
        half_step = 2.0 ** (e - 11)
        assert (np.abs(got - exact) <= half_step + 2e-6 * np.abs(exact)).all()
        # and most are numpy's own rounding of the exact value
        same = np.isclose(got, exact.astype(np.float16).astype(np.float64), rtol=1e-6, atol=0)
        assert same.mean() > 0.99
    mu16 = g.mu.numpy().astype(np.float16).astype(np.float64)
    mu16 /= np.linalg.norm(mu16, axis=-1, keepdims=True)
    assert np.allclose(back.gaussians.mu.numpy()[live], mu16[live], atol=1e-6)
    # every record with light is kept
    assert bool((live | ~(g.w.amax((-1, -2)) > 0)).all())
    assert np.array_equal(
        back.diffuse.numpy(), m.diffuse.numpy().astype(np.float16).astype(np.float32)
    )


def test_float32_round_trip_is_exact(sharp_model, tmp_path):
    p = tmp_path / "m.glb"
    export_gltf(sharp_model, p, float16=False)
    back = import_gltf(p)
    assert torch.equal(back.diffuse, sharp_model.diffuse)
    a, mask = _render(sharp_model)
    b, _ = _render(back)
    assert float(_rel(a, b, mask).max()) < F32_REL


def test_albedo_textures_round_trip(textured_model, tmp_path):
    m = textured_model
    p = tmp_path / "t.glb"
    export_gltf(m, p, float16=False)
    back = import_gltf(p)
    # the two quads' triangles come back in their order (grouped by layer in the file)
    assert torch.equal(back.mesh.faces, m.mesh.faces)
    a, b = m.albedo, back.albedo
    assert b is not None and len(b.images) == len(a.images)
    for x, y in zip(a.images, b.images, strict=True):
        assert torch.equal(x, y)  # PNG is lossless
    for k in ("uvs", "layer", "factor", "wrap", "transform", "nearest"):
        assert torch.equal(getattr(a, k), getattr(b, k).to(getattr(a, k).dtype)), k
    cam = Camera.look_at((1.0, 0.5, 2.5), (1.0, 0.5, 0.0), fov=50.0)
    ra = Renderer(m, envmap.builtin(), SIZE, SIZE, backend="torch", samples=1)
    rb = Renderer(back, envmap.builtin(), SIZE, SIZE, backend="torch", samples=1)
    ia, mask = ra.render(cam, return_mask=True)
    ib = rb.render(cam)
    assert mask.sum() > 100
    assert float(_rel(ia, ib, mask).max()) < F32_REL


def test_the_textured_fallback_shows_the_texture_in_other_viewers(textured_model, tmp_path):
    """trimesh reads the textured primitive's base colour texture, COLOR_0 and UVs."""
    p = tmp_path / "t.glb"
    export_gltf(textured_model, p)
    doc = pygltflib.GLTF2().load(str(p))
    mats = [mm.pbrMetallicRoughness for mm in doc.materials]
    assert sum(x.baseColorTexture is not None for x in mats) == 1
    assert len(doc.meshes[0].primitives) == 2
    loaded = trimesh.load(str(p), process=False)
    geoms = list(loaded.geometry.values()) if isinstance(loaded, trimesh.Scene) else [loaded]
    assert sum(len(gm.faces) for gm in geoms) == len(textured_model.mesh.faces)
    assert any(getattr(gm.visual, "uv", None) is not None for gm in geoms)


def test_loads_in_pygltflib_and_trimesh(diffuse_model, tmp_path):
    p = tmp_path / "m.glb"
    export_gltf(diffuse_model, p)
    doc = pygltflib.GLTF2().load(str(p))
    assert GLTF_EXTENSION in doc.extensionsUsed
    assert GLTF_EXTENSION not in (doc.extensionsRequired or [])
    names = {a.name for a in doc.accessors if a.name}
    assert all(n.startswith("_") for n in names)
    assert {"_LOBELIGHT_LOBE_LIGHT", "_LOBELIGHT_LOBE_MEAN", "_LOBELIGHT_DIFFUSE"} <= names
    mesh = trimesh.load(str(p), force="mesh", process=False)
    v = diffuse_model.mesh.vertices.numpy()
    assert mesh.vertices.shape == v.shape and np.allclose(mesh.vertices, v)
    assert len(mesh.faces) == len(diffuse_model.mesh.faces)
    base, metal, rough = fallback_material(diffuse_model.materials)
    mat = mesh.visual.material
    assert mat.metallicFactor == pytest.approx(metal) and mat.roughnessFactor == pytest.approx(
        rough
    )
    # COLOR_0 (which trimesh leaves out beside a material) is the fallback base colour
    acc = doc.accessors[doc.meshes[0].primitives[0].attributes.COLOR_0]
    bv = doc.bufferViews[acc.bufferView]
    raw = doc.binary_blob()[bv.byteOffset : bv.byteOffset + bv.byteLength]
    assert np.array_equal(np.frombuffer(raw, "<f4").reshape(-1, 3), base.numpy())


def test_fallback_material_inverts_the_gltf_model():
    """A glTF metallic-roughness material (base colour, metallic, roughness: the specification's
    formulas in lobelight.brdf.metallic_roughness) comes back as itself."""
    base = torch.tensor([[0.9, 0.6, 0.2], [0.7, 0.5, 0.3], [0.2, 0.8, 0.4]])
    for metal, rough in ((0.0, 0.5), (0.3, 0.2), (1.0, 0.7)):
        diffuse, spec = brdf.metallic_roughness(
            base, torch.full((3,), metal), torch.full((3,), rough)
        )
        got_base, got_metal, got_rough = fallback_material(Materials(diffuse, spec))
        assert got_rough == pytest.approx(rough, abs=1e-6)
        # the mean-based solve is exact for a uniform metallic
        assert got_metal == pytest.approx(metal, abs=1e-5)
        assert torch.allclose(got_base, base, atol=1e-5)


def test_a_diffuse_material_falls_back_to_a_rough_dielectric():
    d = torch.tensor([[0.5, 0.4, 0.3]])
    got_base, metal, rough = fallback_material(Materials(d, None))
    assert metal == 0.0 and rough == 1.0 and torch.equal(got_base, d)


def _constant_env(c):
    return EnvMap(np.full((16, 32, 3), c, np.float32), layout="latlong", name="constant")


def _glb_json(p: Path) -> dict:
    data = p.read_bytes()
    n = struct.unpack_from("<I", data, 12)[0]
    return json.loads(data[20 : 20 + n])


def test_image_based_light_of_a_constant_map(diffuse_model, tmp_path):
    """Under a constant radiance c the irradiance is pi c everywhere: its only SH coefficient
    is E_00 = pi c sqrt(4 pi); every specular face decodes (RGBD) to c."""
    c = np.array([0.5, 1.0, 2.0])
    p = tmp_path / "m.glb"
    export_gltf(diffuse_model, p, lighting=_constant_env(c))
    doc = _glb_json(p)
    assert "EXT_lights_image_based" in doc["extensionsUsed"]
    assert "EXT_lights_image_based" not in doc.get("extensionsRequired", [])
    assert doc["scenes"][0]["extensions"]["EXT_lights_image_based"] == {"light": 0}
    light = doc["extensions"]["EXT_lights_image_based"]["lights"][0]
    irr = np.array(light["irradianceCoefficients"])
    assert irr.shape == (9, 3)
    # the map's SH projection on a 64^2 cube map quadrature: 1e-4 relative
    assert np.allclose(irr[0], math.pi * c * math.sqrt(4 * math.pi), rtol=1e-4)
    assert np.allclose(irr[1:], 0, atol=1e-4 * c.max())
    mips = light["specularImages"]
    assert len(mips) >= 2 and all(len(m) == 6 for m in mips)
    size = light["specularImageSize"]
    g = pygltflib.GLTF2().load(str(p))
    blob = g.binary_blob()
    for k, faces in enumerate(mips):
        for i in faces:
            bv = g.bufferViews[g.images[i].bufferView]
            raw = blob[bv.byteOffset : bv.byteOffset + bv.byteLength]
            rgbd = np.asarray(Image.open(io.BytesIO(raw))).astype(np.float64) / 255
            assert rgbd.shape == (size >> k, size >> k, 4)
            dec = rgbd[..., :3] ** 2.2 / rgbd[..., 3:]
            # 8-bit codes of (c D)^(1/2.2): half a code, 2.2 x 0.5/255 relative after decoding
            assert np.allclose(dec, c, rtol=2.2 * 0.5 / 255 / 0.5)


def test_errors_name_the_problem(diffuse_model, tmp_path):
    with pytest.raises(InputError, match="glb"):
        export_gltf(diffuse_model, tmp_path / "m.gltf")
    with pytest.raises(InputError, match="does not exist"):
        export_gltf(diffuse_model, tmp_path / "no" / "m.glb")
    plain = tmp_path / "two.glb"
    two_material_glb(plain)
    with pytest.raises(InputError, match="LOBELIGHT_prt"):
        import_gltf(plain)
    bad = tmp_path / "bad.glb"
    bad.write_bytes(b"not a glb at all")
    with pytest.raises(InputError, match="not a binary glTF"):
        import_gltf(bad)
    with pytest.raises(InputError, match="no such file"):
        import_gltf(tmp_path / "missing.glb")


def test_never_written_over_an_input(diffuse_model, tmp_path):
    p = tmp_path / "m.glb"
    export_gltf(diffuse_model, p)
    before = p.read_bytes()
    with protect_inputs():
        read_input(p, limit=1 << 30)
        with pytest.raises(InputError):
            export_gltf(diffuse_model, p)
    assert p.read_bytes() == before


def test_a_truncated_file_is_one_clear_error(diffuse_model, tmp_path):
    p = tmp_path / "m.glb"
    export_gltf(diffuse_model, p)
    data = p.read_bytes()
    cut = tmp_path / "cut.glb"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError):
        import_gltf(cut)


def _validator() -> Path | None:
    """The gltf-validator npm package: ``$LOBELIGHT_GLTF_VALIDATOR`` (its folder, or a folder
    with ``node_modules/gltf-validator``), else where node resolves it."""
    env = os.environ.get("LOBELIGHT_GLTF_VALIDATOR")
    cands = []
    if env:
        cands += [Path(env), Path(env) / "node_modules" / "gltf-validator"]
    for c in cands:
        if (c / "package.json").is_file() and (c / "index.js").is_file():
            return c
    if shutil.which("node") is None:
        return None
    r = subprocess.run(["node", "-e", "console.log(require.resolve('gltf-validator'))"],
                       capture_output=True, text=True, timeout=60)  # fmt: skip
    return Path(r.stdout.strip()).parent if r.returncode == 0 else None


_VALIDATE_JS = """
const fs = require('fs');
const v = require(process.argv[1]);
v.validateBytes(new Uint8Array(fs.readFileSync(process.argv[2])), {maxIssues: 0})
  .then((r) => console.log(JSON.stringify(r.issues)))
  .catch((e) => { console.error(String(e)); process.exit(2); });
"""

needs_validator = pytest.mark.skipif(
    shutil.which("node") is None or _validator() is None,
    reason="node or the gltf-validator npm package is absent "
    "(npm install gltf-validator; LOBELIGHT_GLTF_VALIDATOR=its folder)",
)


@needs_validator
@pytest.mark.parametrize("which", ["diffuse_model", "sharp_model", "textured_model"])
def test_the_khronos_validator_finds_no_errors(which, request, tmp_path):
    m = request.getfixturevalue(which)
    p = tmp_path / "m.glb"
    lighting = envmap.builtin() if which == "diffuse_model" else None
    export_gltf(m, p, lighting=lighting)
    r = subprocess.run(["node", "-e", _VALIDATE_JS, str(_validator()), str(p)],
                       capture_output=True, text=True, timeout=300)  # fmt: skip
    assert r.returncode == 0, r.stderr
    issues = json.loads(r.stdout)
    errors = [x for x in issues["messages"] if x["severity"] <= 1]
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, errors[:5]


def test_the_export_command_writes_the_models_glb(diffuse_model, tmp_path):
    """``lobelight export MODEL --gltf OUT.glb``: the file reads back as the model; a name
    that is not a ``.glb`` is refused before any work (exit 2), and nothing is written."""
    src = tmp_path / "m.npz"
    diffuse_model.save(src)
    out = tmp_path / "m.glb"
    assert main(["export", str(src), "--gltf", str(out), "-q"]) == 0
    back = import_gltf(out)
    torch.testing.assert_close(back.mesh.vertices, diffuse_model.mesh.vertices.cpu())
    bad = tmp_path / "m.gltf"
    assert main(["export", str(src), "--gltf", str(bad), "-q"]) == 2
    assert not bad.exists()
