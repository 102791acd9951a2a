"""The diffuse albedo read per pixel from a glTF asset's base colour textures
(:class:`lobelight.scene.AlbedoTexture`, the renderers' ``albedo``)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from lobelight import envmap, fit, scene
from lobelight import model as model_module
from lobelight.cli import main
from lobelight.data import DEFAULT_ENVMAP, envmap_path
from lobelight.errors import InputError
from lobelight.geometry.camera import Camera
from lobelight.model import per_unit_albedo
from lobelight.model._albedo_file import albedo_arrays, check_albedo
from lobelight.render import Renderer
from lobelight.render._gl import gl_available
from lobelight.scene import (
    AlbedoTexture,
    Sampler,
    Texture,
    sample_texture,
    srgb_decode,
)
from test_gltf_scene import (
    PAINTED_FACTOR,
    PAINTED_SRGB,
    _png,
    _quad,
    two_material_glb,
    write_glb,
)

needs_gl = pytest.mark.skipif(not gl_available(), reason="no headless OpenGL context (EGL)")

#: The checkerboard: 8 x 8 cells of sRGB codes 230 and 30 on a unit quad of two triangles.
CELLS, LIGHT, DARK = 8, 230, 30
#: The image: 64^2 pixels of a camera looking straight at the quad; a cell spans ~6 pixels.
SIZE = 64
CAMERA = Camera.look_at((0.5, 0.5, 1.6), (0.5, 0.5, 0.0), fov=40.0)


def _checker_glb(path, *, mag_filter: int = 9728) -> None:
    """A unit quad with an 8 x 8 checkerboard base colour (nearest filter by default), a
    rough dielectric (metallic 0, roughness 1)."""
    cells = (np.add.outer(np.arange(CELLS), np.arange(CELLS)) % 2).astype(bool)
    img = np.where(cells[..., None], LIGHT, DARK).repeat(3, 2).astype(np.uint8)
    mats = [
        {"name": "checker", "pbrMetallicRoughness": {
            "baseColorTexture": {"index": 0}, "metallicFactor": 0.0, "roughnessFactor": 1.0}}
    ]  # fmt: skip
    sampler = {"magFilter": mag_filter, "minFilter": mag_filter}
    write_glb(path, [_quad(0.0, material=0)], mats, [_png(img)], [sampler])


@pytest.fixture(scope="module")
def checker_model(tmp_path_factory):
    p = tmp_path_factory.mktemp("checker") / "checker.glb"
    _checker_glb(p)
    sc = scene.load(str(p))
    return fit.fit_model(sc, 1, indirect_paths=0, bounces=0, progress=None)


def _pixel_uv() -> np.ndarray:
    """(SIZE, SIZE, 2) the UV each pixel centre's ray meets the quad's plane z = 0 at
    (the quad's UV is (x, 1 - y)), NaN off the quad."""
    o, d = CAMERA.rays(SIZE, SIZE)
    o, d = o.double().numpy(), d.double().numpy()
    t = -o[..., 2] / d[..., 2]
    p = o + t[..., None] * d
    uv = np.stack([p[..., 0], 1 - p[..., 1]], -1)
    inside = (uv >= 0).all(-1) & (uv <= 1).all(-1)
    return np.where(inside[..., None], uv, np.nan)


@pytest.mark.parametrize(
    "backend", ["torch", pytest.param("gl", marks=needs_gl)]
)  # fmt: skip
def test_checkerboard_renders_as_a_checkerboard_at_pixel_scale(checker_model, backend):
    """A checkerboard finer than the mesh (two triangles, 64 cells) renders as one: every
    object pixel is the cell's albedo at its centre's UV times one diffuse light (the flat,
    unoccluded quad receives the same light at every vertex), so adjacent pixels across a cell
    edge keep the full contrast. Per-vertex albedos would give every pixel the mean."""
    r = Renderer(checker_model, envmap.builtin(), SIZE, SIZE, backend=backend, samples=1)
    img = r.render(CAMERA, diffuse=True, glossy=False).cpu().numpy().astype(np.float64)
    uv = _pixel_uv()
    # one pixel's margin from the quad's border (a pixel there is part background)
    inner = np.isfinite(uv).all(-1)
    inner[1:-1, 1:-1] &= inner[:-2, 1:-1] & inner[2:, 1:-1] & inner[1:-1, :-2] & inner[1:-1, 2:]
    inner[[0, -1], :] = inner[:, [0, -1]] = False
    ix = np.floor(np.nan_to_num(uv) * CELLS).astype(int).clip(0, CELLS - 1)
    light = (ix[..., 0] + ix[..., 1]) % 2 == 1
    code = np.where(light, LIGHT, DARK)
    albedo = srgb_decode(torch.tensor(code / 255.0)).numpy()
    ratio = img[..., 1][inner] / albedo[inner]
    # the diffuse light is one value up to the SH transfer's variation between the vertices
    # (the same normal, the same unoccluded sky) and float32 rounding: 1 %
    assert ratio.std() / ratio.mean() < 0.01
    # edge contrast: neighbours across a cell edge differ by the albedos' full ratio (~60)
    row = img[SIZE // 2, :, 1]
    cross = (
        inner[SIZE // 2, 1:]
        & inner[SIZE // 2, :-1]
        & (light[SIZE // 2, 1:] != light[SIZE // 2, :-1])
    )
    pairs = np.stack([row[1:][cross], row[:-1][cross]], -1)
    assert len(pairs) >= 6
    want = srgb_decode(torch.tensor(LIGHT / 255)) / srgb_decode(torch.tensor(DARK / 255))
    contrast = pairs.max(-1) / pairs.min(-1)
    assert np.all(contrast > 0.95 * float(want))


@needs_gl
def test_gl_reads_albedo_textures_as_the_torch_path(tmp_path):
    """A bilinear, repeating texture under a UV transform, magnified: the shader path's texture
    array and ``albedo.glsl``'s wrap and transform against the torch path's sampler."""
    p = tmp_path / "checker.glb"
    _checker_glb(p, mag_filter=9729)
    sc = scene.load(str(p))
    a = sc.albedo
    a.transform = torch.tensor([[[1.5, 0.0, 0.25], [0.0, 1.5, -0.1]]] * 2)
    a.wrap = torch.tensor([[0, 0], [2, 1]])
    m = fit.fit_model(sc, 1, indirect_paths=0, bounces=0, progress=None)
    imgs = [
        Renderer(m, envmap.builtin(), SIZE, SIZE, backend=b, samples=1)
        .render(CAMERA, diffuse=True, glossy=False)
        .cpu()
        .numpy()
        for b in ("torch", "gl")
    ]
    inner = np.isfinite(_pixel_uv()).all(-1)
    d = np.abs(imgs[0] - imgs[1])[inner]
    # half-float texels (3 decimal digits) and the rasteriser's UVs against the rays' (the
    # bilinear weights move with them): 1 % of the brightest cell's value
    assert d.max() < 0.01 * imgs[0][inner].max()


def _texture(wrap_s: str, wrap_t: str, nearest: bool) -> Texture:
    gen = torch.Generator().manual_seed(3)
    codes = torch.randint(0, 256, (5, 7, 3), generator=gen, dtype=torch.uint8)
    lin = srgb_decode(codes.double() / 255).float()
    filt = "nearest" if nearest else "linear"
    return Texture(
        lin, Sampler(wrap_s, wrap_t, filt, filt), "test", 0, ((1.2, 0.3, 0.1), (-0.2, 0.9, 0.4))
    ), codes


@pytest.mark.parametrize("nearest", [False, True])
@pytest.mark.parametrize(("wrap_s", "wrap_t"), [("repeat", "mirror"), ("clamp", "repeat")])
def test_albedo_layers_read_as_the_loaders_sampler(wrap_s, wrap_t, nearest):
    """The renderers' layer sampler (8-bit sRGB codes, decoded per texel) against the glTF
    loader's :func:`~lobelight.scene.sample_texture` on the decoded image, at UVs well beyond
    [0, 1] (every wrap mode, the transform, both filters): equal up to float32 rounding."""
    tex, codes = _texture(wrap_s, wrap_t, nearest)
    modes = ("repeat", "clamp", "mirror")
    a = AlbedoTexture(
        uvs=torch.zeros(1, 2),
        layer=torch.ones(1, dtype=torch.int64),
        factor=torch.ones(1, 3),
        images=(torch.full((1, 1, 3), 255, dtype=torch.uint8), codes),
        wrap=torch.tensor([[0, 0], [modes.index(wrap_s), modes.index(wrap_t)]]),
        transform=torch.tensor([[[1.0, 0, 0], [0, 1.0, 0]], list(tex.uv_transform)]),
        nearest=torch.tensor([False, nearest]),
    )
    uv = torch.rand(4000, 2, generator=torch.Generator().manual_seed(5)) * 6 - 3
    got = a.sample(1, uv)
    want = sample_texture(tex, uv)
    assert torch.allclose(got, want, atol=2e-6)


def test_transfer_per_unit_albedo_is_exact():
    """Dividing the receiver's albedo out and multiplying it back gives the transfer (where the
    albedo is not zero; a zero albedo's transfer is zero)."""
    gen = torch.Generator().manual_seed(1)
    t = torch.rand(50, 25, 3, generator=gen)
    a = torch.rand(50, 3, generator=gen) * 0.9 + 0.05
    a[3] = 0.0
    t[3] = 0.0
    unit = per_unit_albedo(t * a[:, None, :], a)
    assert torch.allclose(unit * a[:, None, :], t * a[:, None, :], rtol=1e-6, atol=0)
    assert torch.equal(unit[3], torch.zeros(25, 3))


def test_untextured_vertices_keep_their_own_albedo(tmp_path):
    """In a model with a textured and an untextured material, the untextured one renders with
    its per-vertex albedo: its factor is the bake's albedo, its layer the white texel."""
    p = tmp_path / "two.glb"
    two_material_glb(p)
    sc = scene.load(str(p))
    a = sc.albedo
    plain = a.layer == 0
    assert bool(plain.any()) and bool((~plain).any())
    torch.testing.assert_close(a.factor[plain], sc.materials.diffuse[plain])
    c = torch.arange(sc.mesh.n_vertices)[plain][:, None].expand(-1, 3)
    b = torch.tensor([[1.0, 0.0, 0.0]]).expand(len(c), 3)
    torch.testing.assert_close(a.at(c, b), sc.materials.diffuse[plain])


def test_albedo_textures_survive_the_model_file(checker_model, tmp_path):
    """A model with albedo textures writes and reads them back exactly (the images as their
    8-bit codes), and the reader refuses a file whose layer sizes and texels disagree."""
    p = tmp_path / "m.npz"
    checker_model.save(p)
    back = model_module.load(p)
    a, b = checker_model.albedo, back.albedo
    assert b is not None
    for k in ("uvs", "layer", "factor", "wrap", "transform", "nearest"):
        assert torch.equal(getattr(a, k).cpu(), getattr(b, k).cpu()), k
    assert all(torch.equal(x, y) for x, y in zip(a.images, b.images, strict=True))
    torch.testing.assert_close(back.diffuse, checker_model.diffuse.cpu())
    arrays = albedo_arrays(a)
    arrays["albedo_sizes"] = arrays["albedo_sizes"] * 2
    with pytest.raises(InputError, match="albedo_texels"):
        check_albedo(arrays, a.n_vertices, "m.npz")
    arrays = albedo_arrays(a)
    del arrays["albedo_wrap"]
    with pytest.raises(InputError, match="come together"):
        check_albedo(arrays, a.n_vertices, "m.npz")


def test_a_material_override_drops_the_files_textures(tmp_path):
    """``--material`` replaces every material of a glTF file, its textures too: the scene then
    has no asset materials to export and no albedo to read per pixel."""
    p = tmp_path / "two.glb"
    two_material_glb(p)
    sc = scene.load(str(p), material="diffuse:color=0.5")
    assert sc.gltf is None and sc.albedo is None
    assert scene.load(str(p)).albedo is not None


def test_the_sun_lights_the_textures_albedo(checker_model):
    """With the map's sun shaded per pixel (the bundled park's), the sun's diffuse light reads
    the same per-pixel albedo as the rest: the checkerboard keeps its contrast in both
    renderers, and they agree."""
    env = envmap.load(envmap_path(DEFAULT_ENVMAP))
    imgs = []
    for backend in ("torch", "gl") if gl_available() else ("torch",):
        r = Renderer(checker_model, env, SIZE, SIZE, backend=backend, samples=1, sun=True)
        assert r.lighting.sun is not None
        imgs.append(r.render(CAMERA, diffuse=True, glossy=False).cpu().numpy())
    inner = np.isfinite(_pixel_uv()).all(-1)
    row = imgs[0][SIZE // 2, :, 1][inner[SIZE // 2]]
    want = srgb_decode(torch.tensor(LIGHT / 255)) / srgb_decode(torch.tensor(DARK / 255))
    # the quad's inner row crosses light and dark cells: their ratio is the albedos'
    assert row.max() / row.min() > 0.95 * float(want)
    if len(imgs) == 2:
        d = np.abs(imgs[0] - imgs[1])[inner]
        # the sun's shadow (none on a lone quad) and its SH differ only by rounding: 1 %
        assert d.max() < 0.01 * imgs[0][inner].max()


def test_a_metallic_texture_shows_in_the_diffuse_albedo_per_pixel(tmp_path):
    """A quad whose metallic-roughness texture is metal on its right half only (nearest
    texels) has glTF's diffuse albedo ``baseColorFactor x base x (1 - metallicFactor x B)`` at
    each pixel: its base colour on the left, none of it where the metal is; a per-vertex
    average of the metallic part would give both halves the same."""
    p = tmp_path / "logo.glb"
    _logo_glb(p)  # the diffuse albedo does not depend on its roughness
    a = scene.load(str(p)).albedo
    got = a.at(LOGO_CORNERS, LOGO_BARY).double()
    want_left = _painted()
    # the left texel is the base colour's own 8-bit codes, decoded: float32 rounding
    torch.testing.assert_close(got[0], want_left, rtol=1e-5, atol=0)
    assert torch.equal(got[1], torch.zeros(3, dtype=torch.float64))


def test_info_says_the_albedo_is_read_per_pixel(checker_model, tmp_path, capsys):
    """``lobelight info`` names where the diffuse albedo comes from: the checker model's one
    8 x 8 texture."""
    p = tmp_path / "checker.npz"
    checker_model.save(p)
    capsys.readouterr()
    assert main(["info", str(p), "--json"]) == 0
    got = json.loads(capsys.readouterr().out)["albedo"]
    assert got == "per pixel from 1 texture (8x8), the rest per vertex"


def _logo_glb(path, *, mag: int = 9728) -> None:
    """A unit quad whose metallic-roughness texture is metal on its right half only, a painted
    base colour, roughness 0.5 (glTF's own BRDF, Schlick's Fresnel)."""
    mr = np.zeros((2, 2, 3), np.uint8)
    mr[:, 1, 2] = 255  # B = 1 (metal) in the right column
    mr[..., 1] = 128  # G: roughness 0.5 x roughnessFactor
    mats = [
        {"name": "logo", "pbrMetallicRoughness": {
            "baseColorFactor": [*PAINTED_FACTOR, 1.0], "baseColorTexture": {"index": 0},
            "metallicFactor": 1.0, "roughnessFactor": 1.0,
            "metallicRoughnessTexture": {"index": 1}}},
    ]  # fmt: skip
    base = np.broadcast_to(np.uint8(PAINTED_SRGB), (2, 2, 3))
    s = {"magFilter": mag, "minFilter": mag}
    write_glb(path, [_quad(0.0, material=0)], mats, [_png(base), _png(mr)], [s, s])


#: Two points of the logo quad's first triangle, as (corners, barycentrics): the quad's
#: corners 0, 1, 2 have UVs (0, 1), (1, 1), (1, 0), so near corner 0 is the left (dielectric)
#: column and near corner 2 the right (metal) one.
LOGO_CORNERS = torch.tensor([[0, 1, 2], [0, 1, 2]])
LOGO_BARY = torch.tensor([[0.8, 0.1, 0.1], [0.1, 0.1, 0.8]])


def _painted() -> torch.Tensor:
    """The logo's painted base colour, linear: its factor times its decoded 8-bit texel."""
    lin = srgb_decode(torch.tensor(PAINTED_SRGB, dtype=torch.float64) / 255)
    return torch.tensor(PAINTED_FACTOR, dtype=torch.float64) * lin


def test_a_metallic_texture_gives_each_texel_its_f0(tmp_path):
    """glTF's specular colour at normal incidence per texel: ``F0 = 0.04 (1 - m) + base m``
    with ``m = metallicFactor x B`` and ``base`` the base colour factor times its texture:
    0.04 grey on the dielectric half, the painted colour on the metal one."""
    p = tmp_path / "logo.glb"
    _logo_glb(p)
    a = scene.load(str(p)).albedo
    got = a.specular_at(LOGO_CORNERS, LOGO_BARY).double()
    metal = _painted()
    # stored as 8-bit sRGB: half a code's step, relative, is about 2.4 x 0.5 / code (the
    # decode's slope): 2.1 % at 0.04 (code 57), under 1 % for the paint
    want0 = torch.full((3,), 0.04, dtype=torch.float64)
    torch.testing.assert_close(got[0], want0, rtol=0.022, atol=0)
    torch.testing.assert_close(got[1], metal, rtol=0.01, atol=0)


@pytest.mark.parametrize(
    "backend", ["torch", pytest.param("gl", marks=needs_gl)]
)  # fmt: skip
def test_the_glossy_light_follows_the_texels_f0(tmp_path, backend):
    """The glossy light of a quad half metal, half dielectric: per pixel, the interpolated
    vertices' glossy light times the texel's F0 over theirs. At a pixel beside the quad's
    vertical midline on either side the vertices' blend is nearly the same, so the glossy
    light across the line jumps by the two texels' F0 ratio (the paint over 0.04, about 4-12
    per channel); per-vertex F0 would show no jump."""
    p = tmp_path / "logo.glb"
    _logo_glb(p)
    sc = scene.load(str(p))
    m = fit.fit_model(sc, 1, indirect_paths=0, bounces=0, progress=None)
    img = Renderer(m, envmap.builtin(), SIZE, SIZE, backend=backend, samples=1).render(
        CAMERA, diffuse=False, glossy=True
    )
    img = img.cpu().numpy().astype(np.float64)
    uv = _pixel_uv()
    row = SIZE // 2
    u = uv[row, :, 0]
    left = int(np.nanargmax(np.where(u < 0.5, u, np.nan)))
    right = left + 1
    assert u[right] > 0.5
    f0 = sc.albedo.specular_at(LOGO_CORNERS, LOGO_BARY).double().numpy()  # left, right
    want = f0[1] / f0[0]
    got = img[row, right] / img[row, left]
    # the two pixels' vertex blends differ by one pixel's step of 64 across the quad (under
    # 3 % in the glossy light of a flat quad under the sky) and half-float texels: 5 %
    np.testing.assert_allclose(got, want, rtol=0.05)


def test_f0_textures_survive_the_model_file(tmp_path):
    """The F0 images travel in the model file (``albedo_specular``) and come back equal; a
    file whose F0 texels do not match its albedo texels is refused naming the array."""
    p = tmp_path / "logo.glb"
    _logo_glb(p)
    m = fit.fit_model(scene.load(str(p)), 1, indirect_paths=0, bounces=0, progress=None)
    out = tmp_path / "logo.npz"
    m.save(out)
    back = model_module.load(out).albedo
    assert back.specular is not None
    for x, y in zip(back.specular, m.albedo.specular, strict=True):
        assert torch.equal(x, y)
    arrays = albedo_arrays(m.albedo)
    arrays["albedo_specular"] = arrays["albedo_specular"][:-1]
    with pytest.raises(InputError, match="albedo_specular"):
        check_albedo(arrays, m.mesh.n_vertices, "logo.npz")
