"""The Mitsuba export of glTF scenes with their textures (lobelight.reference.mitsuba) against
our own evaluation and a closed form.

- At points on a textured quad found by Mitsuba's own ray intersection, the exported BSDF's
  value (eval·cos) equals lobelight's glTF material (:func:`lobelight.brdf.metallic_roughness`
  summed with its Lambert part) with the factors read by :func:`lobelight.scene.sample_texture`
  at the same UV: anywhere when only one of the two textures is given (the composed image is
  then linear in it), and where both are, at points whose bilinear footprint is one constant
  block of texels (the composition is exact there; elsewhere it is not: module docstring of
  :mod:`lobelight.reference.mitsuba`). Wrap modes, UVs beyond [0, 1], nearest filtering and a
  ``KHR_texture_transform`` are covered; Mitsuba's interpolated UV equals ours (no flip).
- A four-colour textured quad rendered by Mitsuba under a uniform environment: each quadrant's
  mean radiance is ``rho L`` plus the lobe's directional albedo (by quadrature of the glTF
  formula), and quadrant differences are ``(rho_a - rho_b) L`` exactly.
- What Mitsuba cannot express is refused, naming the material.
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
import torch

from lobelight import brdf as B
from lobelight.errors import InputError
from lobelight.geometry.camera import Camera
from lobelight.scene import (
    GltfAsset,
    GltfMaterial,
    Sampler,
    Scene,
    Texture,
    mesh_from_arrays,
    sample_texture,
)
from lobelight.scene._materials import gltf_materials
from test_brdf import hemisphere_integral, mitsuba_pairs
from test_brdf_gltf import gltf_formula

mi = pytest.importorskip("mitsuba", reason="Mitsuba 3 is the independent reference")

#: Texels per side of the test textures, and per side of one constant block in them.
_TEXELS, _BLOCK = 8, 2
#: The quad's default UV map: ``uv = xy @ A.T + b`` takes [-1, 1]^2 to [0, 1]^2, V down.
_A = np.array([[0.5, 0.0], [0.0, -0.5]])
_B = np.array([0.5, 0.5])
#: Where the uniform maps are written (one folder for the session, removed at its end).
_ENV_TMP = tempfile.TemporaryDirectory(prefix="lobelight-test-env-")
_ENV_DIR = Path(_ENV_TMP.name)


def _mitsuba(variant: str = "scalar_rgb"):
    from lobelight.reference.mitsuba import load_mitsuba

    try:
        return load_mitsuba(variant)
    except (ImportError, AttributeError, ValueError, InputError) as exc:
        pytest.skip(reason=f"Mitsuba's {variant} variant cannot be set here: {exc}")


def _blocks(seed: int, channels: int, lo: float = 0.0) -> torch.Tensor:
    """(8, 8, C) float32 image of 2 x 2-texel blocks of random values in [lo, 1]."""
    g = np.random.default_rng(seed)
    n = _TEXELS // _BLOCK
    vals = lo + (1 - lo) * g.random((n, n, channels))
    return torch.tensor(np.kron(vals, np.ones((_BLOCK, _BLOCK, 1))), dtype=torch.float32)


def _quad(material: GltfMaterial, a=_A, b=_B, env="builtin", camera=None) -> Scene:
    """The square [-1, 1]^2 at z = 0 facing +z, two triangles, UV ``xy @ a.T + b``, with the
    glTF ``material`` (the scene's per-vertex materials are its factors: the export does not
    read them)."""
    xy = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
    v = np.concatenate([xy, np.zeros((4, 1))], 1)
    mesh = mesh_from_arrays(
        v, np.array([[0, 1, 2], [0, 2, 3]]), normals=np.tile([0.0, 0.0, 1.0], (4, 1)), weld=False
    )
    uv = torch.tensor(mesh.vertices[:, :2].double().numpy() @ a.T + b, dtype=torch.float32)
    asset = GltfAsset(
        mesh,
        uv,
        torch.ones(4, 4),
        torch.zeros(4, dtype=torch.int64),
        (material, GltfMaterial("default")),
    )
    mats = gltf_materials(torch.full((4, 3), 0.5), torch.zeros(4), torch.full((4,), 0.5))
    cam = camera or Camera.look_at((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), fov=40.0)
    return Scene(mesh, mats, env, cam, "quad", gltf=asset)


def _factors(mat: GltfMaterial, uv: torch.Tensor):
    """Base colour (P, 3), metallic and roughness (P,) of ``mat`` at ``uv`` (P, 2), read with
    :func:`lobelight.scene.sample_texture` (float64)."""
    uv = uv.double()
    base = torch.tensor(mat.base_color[:3], dtype=torch.float64).expand(len(uv), 3)
    metal = torch.full((len(uv),), mat.metallic, dtype=torch.float64)
    rough = torch.full((len(uv),), mat.roughness, dtype=torch.float64)
    if mat.base_color_texture is not None:
        base = base * sample_texture(mat.base_color_texture, uv).double()[:, :3]
    if mat.metallic_roughness_texture is not None:
        mr = sample_texture(mat.metallic_roughness_texture, uv).double()
        metal, rough = metal * mr[:, 2], rough * mr[:, 1]
    return base, metal, rough


def _compare(mat: GltfMaterial, tex_uv: np.ndarray, a=_A, b=_B, pairs: int = 6) -> int:
    """Mitsuba's exported BSDF against ours at the quad's points whose UV is ``tex_uv``
    (P, 2); returns how many values were compared. The points are hit by Mitsuba's rays."""
    import drjit as dr

    from lobelight.reference.mitsuba import scene_dict

    m = _mitsuba()
    sc = _quad(mat, a, b)
    with tempfile.TemporaryDirectory() as work:
        d = scene_dict(sc, _constant_env(m), width=4, height=4, spp=1, workdir=work)
        scene = m.load_dict(d)
    xy = (tex_uv - b) @ np.linalg.inv(a).T  # (P, 2) points on the quad
    assert np.all(np.abs(xy) < 0.999), "a UV outside the quad"
    base, metal, rough = _factors(mat, torch.tensor(tex_uv))
    ctx = m.BSDFContext()
    ours, theirs = [], []
    for p in range(len(xy)):
        ray = m.Ray3f(m.Point3f(float(xy[p, 0]), float(xy[p, 1]), 2.0), m.Vector3f(0, 0, -1))
        si = scene.ray_intersect(ray)
        assert bool(si.is_valid())
        # Mitsuba's interpolated UV is ours: texture coordinates written unflipped
        np.testing.assert_allclose(list(si.uv), tex_uv[p], rtol=0, atol=2e-6)
        wi_l, wo_l = mitsuba_pairs(pairs, float(rough[p]) ** 2 + 0.05, seed=100 + p)
        diffuse, spec = B.metallic_roughness(base[p].clamp(0, 1), metal[p], rough[p])
        model = B.Sum(B.Lambert(diffuse), spec)
        n, t = torch.tensor([0.0, 0.0, 1.0]), torch.tensor([1.0, 0.0, 0.0])
        ours.append(model.eval(wi_l, wo_l, n, t) * wi_l[:, 2:3])  # (pairs, 3)
        bsdf = si.bsdf()
        for k in range(pairs):
            si.wi = m.Vector3f(*wo_l[k].tolist())  # Mitsuba's si.wi is our wo
            theirs.append(list(bsdf.eval(ctx, si, m.Vector3f(*wi_l[k].tolist()))))
        dr.eval()
    ours_t = torch.cat(ours).double()
    theirs_t = torch.tensor(theirs, dtype=torch.float64)
    # float32 on both sides with the same formulas (tests/test_brdf_gltf.py's 1e-5); the
    # composed textures are float32 images of float64 products: rounding ~6e-8 relative
    torch.testing.assert_close(ours_t, theirs_t, rtol=1e-5, atol=1e-7 * float(theirs_t.max()))
    return int(theirs_t.numel())


def _constant_env(m, value: float = 1.0) -> str:
    """A uniform lat-long map of radiance ``value`` (Mitsuba's own writer), written once."""
    path = _ENV_DIR / f"uniform_{value:g}.exr"
    if not path.is_file():
        m.Bitmap(np.full((8, 16, 3), value, dtype=np.float32)).write(str(path))
    return str(path)


def _block_centres(rng, count: int) -> np.ndarray:
    """UVs of ``count`` random block centres (texel corners inside a constant 2 x 2 block)."""
    n = _TEXELS // _BLOCK
    ij = rng.integers(0, n, size=(count, 2))
    return (ij * _BLOCK + _BLOCK / 2) / _TEXELS


def _material(base=None, mr=None, **kw) -> GltfMaterial:
    return GltfMaterial(
        "test",
        base_color=kw.pop("base_color", (0.9, 0.8, 0.7, 1.0)),
        metallic=kw.pop("metallic", 0.8),
        roughness=kw.pop("roughness", 0.9),
        base_color_texture=base,
        metallic_roughness_texture=mr,
        **kw,
    )


def test_both_textures_compose_exactly_on_constant_blocks():
    """Base colour and metallic-roughness textures (products of the two composed texel by
    texel), read at block centres: the value is ours to 1e-5."""
    s = Sampler("repeat", "repeat")
    mat = _material(
        Texture(_blocks(1, 4), s, "base"), Texture(_blocks(2, 3, lo=0.1), s, "metal-rough")
    )
    assert _compare(mat, _block_centres(np.random.default_rng(3), 16)) == 16 * 6 * 3


@pytest.mark.parametrize("which", ["base", "metal_rough"])
def test_one_texture_is_exact_anywhere(which):
    """One texture only: the composed slots are linear in it, so bilinear filtering gives our
    value at any point, here random UVs with a constant factor on the other slot."""
    tex = Texture(_blocks(4, 4 if which == "base" else 3, lo=0.05), Sampler(), which)
    mat = _material(tex, None) if which == "base" else _material(None, tex)
    uv = np.random.default_rng(5).uniform(0.02, 0.98, size=(16, 2))
    _compare(mat, uv)


def test_a_texture_of_one_value_is_a_factor_whatever_its_sampler():
    """A uniform metallic-roughness texture with another sampler than the base colour's (which
    could not be composed with it) reads as its value: ours anywhere."""
    mr = Texture(torch.tensor([0.0, 0.6, 0.3]).expand(4, 4, 3), Sampler("mirror", "clamp"), "mr")
    mat = _material(Texture(_blocks(15, 4), Sampler(), "base"), mr)
    _compare(mat, np.random.default_rng(16).uniform(0.02, 0.98, size=(12, 2)))


def test_clamp_nearest_and_uvs_beyond_the_texture():
    """Nearest filtering with clamped wrapping, the quad's UVs spanning [-0.25, 1.25]: points
    beyond the texture read its edge texels, as sample_texture does."""
    s = Sampler("clamp", "clamp", "nearest", "nearest")
    mat = _material(Texture(_blocks(6, 4), s, "base"), Texture(_blocks(7, 3, lo=0.1), s, "mr"))
    a = np.array([[0.75, 0.0], [0.0, -0.75]])
    uv = np.random.default_rng(8).uniform(-0.24, 1.24, size=(16, 2))
    # nearest: exact wherever the point is not on a texel edge (random points are not)
    _compare(mat, uv, a=a)


@pytest.mark.parametrize("filt", ["linear", "nearest"])
def test_u_and_v_wrapped_differently(filt):
    """Clamped along U and mirrored along V (Mitsuba's bitmap has one wrap mode: the export
    lays the image out over the texels the quad's UVs, in [-0.25, 1.25], reach), with a
    texture transform: ours anywhere, one texture given."""
    transform = ((1.2, 0.0, 0.1), (0.0, 0.9, -0.05))
    s = Sampler("clamp", "mirror", filt, filt)
    mat = _material(Texture(_blocks(17, 4), s, "base", 0, transform), None)
    a = np.array([[0.75, 0.0], [0.0, -0.75]])
    _compare(mat, np.random.default_rng(18).uniform(-0.24, 1.24, size=(16, 2)), a=a)


def test_texture_transform_and_mirrored_wrapping():
    """KHR_texture_transform (offset, rotation, scale) as the bitmap's to_uv, mirrored
    wrapping: block centres in texture space, mapped back to the quad's UVs (beyond [0, 1])."""
    rot, scale, off = 0.3, np.array([1.5, 0.8]), np.array([0.1, -0.2])
    c, s_ = math.cos(rot), math.sin(rot)
    m2 = np.array([[c, s_], [-s_, c]]) * scale[None, :]
    transform = tuple(tuple(float(x) for x in r) for r in np.concatenate([m2, off[:, None]], 1))
    s = Sampler("mirror", "mirror")
    mat = _material(
        Texture(_blocks(9, 4), s, "base", 0, transform),
        Texture(_blocks(10, 3, lo=0.1), s, "mr", 0, transform),
    )
    a = np.array([[1.2, 0.0], [0.0, -1.2]])
    b = np.array([0.4, 0.6])
    rng = np.random.default_rng(11)
    # texture-space block centres, many in the mirrored copies, then back through the transform
    tex = _block_centres(rng, 64) + rng.integers(-2, 3, size=(64, 2))
    uv = (tex - off) @ np.linalg.inv(m2).T
    xy = (uv - b) @ np.linalg.inv(a).T
    keep = np.all(np.abs(xy) < 0.95, axis=1)
    assert keep.sum() >= 10
    _compare(mat, uv[keep][:16], a=a, b=b)


def test_untextured_and_double_sided():
    """A material without textures exports its constant factors; a double-sided one is
    wrapped in twosided and reflects from its back as from its front."""
    from lobelight.reference.mitsuba import gltf_bsdf

    mat = _material(None, None, metallic=0.3, roughness=0.5)
    _compare(mat, np.random.default_rng(12).uniform(0.1, 0.9, size=(4, 2)))
    _mitsuba()
    d = gltf_bsdf(_material(None, None, double_sided=True))
    assert d["type"] == "twosided"


@pytest.mark.parametrize(
    ("samplers", "colors", "what"),
    [
        ((Sampler("repeat", "repeat"), Sampler("clamp", "clamp")), None, "differ"),
        ((Sampler("repeat", "clamp"), None), None, "one wrap mode"),
        ((Sampler(), None), torch.tensor([[1.0, 1, 1, 1], [0.5, 1, 1, 1]]), "COLOR_0"),
    ],
)
def test_what_mitsuba_cannot_express_is_refused(samplers, colors, what):
    from lobelight.reference.mitsuba import gltf_bsdf

    _mitsuba()
    base = Texture(_blocks(13, 4), samplers[0], "base")
    mr = None if samplers[1] is None else Texture(_blocks(14, 3), samplers[1], "mr")
    with pytest.raises(InputError, match=what) as info:
        gltf_bsdf(_material(base, mr), colors)
    assert "'test'" in str(info.value)


def test_wraps_laid_out_over_too_many_texels_are_refused():
    from lobelight.reference.mitsuba import gltf_bsdf

    _mitsuba()
    base = Texture(_blocks(19, 4), Sampler("repeat", "clamp"), "base")
    uvs = torch.tensor([[-10.0, 0.0], [10.0, 1.0]])  # 20 repeats along U: 20 times the texels
    with pytest.raises(InputError, match="too many to lay out"):
        gltf_bsdf(_material(base, None), None, uvs)


def _llvm():
    import drjit as dr

    if "llvm_ad_rgb" not in mi.variants() or not dr.has_backend(dr.JitBackend.LLVM):
        pytest.skip(reason="Mitsuba's llvm_ad_rgb variant needs the LLVM library (libLLVM)")
    return _mitsuba("llvm_ad_rgb")


def test_rendered_textured_quad_under_a_uniform_sky():
    """Four colours in the texture's quadrants, seen from straight above under a uniform
    environment of radiance 1: each image quadrant's mean is ``rho + A_spec`` (the lobe's
    directional albedo at normal incidence by quadrature of the glTF formula: the same in
    every quadrant, metallic 0), and their differences are ``rho_a - rho_b`` exactly."""
    from lobelight.reference.mitsuba import scene_dict

    m = _llvm()
    try:
        rho = np.array([[[0.8, 0.2, 0.1], [0.1, 0.7, 0.2]], [[0.2, 0.3, 0.9], [0.6, 0.6, 0.6]]])
        img = torch.tensor(np.kron(rho, np.ones((4, 4, 1))), dtype=torch.float32)  # (8, 8, 3)
        img = torch.cat([img, torch.ones(8, 8, 1)], -1)
        mat = _material(
            Texture(img, Sampler("clamp", "clamp"), "four"),
            None,
            base_color=(1.0, 1.0, 1.0, 1.0),
            metallic=0.0,
            roughness=0.6,
        )
        # the view spans x, y in [-0.8, 0.8] at 20 units: directions within 2.3 degrees of
        # the normal
        cam = Camera.look_at((0.0, 0.0, 20.0), (0.0, 0.0, 0.0), fov=2 * math.degrees(0.04))
        sc = _quad(mat, env=_constant_env(m), camera=cam)
        w = 32
        with tempfile.TemporaryDirectory() as work:
            d = scene_dict(
                sc, sc.environment, width=w, height=w, spp=256, max_depth=2, seed=3, workdir=work
            )
            s = m.load_dict(d)
        out = np.asarray(m.render(s), dtype=np.float64)  # (w, w, 3)
    finally:
        _mitsuba()
    # the lobe's directional albedo at normal incidence: the glTF formula (written in
    # tests/test_brdf_gltf.py independently of the module) integrated over the hemisphere
    wo = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64)

    def spec_cos(dirs):
        flat = dirs.reshape(-1, 3).numpy()
        _, spec = gltf_formula(flat, np.repeat(wo.numpy(), len(flat), 0), [1.0] * 3, 0.0, 0.6)
        return torch.tensor(spec[:, 0] * flat[:, 2]).reshape(dirs.shape[:-1])

    a_spec = float(hemisphere_integral(spec_cos, 96, 64, 4))
    # away from the bilinear ramp across the middle (texture u in [7/16, 9/16]: pixels 14-17)
    halves = (slice(0, 12), slice(20, 32))
    means, errs = np.zeros((2, 2, 3)), np.zeros((2, 2, 3))
    for r, rows in enumerate(halves):
        for c, cols in enumerate(halves):
            px = out[rows, cols].reshape(-1, 3)
            means[r, c] = px.mean(0)
            errs[r, c] = px.std(0, ddof=1) / math.sqrt(len(px))
    # 4.5 standard errors of each quadrant's mean (pixels are independent estimates); the
    # quadrature of A_spec is good to ~1e-4 and the view's 2.3 degrees move it by less
    tol = 4.5 * errs + 3e-4
    np.testing.assert_array_less(np.abs(means - (rho + a_spec)), tol)
    for (r0, c0), (r1, c1) in [((0, 0), (0, 1)), ((0, 0), (1, 0)), ((1, 1), (0, 1))]:
        diff = means[r0, c0] - means[r1, c1]
        want = rho[r0, c0] - rho[r1, c1]
        bound = 4.5 * np.sqrt(errs[r0, c0] ** 2 + errs[r1, c1] ** 2)
        np.testing.assert_array_less(np.abs(diff - want), bound)
