"""The glTF 2.0 metallic-roughness material (lobelight.brdf.gltf) against independent references.

References: closed forms (the lobe at normal incidence, the glTF formula written out below
with the other common forms of GGX's D and Smith's G1), :class:`lobelight.brdf.GGX` (the same
lobe with F = 1), Mitsuba 3's ``principled`` (value, density and samples) and Mitsuba's
``diffuse`` plus ``principled`` summed by the reference export, quadrature of the directional
albedo, and the path tracer under a white sky. The sampling tests every model gets (χ²,
reciprocity, energy, weight = f cos / pdf) run on it in tests/test_brdf.py.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from lobelight import brdf as B
from lobelight import envmap, render, scene
from lobelight.errors import InputError
from lobelight.geometry import sphere
from lobelight.reference import paths as reference
from lobelight.scene._materials import gltf_materials
from test_brdf import (
    _BT,
    _N,
    _T,
    F32,
    F64,
    frame_args,
    hemisphere_integral,
    local_dir,
    mc_albedo,
    mitsuba_pairs,
    to_world,
    upper_dirs,
)
from test_sun import assert_sun_highlight_matches_torch, dark_model, needs_gl

_BASE = [0.8, 0.5, 0.2]


def gltf_formula(wi, wo, base_color, metallic, roughness):
    """The issue's formula in local coordinates (float64 numpy), written independently of the
    module: GGX ``D = a^2 / (pi (c^2 (a^2 - 1) + 1)^2)`` and Smith's
    ``G1 = 2 c / (c + sqrt(a^2 + (1 - a^2) c^2))`` (forms equal to, but not written as, the
    module's), Schlick's F from ``F0 = mix(0.04, c, m)``, plus Lambert ``c (1 - m) / pi``."""
    c = np.asarray(base_color, dtype=np.float64)
    a = roughness**2
    h = wi + wo
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    ch = h[:, 2]
    d = a * a / (np.pi * (ch * ch * (a * a - 1) + 1) ** 2)

    def g1(v):
        cv = v[:, 2]
        return 2 * cv / (cv + np.sqrt(a * a + (1 - a * a) * cv * cv))

    f0 = 0.04 * (1 - metallic) + c * metallic
    voh = (wo * h).sum(-1, keepdims=True)
    fresnel = f0 + (1 - f0) * (1 - voh) ** 5
    spec = fresnel * (d * g1(wi) * g1(wo) / (4 * wi[:, 2] * wo[:, 2]))[:, None]
    return c * (1 - metallic) / np.pi + spec, spec


def test_the_material_is_the_gltf_formula():
    # float64 throughout: both sides differ by rounding only (~1e-15 relative); 1e-10
    n, t = frame_args(F64)
    wi_l, wo_l = upper_dirs(400, 1), upper_dirs(400, 2)
    for metallic, roughness in ((0.0, 0.5), (1.0, 0.3), (0.35, 0.8), (0.6, 0.1)):
        diffuse, spec = B.metallic_roughness(
            *(torch.tensor(x, dtype=F64) for x in (_BASE, metallic, roughness))
        )
        assert diffuse.dtype == F64 and spec.params["f0"].dtype == F64
        model = B.Sum(B.Lambert(diffuse), spec)
        ours = model.eval(to_world(wi_l), to_world(wo_l), n, t)
        ours_spec = spec.eval(to_world(wi_l), to_world(wo_l), n, t)
        ref, ref_spec = gltf_formula(wi_l.numpy(), wo_l.numpy(), _BASE, metallic, roughness)
        torch.testing.assert_close(ours, torch.from_numpy(ref), rtol=1e-10, atol=0)
        torch.testing.assert_close(ours_spec, torch.from_numpy(ref_spec), rtol=1e-10, atol=0)


def test_metallic_roughness_maps_the_factors():
    diffuse, spec = B.metallic_roughness(_BASE, 0.25, 0.6)
    base = torch.tensor(_BASE)
    torch.testing.assert_close(diffuse, 0.75 * base)
    torch.testing.assert_close(spec.params["f0"], 0.04 * 0.75 + 0.25 * base)
    assert float(spec.params["alpha"]) == pytest.approx(0.36)
    # per vertex
    g = torch.Generator().manual_seed(0)
    c, m, r = torch.rand(5, 3, generator=g), torch.rand(5, generator=g), torch.rand(5, generator=g)
    mats = gltf_materials(c, m, r)
    torch.testing.assert_close(mats.diffuse, c * (1 - m[:, None]))
    torch.testing.assert_close(mats.specular.params["f0"], 0.04 * (1 - m[:, None]) + c * m[:, None])
    torch.testing.assert_close(mats.specular.params["alpha"], r * r)
    assert mats.model == "ggx_schlick" and mats.n_vertices == 5
    assert gltf_materials(_BASE, 1.0, 0.5, n_vertices=3).diffuse.abs().max() == 0
    with pytest.raises(InputError, match="n_vertices"):
        gltf_materials(_BASE, 0.5, 0.5)
    with pytest.raises(InputError, match="roughness"):
        gltf_materials(c, m, torch.rand(4))
    with pytest.raises(InputError, match="metallic"):
        gltf_materials(_BASE, 1.5, 0.5, n_vertices=3)


def test_normal_incidence_closed_form():
    # wi = wo = n: h = n, F = F0, D = 1 / (pi a^2), G1 = 1, so f = F0 / (4 pi a^2); float64
    n, t = frame_args(F64)
    up = to_world(torch.tensor([0.0, 0.0, 1.0], dtype=F64))
    f0 = torch.tensor([0.9, 0.3, 0.04], dtype=F64)
    for alpha in (0.002, 0.05, 0.3, 1.0):
        f = B.GGXSchlick(torch.tensor(alpha, dtype=F64), f0).eval(up, up, n, t)
        torch.testing.assert_close(f, f0 / (4 * math.pi * alpha**2), rtol=1e-12, atol=0)
    # below Mitsuba principled's clamp the lobe keeps alpha = 1e-3
    f = B.GGXSchlick(torch.tensor(1e-4, dtype=F64), f0).eval(up, up, n, t)
    torch.testing.assert_close(f, f0 / (4 * math.pi * 1e-6), rtol=1e-12, atol=0)


def test_f0_one_is_the_ggx_conductor_without_fresnel():
    # F = 1 everywhere: value, density and samples (same numbers) are GGX's, bit for bit
    n, t = frame_args()
    wi, wo = to_world(upper_dirs(500, 3, F32)), to_world(upper_dirs(500, 4, F32))
    u = torch.rand(500, 2, generator=torch.Generator().manual_seed(5))
    for alpha in (0.02, 0.3, 0.9):
        a, b = B.GGXSchlick(alpha, 1.0), B.GGX(alpha)
        torch.testing.assert_close(a.eval(wi, wo, n, t), b.eval(wi, wo, n, t), rtol=0, atol=0)
        torch.testing.assert_close(a.pdf(wi, wo, n, t), b.pdf(wi, wo, n, t), rtol=0, atol=0)
        for x, y in zip(a.sample(wo, n, u, t), b.sample(wo, n, u, t), strict=True):
            torch.testing.assert_close(x, y, rtol=0, atol=0)


def test_albedo_by_quadrature_and_sampling():
    # The lobe's directional albedo by quadrature of eval (48 x 96 bins of 8 x 8 nodes; error
    # < 1e-5 against 12 x 12 nodes) against its importance-sampled estimate (4σ + 2e-5), and
    # <= 1. Schlick's F is linear in F0, so E(F0) = F0 E(1) + (1 - F0) E(0) channel by channel.
    n, t = frame_args(F64)
    model = B.GGXSchlick(0.25, [1.0, 0.5, 0.0])
    for theta in (0.0, 60.0, 85.0):
        wo = to_world(local_dir(theta))

        def fcos(d, wo=wo):
            return model.eval(to_world(d), wo, n, t) * d[..., 2:]

        fine = hemisphere_integral(fcos, 48, 96, 8)
        check = hemisphere_integral(fcos, 48, 96, 12)
        assert float((fine - check).abs().max()) < 1e-5
        assert (fine <= 1).all()
        torch.testing.assert_close(fine[1], 0.5 * (fine[0] + fine[2]), rtol=1e-9, atol=0)
        mean, se = mc_albedo(model, local_dir(theta), 100_000, seed=2)
        assert ((fine - mean).abs() < 4 * se + 2e-5).all(), (theta, fine, mean)


def test_a_white_non_metal_reflects_more_than_it_receives_at_grazing():
    # the documented price of the plain Lambert term (lobelight.brdf.gltf): base colour 1,
    # metallic 0 has albedo 1 + the Schlick lobe's, above 1 towards grazing views. Quadrature
    # as above (the integrand is smooth: 48 x 96 bins of 8 x 8 nodes)
    n, t = frame_args(F64)
    diffuse, spec = B.metallic_roughness(1.0, 0.0, 0.5)
    model = B.Sum(B.Lambert(diffuse.double()), spec.to(dtype=F64))
    wo = to_world(local_dir(80.0))

    def fcos(d):
        return model.eval(to_world(d), wo, n, t)[..., 0] * d[..., 2]

    assert float(hemisphere_integral(fcos, 48, 96, 8)) > 1.02


# --------------------------------------------------------------------------------------------
# Mitsuba 3


def _mitsuba(variant: str = "scalar_rgb"):
    pytest.importorskip("mitsuba", reason="mitsuba is not installed")
    from lobelight.reference.mitsuba import load_mitsuba

    try:
        return load_mitsuba(variant)
    except (ImportError, AttributeError, ValueError, InputError) as exc:
        pytest.skip(reason=f"Mitsuba's {variant} variant cannot be set here: {exc}")


def _mi_eval(mi, bsdf, wi_l, wo_l, u=None):
    """Mitsuba's eval (with the cosine), pdf and, with ``u``, samples (direction, weight and
    density) at local direction pairs (Mitsuba's si.wi is our wo)."""
    import drjit as dr

    ctx = mi.BSDFContext()
    f, p, s_wi, s_w, s_p = [], [], [], [], []
    for a in range(wi_l.shape[0]):
        si = dr.zeros(mi.SurfaceInteraction3f)
        si.wi = mi.Vector3f(*wo_l[a].tolist())
        si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
        v = mi.Vector3f(*wi_l[a].tolist())
        f.append(list(bsdf.eval(ctx, si, v)))
        p.append(float(bsdf.pdf(ctx, si, v)))
        if u is not None:
            bs, w = bsdf.sample(ctx, si, 0.5, mi.Point2f(*u[a].tolist()))
            ok = any(float(x) != 0 for x in w)
            s_wi.append(list(bs.wo))
            s_w.append(list(w))
            s_p.append(float(bs.pdf) if ok else 0.0)
    out = [torch.tensor(f), torch.tensor(p)]
    if u is not None:
        out += [torch.tensor(s_wi), torch.tensor(s_w), torch.tensor(s_p)]
    return out


@pytest.mark.parametrize(
    ("alpha", "f0"),
    [(0.3, [0.9, 0.6, 0.2]), (0.05, [0.04, 0.04, 0.04]), (0.8, [1.0, 0.7, 0.0])],
)
def test_the_lobe_is_mitsuba_principled_metal(alpha, f0):
    """eval·cos, pdf and samples against Mitsuba's principled with metallic = 1 at 50 local
    pairs: 1e-5 relative (both sides compute the same formulas in float32; the largest
    difference seen is below 1e-6), samples as tests/test_brdf.py's GGX check."""
    mi = _mitsuba()
    model = B.GGXSchlick(alpha, f0)
    bsdf = mi.load_dict(model.mitsuba_dict())
    n, t = frame_args()
    wi_l, wo_l = mitsuba_pairs(50, alpha, seed=21)
    u = torch.rand(50, 2, generator=torch.Generator().manual_seed(22))
    wi, wo = to_world(wi_l.double()).float(), to_world(wo_l.double()).float()
    fcos = model.eval(wi, wo, n, t) * (wi * n).sum(-1, keepdim=True)
    pdf = model.pdf(wi, wo, n, t)
    ref_f, ref_p, ref_wi, ref_w, ref_sp = _mi_eval(mi, bsdf, wi_l, wo_l, u)
    assert (ref_f[:, 1] > 0).sum() >= 35
    torch.testing.assert_close(fcos, ref_f, rtol=1e-5, atol=1e-7 * float(ref_f.max()))
    torch.testing.assert_close(pdf, ref_p, rtol=1e-5, atol=1e-7 * float(ref_p.max()))
    s_wi, s_w, s_pdf = model.sample(wo, n, u, t)
    s_wi_l = s_wi.double() @ torch.stack([_T, _BT, _N]).T
    valid = ref_sp > 0
    assert valid.sum() > 30  # the rough lobe (alpha 0.8) sends a quarter below the horizon
    # sampled directions: tolerances of tests/test_brdf.py's GGX comparison (same routine)
    torch.testing.assert_close(s_wi_l[valid].float(), ref_wi[valid], rtol=1e-4, atol=2e-5)
    torch.testing.assert_close(s_w, ref_w, rtol=1e-4, atol=1e-7)
    torch.testing.assert_close(s_pdf[valid], ref_sp[valid], rtol=1e-4, atol=1e-7)


@pytest.mark.parametrize(
    ("base", "metallic", "roughness"), [(_BASE, 0.0, 0.5), (_BASE, 0.7, 0.3), (1.0, 0.0, 0.9)]
)
def test_the_material_is_mitsuba_diffuse_plus_principled(base, metallic, roughness):
    """The exported material (reference.mitsuba.material_dict: Mitsuba's diffuse and
    principled summed) against the Lambert + lobe sum: eval·cos to 1e-5 relative (float32 on
    both sides; the largest difference seen is ~3e-7), and the sum's own samples carry its
    value over its density."""
    from lobelight.reference.mitsuba import SUM_PLUGIN, material_dict

    mi = _mitsuba()
    diffuse, spec = B.metallic_roughness(base, metallic, roughness)
    d = material_dict(diffuse, spec)
    assert d["type"] == SUM_PLUGIN
    assert [d["bsdf_0"]["type"], d["bsdf_1"]["type"]] == ["diffuse", "principled"]
    bsdf = mi.load_dict(d)
    model = B.Sum(B.Lambert(diffuse), spec)
    n, t = frame_args()
    wi_l, wo_l = mitsuba_pairs(50, roughness**2, seed=31)
    u = torch.rand(50, 2, generator=torch.Generator().manual_seed(32))
    wi, wo = to_world(wi_l.double()).float(), to_world(wo_l.double()).float()
    fcos = model.eval(wi, wo, n, t) * (wi * n).sum(-1, keepdim=True)
    ref_f, ref_p, s_wi, s_w, s_p = _mi_eval(mi, bsdf, wi_l, wo_l, u)
    torch.testing.assert_close(fcos, ref_f, rtol=1e-5, atol=1e-7 * float(ref_f.max()))
    # the mixture density is the parts' densities weighted by the sum's probabilities
    parts = [mi.load_dict(d["bsdf_0"]), mi.load_dict(d["bsdf_1"])]
    mix = d["prob_0"] * _mi_eval(mi, parts[0], wi_l, wo_l)[1]
    mix = mix + d["prob_1"] * _mi_eval(mi, parts[1], wi_l, wo_l)[1]
    torch.testing.assert_close(ref_p, mix, rtol=1e-6, atol=0)
    # samples: weight = eval·cos / pdf at the sampled direction (both from Mitsuba)
    ok = s_p > 0
    assert ok.sum() > 40
    f_s, p_s = _mi_eval(mi, bsdf, s_wi[ok], wo_l[ok])
    torch.testing.assert_close(s_w[ok], f_s / p_s[:, None], rtol=1e-5, atol=0)
    torch.testing.assert_close(s_p[ok], p_s, rtol=1e-6, atol=0)


# --------------------------------------------------------------------------------------------
# the path tracer and the sun shader


def test_the_path_tracer_shades_it_under_a_white_sky():
    # A convex sphere under uniform radiance 1: every path escapes after one bounce, so the
    # radiance leaving a vertex towards wo is the material's directional albedo there, here by
    # quadrature of eval (48 x 96 bins of 8 x 8 nodes: < 1e-5). The path tracer's estimate
    # (its BRDF sampling, densities and MIS with the sky) within 4 standard errors + 1e-4.
    sc = scene.builtin("sphere", subdivisions=2)
    mats = gltf_materials(_BASE, 0.4, 0.45, n_vertices=sc.mesh.n_vertices)
    sc = dataclasses.replace(sc, materials=mats)
    env = envmap.EnvMap(torch.ones(16, 32, 3), layout="latlong", name="white")
    v = torch.tensor([0, 7])
    nrm = sc.mesh.normals[v].double()
    lt, lb, ln = sphere.frame(nrm)  # (2, 3) each
    th = torch.tensor([10.0, 70.0], dtype=F64).deg2rad()[:, None]
    views = th.sin() * lt + th.cos() * ln  # one view per vertex, 10 and 70 degrees off normal
    mean, se = reference.radiance_at(sc, env, v, views.float(), spp=4096, max_depth=-1)
    model = mats.take(v[:1]).brdf().to(dtype=F64)
    for k in range(2):
        frame = torch.stack([lt[k], lb[k], ln[k]])  # rows: local x, y, z in the world

        def fcos(d, k=k, frame=frame):
            w = d @ frame
            return model.eval(w, views[k].expand_as(w), nrm[k].expand_as(w)) * d[..., 2:]

        albedo = hemisphere_integral(fcos, 48, 96, 8)
        got, err = mean[k, k].double(), se[k, k].double()
        assert ((got - albedo).abs() <= 4 * err + 1e-4).all(), (k, got, albedo, err)


@pytest.fixture(scope="module")
def sun_light(builtin_sky):
    return render.Lighting(builtin_sky, base_res=16, sun=True)


@needs_gl
def test_the_sun_shader_evaluates_the_lobe(sun_light):
    # prt.glsl's Schlick branch against lobelight.brdf's eval (the torch path), as
    # tests/test_sun.py checks the other models: a sphere with a per-vertex F0 and roughness,
    # no Gaussians and no SH, so the glossy image is the sun's highlight alone. Tolerances as
    # there: 1e-3 relative where the highlight is, float32 GLSL against float32 torch.
    sc = scene.builtin("sphere", subdivisions=4)
    # fields smooth over the sphere, as textures give: F0 from dielectric to coloured metal
    x, y, _ = (0.5 + 0.5 * sc.mesh.vertices / sc.mesh.vertices.norm(dim=-1, keepdim=True)).unbind(
        -1
    )
    base = torch.stack([0.2 + 0.8 * x, torch.full_like(x, 0.6), torch.full_like(x, 0.1)], -1)
    mats = gltf_materials(base, y, 0.3 + 0.2 * x)
    m = dark_model(dataclasses.replace(sc, materials=mats))
    assert_sun_highlight_matches_torch(m, sun_light)
