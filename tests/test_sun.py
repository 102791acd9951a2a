"""The sun taken out of the diffuse lighting and shaded per pixel with shadows."""

from __future__ import annotations

import math

import pytest
import torch

from lobelight import brdf, envmap, fit, render, scene
from lobelight.envmap import _builtin
from lobelight.geometry import sphere
from lobelight.geometry.raycast import RayCaster
from lobelight.model import Model
from lobelight.render._gl import gl_available

needs_gl = pytest.mark.skipif(not gl_available(), reason="no headless OpenGL context (EGL)")


@pytest.fixture(scope="module")
def sky(builtin_sky):
    return builtin_sky


@pytest.fixture(scope="module")
def sun_light(sky):
    """The sky's lighting with the sun taken out (base 16): one for the module, as a viewer
    keeps one for every frame (its chains are built on first use and kept)."""
    return render.Lighting(sky, base_res=16, sun=True)


def dark_model(sc) -> Model:
    """A model of a scene's mesh with no glossy transport and no SH diffuse: its diffuse part
    is the sun's light alone."""
    v = sc.mesh.n_vertices
    mu = torch.zeros(v, 92, 1, 3)
    mu[..., 2] = 1.0
    g = fit.Gaussians(torch.zeros(v, 92, 1, 3), mu, torch.ones(v, 92, 1))
    return Model(sc.mesh, sphere.geodesic_views(), g, torch.zeros(v, 25, 3), sc.materials, {})


def test_extract_sun_finds_the_builtin_sun(sky):
    sun, rest = envmap.extract_sun(sky)
    assert sun is not None
    want = torch.tensor(_builtin.SUN_DIRECTION, dtype=torch.float32)
    # the disc is 0.6 deg across on 0.35 deg pixels: its weighted centre to a tenth of a degree
    angle = math.degrees(math.acos(min(1.0, float(sun.direction @ want))))
    assert angle < 0.1
    # nothing is lost or made: the residual carries the rest of the power (float32 sums)
    torch.testing.assert_close(rest.power() + sun.irradiance, sky.power(), rtol=1e-5, atol=0)
    # the built-in sun carries half of the power (mean over RGB); the ring's estimate of the
    # glow under the disc moves that by well under 1 %
    share = float(sun.irradiance.mean() / sky.power().mean())
    assert abs(share - _builtin._SUN_FRACTION) < 0.01
    # the residual has no sun left in it
    assert envmap.extract_sun(rest)[0] is None
    assert float(rest.data.amax()) < 0.01 * float(sky.data.amax())


def test_an_extended_source_is_taken_whole_with_its_spread():
    """A uniform disc of 6 degrees (a studio's softbox) on a dim sky: the sun is all of it, its
    farthest pixel at the disc's radius and its RMS angle that of a uniform disc, r / sqrt 2."""
    from lobelight.envmap._envmap import _LatlongCells

    h, w = 256, 512
    dirs = _LatlongCells(h, w).frames()[0].double().reshape(h, w, 3)
    centre = torch.nn.functional.normalize(torch.tensor([0.6, 0.5, -0.3]), dim=0).double()
    r = math.radians(6.0)
    inside = (dirs @ centre) >= math.cos(r)
    data = torch.full((h, w, 3), 0.5, dtype=torch.float64)
    data[inside] = 400.0
    env = envmap.EnvMap(data.float(), layout="latlong", name="softbox")
    sun, rest = envmap.extract_sun(env)
    assert sun is not None
    # pixels are 0.7 degrees: the radius to a pixel; the RMS angle to a tenth (measured 6 %
    # under r / sqrt 2: the pixel centres inside the cone stop short of its edge)
    assert abs(math.degrees(sun.radius) - 6.0) < 0.7
    assert sun.spread == pytest.approx(r / math.sqrt(2), rel=0.1)
    torch.testing.assert_close(rest.power() + sun.irradiance, env.power(), rtol=1e-4, atol=0)
    # all of the disc's light above the sky is the sun's: the rest is the sky alone
    assert float(rest.data.amax()) == pytest.approx(0.5, rel=1e-3)


def test_a_map_without_a_sun_stays_whole():
    flat = envmap.EnvMap(torch.ones(32, 64, 3), layout="latlong", name="flat")
    sun, rest = envmap.extract_sun(flat)
    assert sun is None and rest is flat
    with pytest.raises(Exception, match="threshold"):
        envmap.extract_sun(flat, threshold=2.0)


def test_diffuse_lighting_without_the_sun_plus_the_sun_is_the_whole(sky):
    whole = render.Lighting(sky, base_res=16)
    split = render.Lighting(sky, base_res=16, prefiltered=whole.prefiltered, sun=True)
    assert whole.sun is None and split.sun is not None
    # the constant SH term is the power / sqrt(4 pi); the projection resamples the map to a
    # 64^2 cube first (solid-angle weighted), which keeps the power to float32 rounding
    y00 = 1 / math.sqrt(4 * math.pi)
    torch.testing.assert_close(
        split.sh[0] + split.sun.irradiance * y00, whole.sh[0], rtol=2e-3, atol=0
    )
    # the sun turns with the lighting: R d
    rot = render.as_rotation(70.0)
    torch.testing.assert_close(split.sun_direction(rot), rot @ split.sun.direction)


def test_sun_on_a_convex_sphere_is_lambert_without_shadows(sun_light):
    # a convex mesh casts no shadow on itself: every point facing the sun gets
    # albedo / pi E cos exactly, cos with the interpolated normal. Independently of the
    # renderer: the radial normal at the ray's hit point
    sc = scene.builtin("sphere", subdivisions=4)
    m = dark_model(sc)
    light = sun_light
    cam = render.Camera.look_at((0.3, 0.8, 3.0), (0.0, 0.0, 0.0), fov=40)
    ren = render.Renderer(m, light, 64, 48, backend="torch")
    img, mask = ren.render(cam, 25.0, background=False, glossy=False, return_mask=True)
    o, d = cam.rays(64, 48)
    _, dist, _ = RayCaster(m.mesh, offset=0.0).first_hit(o[mask], d[mask])
    # the true sphere's normal at the hit point: radial (the mesh is centred at the origin)
    n = torch.nn.functional.normalize(
        o[mask].double() + dist.double()[:, None] * d[mask].double(), dim=-1
    )
    l = light.sun_direction(render.as_rotation(25.0)).double()
    want = sc.materials.diffuse[0].double() / math.pi * light.sun.irradiance.double()
    want = want * (n @ l).clamp_min(0)[:, None]
    got = img[mask].double()
    # away from the terminator: 1e-2 of the peak (the mesh's vertex normals, averaged face
    # normals, are within 0.34 deg of radial at the hit points: the cosine differs by <= 0.006)
    away = (n @ l) > 0.1
    assert int(away.sum()) > 100  # the test sees lit points
    assert float((got - want)[away].abs().max()) < 1e-2 * float(want.max())
    # at it, a facet whose plane faces away from the sun while its interpolated normal does
    # not is in its own shadow, as a shadow ray from a flat triangle must be: the error is at
    # most the cosine a ~2 deg facet can differ by, ~0.035 of the peak
    assert float((got - want).abs().max()) < 0.035 * float(want.max())


@needs_gl
def test_shadow_map_matches_shadow_rays_on_the_knot(sun_light):
    # the shader's soft shadow map against the torch path's shadow rays over the sun's disc
    # (render/_sun_shadow.py): they can differ only in the penumbrae, a pixel wide here (the
    # shader places its taps by the blockers' heights in the map, the rays meet each blocker
    # where it is; the map's texel size). Measured 2.0 % of the object pixels over 1e-3, 1.6 %
    # over 1e-2 and 0.7 % over 0.1
    sc = scene.builtin("knot")
    m = dark_model(sc)
    light = sun_light
    out = {}
    for backend in ("gl", "torch"):
        # one sample per pixel: the count below is of single samples near a shadow edge
        with render.Renderer(m, light, 128, 96, backend=backend, samples=1) as ren:
            out[backend] = ren.render(
                sc.camera, 30.0, background=False, glossy=False, return_mask=True
            )
    (a, ma), (t, mt) = out["gl"], out["torch"]
    both = ma & mt
    rel = (a - t).abs().amax(-1) / t.amax(-1).clamp_min(1e-3)
    assert float((rel[both] > 1e-3).float().mean()) < 0.03
    assert float((rel[both] > 0.1).float().mean()) < 0.015
    assert float((a - t)[both].abs().mean()) < 0.01 * float(t[both].mean())
    # there are shadows to get right: points facing the sun that it does not reach
    mesh = m.mesh
    o, d = sc.camera.rays(128, 96)
    tri, _, bary = RayCaster(mesh, offset=0.0).first_hit(o.reshape(-1, 3), d.reshape(-1, 3))
    hit = tri >= 0
    f = mesh.faces[tri[hit]]
    n = torch.nn.functional.normalize((mesh.normals[f] * bary[hit][..., None]).sum(1), dim=-1)
    facing = (n @ light.sun_direction(render.as_rotation(30.0))) > 0.1
    dark = t.reshape(-1, 3)[hit].amax(-1) <= 0
    assert float((facing & dark).float().mean()) > 0.05


@needs_gl
def test_the_shadow_map_follows_the_turning_light(sun_light):
    # the map is re-rendered only when the sun's direction changes: turning away and back
    # gives the first frame again, and the turned frame differs
    sc = scene.builtin("knot")
    light = sun_light
    with render.Renderer(dark_model(sc), light, 64, 48, backend="gl") as ren:
        a = ren.render(sc.camera, 30.0, background=False)
        b = ren.render(sc.camera, 100.0, background=False)
        c = ren.render(sc.camera, 30.0, background=False)
        d = ren.render(sc.camera, 100.0, background=False)
    torch.testing.assert_close(a, c, rtol=0, atol=0)
    torch.testing.assert_close(b, d, rtol=0, atol=0)
    assert float((a - b).abs().mean()) > 0.05 * float(a.mean())


def _with_specular(sc, spec):
    import dataclasses

    return dataclasses.replace(sc, materials=dataclasses.replace(sc.materials, specular=spec))


_SPECULARS = {
    # the knot's own model, with a per-vertex exponent and colour
    "phong_per_vertex": lambda v: brdf.Phong(
        torch.linspace(0.2, 0.9, v)[:, None].expand(v, 3), torch.linspace(50.0, 400.0, v)
    ),
    "blinn_phong": lambda v: brdf.BlinnPhong(0.6, 120.0),
    "ggx_gold": lambda v: brdf.GGX(0.15, eta=[0.143, 0.374, 1.442], k=[3.983, 2.385, 1.603]),
    "beckmann_per_vertex": lambda v: brdf.Beckmann(torch.linspace(0.05, 0.3, v), specular=0.8),
}


@needs_gl
@pytest.mark.parametrize("name", sorted(_SPECULARS))
def test_sun_glossy_shader_matches_the_torch_brdf(sun_light, name):
    # the shader's BRDFs (prt.glsl) against lobelight.brdf's, which tests/test_brdf.py checks
    # against Mitsuba 3: a model with no Gaussians and no SH, so its glossy image is the sun's
    # glossy reflection alone. A convex sphere casts no shadow; float32 GLSL against float32
    # torch, per-vertex parameters interpolated alike (the rasteriser's perspective-correct
    # interpolation against barycentrics of the ray hit: equal up to rounding)
    sc = scene.builtin("sphere", subdivisions=4)
    sc = _with_specular(sc, _SPECULARS[name](sc.mesh.n_vertices))
    assert_sun_highlight_matches_torch(dark_model(sc), sun_light)


def assert_sun_highlight_matches_torch(m: Model, light) -> None:
    """The glossy image of a model with no Gaussians and no SH (the sun's highlight alone) in
    GL and in torch, seen from one camera: the two agree."""
    cam = render.Camera.look_at((0.3, 0.8, 3.0), (0.0, 0.0, 0.0), fov=40)
    out = {}
    for backend in ("gl", "torch"):
        with render.Renderer(m, light, 96, 72, backend=backend) as ren:
            out[backend] = ren.render(cam, 200.0, background=False, diffuse=False, return_mask=True)
    (a, ma), (t, mt) = out["gl"], out["torch"]
    both = ma & mt
    peak = float(t[both].amax())
    assert peak > 1.0  # the sun's highlight is in view (E_sun is ~2e2 here)
    lit = t[both].amax(-1) > 1e-3 * peak
    assert int(lit.sum()) > 50
    rel = (a - t)[both].abs().amax(-1) / t[both].amax(-1).clamp_min(1e-3 * peak)
    # 1e-3 relative where the highlight is; a few terminator pixels may differ where the
    # shadow map's bias lets through what the ray's offset does not (as for the diffuse sun)
    assert float((rel[lit] > 1e-3).float().mean()) < 0.02, float(rel[lit].max())
    assert float((a - t)[both].abs().mean()) < 1e-3 * float(t[both].mean())


def test_the_sun_and_the_rest_of_the_map_make_the_whole_for_the_gaussians(sky):
    # the Gaussians of a model shaded with the sun per pixel integrate the map without it: for
    # a lobe much wider than the sun, int G L = int G L_rest + G(l) E_sun, to the chains'
    # prefiltering accuracy (docs/results.md: <= 2 % for these widths)
    light = render.Lighting(sky, base_res=64, sun=True)
    g = torch.Generator().manual_seed(3)
    l = light.sun.direction
    mu = torch.nn.functional.normalize(l + 0.3 * torch.randn(64, 3, generator=g), dim=-1)
    rot = torch.eye(3)
    for lam in (2.0, 10.0, 40.0):
        lam_t = torch.full((64,), lam)
        whole = light.integrate(mu, lam_t, rot)
        rest = light.rest_prefiltered.integrate(mu, lam_t)
        sun = torch.exp(lam * ((mu @ l) - 1))[:, None] * light.sun.irradiance
        assert float(((rest + sun) - whole).norm() / whole.norm()) < 0.02


def test_only_models_the_shader_can_evaluate_take_the_sun_per_pixel():
    from lobelight.render._sun_glossy import sun_glossy_supported

    assert sun_glossy_supported(brdf.GGX(0.1)) and sun_glossy_supported(brdf.Phong(0.5, 10.0))
    # anisotropic lobes, Ward, Lafortune and sums keep the sun in the Gaussians' lighting
    assert not sun_glossy_supported(brdf.GGX(alpha_u=0.1, alpha_v=0.3))
    assert not sun_glossy_supported(brdf.Ward(0.5, 0.1))
    assert not sun_glossy_supported(None)


@pytest.mark.parametrize(
    "spec",
    [brdf.GGX(0.05), brdf.Beckmann(0.05), brdf.Phong(1.0, 800.0), brdf.BlinnPhong(1.0, 2000.0)],
    ids=["ggx", "beckmann", "phong", "blinn-phong"],
)
def test_a_wide_sun_widens_the_lobe_and_keeps_its_light(spec):
    """A sharp lobe lit by a uniform disc of 4 degrees: the disc's average of f cos (quadrature
    over the disc) against the point sun with the widened lobe and with the lobe as it is, at
    views across the highlight. The point sun overshoots the peak by the ratio of the lobe's
    width to the disc's; the widened lobe follows the disc's average and keeps its light."""
    from lobelight.render._sun_glossy import sun_widened

    radius = math.radians(4.0)
    n = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    tilt = math.radians(30.0)
    centre = torch.tensor([math.sin(tilt), 0.0, math.cos(tilt)], dtype=torch.float64)
    # the disc: a polar grid of equal solid angles about its centre
    k = 64
    u = (torch.arange(k, dtype=torch.float64) + 0.5) / k
    s = 1 - u * (1 - math.cos(radius))  # cos of the angle from the centre, equal-area rings
    phi = (torch.arange(2 * k, dtype=torch.float64) + 0.5) * (math.pi / k)
    t, b, _ = sphere.frame(centre)
    st = (1 - s**2).sqrt()[:, None, None]
    disc = (
        st * (phi.cos()[None, :, None] * t + phi.sin()[None, :, None] * b)
        + s[:, None, None] * centre
    )
    disc = disc.reshape(-1, 3)  # (D, 3)
    spread = math.sqrt(float((torch.arccos((disc @ centre).clamp(-1, 1)) ** 2).mean()))
    # views over the highlight: mirror directions of the centre, offset up to 3 disc radii
    mirror = 2 * (centre @ n) * n - centre
    g = torch.linspace(-3 * radius, 3 * radius, 25, dtype=torch.float64)
    tm, bm, _ = sphere.frame(mirror)
    gx, gy = torch.meshgrid(g, g, indexing="ij")
    views = torch.nn.functional.normalize(
        mirror + gx.reshape(-1, 1) * tm + gy.reshape(-1, 1) * bm, dim=-1
    )  # (W, 3)
    spec = spec.to(dtype=torch.float64)

    def f_cos(model, lights, vs):  # (W, L) f(l, v) max(n.l, 0)
        wi = lights[None].expand(vs.shape[0], -1, 3)
        wo = vs[:, None].expand_as(wi)
        return model.eval(wi, wo, n.expand_as(wi)).mean(-1) * (wi @ n).clamp_min(0)

    truth = f_cos(spec, disc, views).mean(1)  # the disc's average, (W,)
    point = f_cos(spec, centre[None], views)[:, 0]
    wide = f_cos(sun_widened(spec, spread), centre[None], views)[:, 0]

    def rel(x):
        return float((x - truth).norm() / truth.norm())

    # measured: point 0.20-0.65, widened 0.04-0.12 (GGX's long tail fits the sum of variances
    # least well); light kept to 2 %
    assert rel(wide) < 0.15
    assert rel(wide) < 0.6 * rel(point)
    assert float(wide.sum() / truth.sum()) == pytest.approx(1.0, abs=0.03)
    assert sun_widened(spec, 0.0) is spec
