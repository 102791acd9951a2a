"""The SG-BRDF method in GLSL (render/_gl_sgbrdf.py) against its torch twin.

The torch path (``lobelight.sgbrdf.shade`` / ``render_sphere`` with the exact Prefiltered
chain for "ours", ``shade_fis`` for "fis") is the reference: both do the same float32
arithmetic, so the images agree to rounding and to the texture units' filtering precision.
The bound of the existing renderer, 1e-3 relative per covered pixel, is used here too; on
llvmpipe the worst pixels stay well inside it (for FIS a silhouette pixel under a perspective
camera, where the float32 ray-sphere hit of the shader and the float64 one of ``sphere_hits``
differ most). GPU texture units blend with 8-bit sub-texel weights, an error of
at most 1/512 of the difference between neighbouring texels (a few per cent on the smooth test
map), i.e. ~1e-4: still inside the bound. Small fits (few lobes and samples) and 64 x 64 images
keep every test short; a fit's quality is irrelevant to agreement between renderers.
"""

from __future__ import annotations

import math

import pytest
import torch

from conftest import smooth_env
from lobelight.bench import bench_sgbrdf_gl, time_frames
from lobelight.brdf import GGX, Ward
from lobelight.envmap import EnvMap, prefilter
from lobelight.errors import InputError
from lobelight.geometry.camera import Camera
from lobelight.lobes.sg import integral
from lobelight.render._gl import gl_available
from lobelight.render._gl_sgbrdf import GLSGBRDFRenderer, gl_mip_chain
from lobelight.sgbrdf import fit, render_sphere, shade, shade_fis, sphere_hits
from lobelight.studies.compare_brdf import compare_brdf

needs_gl = pytest.mark.skipif(not gl_available(), reason="no headless OpenGL context (EGL)")

#: The agreement bound between the GL and torch paths (module docstring).
REL_TOL = 1e-3
CAM = Camera.look_at((0.5, 1.0, 3.0), (0.0, 0.0, 0.0), fov=45.0)
W, H = 64, 48  # not square, so that a swapped axis would show


pytestmark = pytest.mark.usefixtures("one_torch_thread")


MATERIALS = {
    # elevation layout (16 views); geodesic layout (92 views, 61 fitted); both grey, so the
    # shader reads one texel per lobe ("GREY"); a coloured one reads the two-texel layout
    "iso": Ward(1.0, 0.1),
    "aniso": Ward(1.0, 0.05, 0.2),
    "rgb": Ward((0.9, 0.6, 0.3), 0.1),
}


@pytest.fixture(scope="module")
def models():
    return {
        k: fit(b, n_lobes=3 if k == "aniso" else 4, samples=512, max_iter=40)
        for k, b in MATERIALS.items()
    }


@pytest.fixture(scope="module")
def env():
    return smooth_env()


@pytest.fixture(scope="module")
def pf(env):
    return prefilter(env, base_res=32)


def _rel(got: torch.Tensor, want: torch.Tensor) -> torch.Tensor:
    """Per-pixel relative error, ``(P,)``: max channel difference over the max channel."""
    return (got - want).abs().amax(-1) / want.amax(-1).clamp_min(1e-6)


@needs_gl
@pytest.mark.parametrize("kind", ["iso", "aniso", "rgb"])
@pytest.mark.parametrize("camera", [None, CAM], ids=["ortho", "perspective"])
def test_ours_matches_torch(models, pf, kind, camera):
    model = models[kind]
    assert model.layout == ("geodesic" if kind == "aniso" else "elevation")
    with GLSGBRDFRenderer(model, pf, W, H, method="ours") as r:
        assert r.defines["GREY"] == int(kind != "rgb")
        img, mask = r.render(camera)
    ref, ref_mask = render_sphere(model, pf, width=W, height=H, camera=camera)
    # the orthographic rays are the same float32 formula; a perspective hit is float32 in the
    # shader and float64 in sphere_hits, which may disagree where a pixel centre grazes the rim
    assert int((mask != ref_mask).sum()) <= (0 if camera is None else 2)
    both = mask & ref_mask
    assert int(both.sum()) > 0.4 * W * H
    assert float(ref[both].amax()) > 0.5  # the image is not trivially dark
    assert float(_rel(img[both], ref[both]).max()) <= REL_TOL
    assert bool((img[~mask] == 0).all())


@needs_gl
@pytest.mark.parametrize("kind", ["iso", "aniso"])
@pytest.mark.parametrize("camera", [None, CAM], ids=["ortho", "perspective"])
def test_fis_matches_torch(models, env, kind, camera):
    b = MATERIALS[kind]
    # the GL cube map's coarser levels are glGenerateMipmap's 2 x 2 means: gl_mip_chain
    chain = gl_mip_chain(env, base_res=32)
    with GLSGBRDFRenderer(models[kind], env, W, H, method="fis", chain=chain, brdf=b) as r:
        img, mask = r.render(camera)
    hits = sphere_hits(W, H, camera=camera)
    m = hits["mask"]
    ref = torch.zeros(H, W, 3)
    ref[m] = shade_fis(b, chain, hits["normals"][m], hits["views"][m], tangents=hits["tangents"][m])
    assert int((mask != m).sum()) <= (0 if camera is None else 2)
    both = mask & m
    assert float(ref[both].amax()) > 0.5
    assert float(_rel(img[both], ref[both]).max()) <= REL_TOL


@needs_gl
def test_fis_default_material_and_lighting(models, env):
    # without brdf / chain: the model's own material and the EnvMap resampled to fis_res,
    # i.e. shade_fis on gl_mip_chain(env, base_res=fis_res)
    with GLSGBRDFRenderer(models["iso"], env, 32, 32, method="fis", fis_res=16) as r:
        img, mask = r.render()
    hits = sphere_hits(32)
    m = hits["mask"]
    want = shade_fis(
        MATERIALS["iso"],
        gl_mip_chain(env, base_res=16),
        hits["normals"][m],
        hits["views"][m],
        tangents=hits["tangents"][m],
    )
    assert bool((mask == m).all())
    assert float(_rel(img[m], want).max()) <= REL_TOL


@needs_gl
@pytest.mark.parametrize("kind", ["iso", "aniso"])
def test_constant_environment_gives_the_albedo(models, kind):
    # Under L = 1 every lobe integrates to its mass w Z(kappa), so a pixel shows the fitted
    # mixture's integral, the interpolated directional albedo. The prefiltered levels of a
    # constant map are 1 up to float32 rounding, hence 1e-4.
    model = models[kind]
    white = EnvMap(torch.ones(16, 32, 3), layout="latlong", name="white")
    with GLSGBRDFRenderer(model, prefilter(white, base_res=16), W, W, method="ours") as r:
        img, mask = r.render()
    hits = sphere_hits(W)
    n = hits["normals"][mask]  # orthographic: the view is +Z, so cos(theta_o) = n_z
    if kind == "iso":
        # independent of SGBRDF.lobes: the mixture at fitted view j integrates to albedo[j]
        # exactly (its weights are A_j alpha_jk C(kappa_jk)), and masses blend linearly in theta
        th_v = torch.atan2(model.views[:, 0], model.views[:, 2]).double()
        th = torch.acos(n[:, 2].double().clamp(-1, 1)).clamp(float(th_v[0]), float(th_v[-1]))
        j1 = torch.searchsorted(th_v, th).clamp(1, len(th_v) - 1)
        s = ((th - th_v[j1 - 1]) / (th_v[j1] - th_v[j1 - 1])).unsqueeze(-1)
        a = model.albedo.double()
        want = (1 - s) * a[j1 - 1] + s * a[j1]
    else:
        # the geodesic views not fitted have weight 0 and no albedo: take the interpolated
        # mixture's integral, sum_k w_k Z(kappa_k)
        t = hits["tangents"][mask]
        o = torch.stack([t[:, 2], torch.cross(n, t, dim=-1)[:, 2], n[:, 2]], -1)
        _, kappa, weight = model.lobes(o)
        want = (weight * integral(kappa).unsqueeze(-1)).sum(-2).double()
    assert float(want.min()) > 0.3
    assert float(_rel(img[mask].double(), want).max()) <= 1e-4


@needs_gl
@pytest.mark.parametrize("method", ["ours", "fis"])
def test_mesh_matches_torch(models, env, pf, method):
    # a square in z = 0 with a tilted shading normal and a tangent, seen in perspective: every
    # pixel's point is the analytic ray-plane hit, so the torch path is exact per pixel
    # (the rasteriser's perspective-correct interpolation differs by rounding only)
    model, b = models["aniso"], MATERIALS["aniso"]
    nrm = torch.nn.functional.normalize(torch.tensor([0.3, 0.2, 1.0]), dim=0)
    tan = torch.tensor([1.0, 0.5, 0.0])
    mesh = {
        "positions": torch.tensor([[-1.0, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]]),
        "normals": nrm.expand(4, 3),
        "tangents": tan.expand(4, 3),
        "faces": [[0, 1, 2], [0, 2, 3]],
    }
    cam = Camera.look_at((0.3, 0.2, 2.5), (0.0, 0.0, 0.0), fov=50.0)
    chain = gl_mip_chain(env, base_res=32)
    light = pf if method == "ours" else env
    with GLSGBRDFRenderer(model, light, W, W, method=method, mesh=mesh, brdf=b, chain=chain) as r:
        img, mask = r.render(cam)
        flat, flat_mask = r.render(None)  # orthographic: one normal, one view, one value
    org, d = cam.rays(W, W, dtype=torch.float64)
    p = org + (-org[..., 2] / d[..., 2]).unsqueeze(-1) * d
    inside = (p[..., 0].abs() < 0.97) & (p[..., 1].abs() < 0.97)  # clear of the edges
    v = (-d).float()
    nn, tt = nrm.expand_as(v), tan.expand_as(v)
    if method == "ours":
        want = shade(model, pf, nn, v, tangents=tt)
        want_flat = shade(model, pf, nrm, torch.tensor([0.0, 0.0, 1.0]), tangents=tan)
    else:
        want = shade_fis(b, chain, nn, v, tangents=tt)
        want_flat = shade_fis(b, chain, nrm, torch.tensor([0.0, 0.0, 1.0]), tangents=tan)
    assert bool(mask[inside].all())
    assert float(_rel(img[inside], want[inside]).max()) <= REL_TOL
    assert bool(flat_mask.all())  # the square covers [-1, 1]^2, the whole orthographic view
    assert float(_rel(flat[flat_mask], want_flat.expand(int(flat_mask.sum()), 3)).max()) <= REL_TOL


@needs_gl
def test_bench_gl_reports_both_methods(models, pf, env):
    # structure only: the numbers are machine-dependent and a test times nothing it asserts on
    chain = gl_mip_chain(env, base_res=16)
    res = bench_sgbrdf_gl(models["iso"], pf, chain=chain, size=16, min_seconds=0.02, rounds=1)
    assert res["benchmark"] == "sgbrdf_gl"
    assert set(res["fps"]) == {"ours", "fis40"}
    assert all(v > 0 and math.isfinite(v) for v in res["fps"].values())
    assert res["pixels"] == int(sphere_hits(16)["mask"].sum())
    assert res["fis_samples"] == 40 and res["renderer"]
    assert math.isclose(res["speedup"], res["fps"]["ours"] / res["fps"]["fis40"])


@needs_gl
def test_compare_brdf_gl_rows(tmp_path, monkeypatch, env):
    import lobelight.studies.compare_brdf as cmp

    # short timings: the rows' presence and accuracy are tested, not the speed
    monkeypatch.setattr(cmp, "GL_MIN_SECONDS", 0.01)
    monkeypatch.setattr(cmp, "GL_ROUNDS", 1)
    res = compare_brdf(
        tmp_path, env=env, size=16, alphas=(0.1,), aniso=None, ref_spp=64, backend="both"
    )
    rows = {r["method"]: r for r in res["table"]}
    assert {"ours_gl", "fis40_gl"} <= set(rows) and res["gl"]["renderer"]
    assert res["methods"][-2:] == ["ours_gl", "fis40_gl"]
    # the GL image equals the torch one to REL_TOL per pixel, so its relative L2 error against
    # the reference moves by at most that much
    assert abs(rows["ours_gl"]["rel_l2"] - rows["ours"]["rel_l2"]) <= REL_TOL
    for key in ("gl_all_psnr_ours_ge_fis", "gl_ours_faster_than_fis"):
        assert isinstance(res["goals"][key], bool)


def test_bad_input(models, pf, env):
    # checked before any OpenGL context is made: runs without one
    m = models["iso"]
    with pytest.raises(InputError, match="method"):
        GLSGBRDFRenderer(m, pf, 8, 8, method="mip")
    with pytest.raises(InputError, match="model"):
        GLSGBRDFRenderer(m.params, pf, 8, 8)
    with pytest.raises(InputError, match="lighting"):
        GLSGBRDFRenderer(m, "sky.hdr", 8, 8)
    with pytest.raises(InputError, match="lighting"):
        GLSGBRDFRenderer(m, prefilter(env, base_res=16, blend="moment"), 8, 8)
    with pytest.raises(InputError, match="width"):
        GLSGBRDFRenderer(m, pf, 0, 8)
    with pytest.raises(InputError, match="brdf"):
        GLSGBRDFRenderer(m, env, 8, 8, method="fis", brdf=GGX(0.1))
    with pytest.raises(InputError, match="lighting"):
        GLSGBRDFRenderer(m, pf, 8, 8, method="fis")  # a Prefiltered has no map to sample
    with pytest.raises(InputError, match="chain"):
        GLSGBRDFRenderer(m, env, 8, 8, method="fis", chain=torch.ones(6, 12, 12, 3))
    with pytest.raises(InputError, match="samples"):
        GLSGBRDFRenderer(m, env, 8, 8, method="fis", samples=0)
    quad = {"positions": torch.zeros(3, 3), "normals": torch.zeros(3, 3), "faces": [[0, 1, 3]]}
    with pytest.raises(InputError, match="faces"):
        GLSGBRDFRenderer(m, pf, 8, 8, mesh=quad)
    with pytest.raises(InputError, match="normals"):
        GLSGBRDFRenderer(m, pf, 8, 8, mesh={"positions": torch.zeros(3, 3), "faces": [[0, 1, 2]]})
    with pytest.raises(InputError, match="backend"):
        compare_brdf("unused", backend="gl")
    with pytest.raises(InputError, match="base_res"):
        gl_mip_chain(env, base_res=24)


@needs_gl
def test_bad_camera_and_timing(models, pf):
    with GLSGBRDFRenderer(models["iso"], pf, 8, 8) as r:
        with pytest.raises(InputError, match="camera"):
            r.render((0, 0, 3))
        with pytest.raises(InputError, match="min_seconds"):
            time_frames(r, 0.0)


@needs_gl
def test_lobes_in_every_octant(pf):
    # a synthetic table whose means point into all eight octants (below the horizon too), so
    # that the grey layout's octahedral means are decoded on every fold of the map
    from lobelight.sgbrdf import SGBRDF, elevation_views

    views = elevation_views(4)
    signs = torch.tensor([[sx, sy, sz] for sx in (1, -1) for sy in (1, -1) for sz in (1, -1)])
    mu = torch.nn.functional.normalize(signs * torch.tensor([0.3, 0.5, 0.8]), dim=-1)
    kappa = torch.tensor([2.0, 5.0, 20.0, 50.0, 3.0, 8.0, 30.0, 100.0])
    w = torch.linspace(0.2, 1.0, 8).unsqueeze(-1).expand(8, 3)
    params = torch.cat([w, mu, kappa.unsqueeze(-1)], -1)  # (8, 7)
    params = params.expand(4, 8, 7) * torch.tensor([1.0, 0.9, 0.8, 0.7]).view(4, 1, 1)
    params[..., 3:6] = mu  # the scale above is for the weights and sharpness only
    model = SGBRDF(
        params=params.contiguous(),
        views=views,
        fit_views=views,
        layout="elevation",
        albedo=torch.ones(4, 3),
        used=torch.ones(4, dtype=torch.bool),
    )
    with GLSGBRDFRenderer(model, pf, W, H) as r:
        assert r.defines["GREY"] == 1
        img, mask = r.render(CAM)
    ref, ref_mask = render_sphere(model, pf, width=W, height=H, camera=CAM)
    both = mask & ref_mask
    assert float(_rel(img[both], ref[both]).max()) <= REL_TOL
