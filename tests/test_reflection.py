"""The sharp reflection shaded per pixel (lobelight.render._reflection): its tables against
quadrature, its placement against Mitsuba 3, the object seen in it on a concave shape (hit
tiles: what it sees of the object, and where it sees the sky) against Mitsuba 3 and between
the two renderers, and a sun's shape seen
in it against Mitsuba 3 and between the two renderers."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import trimesh

from lobelight import brdf, envmap, render, scene
from lobelight.envmap._envmap import _LatlongCells
from lobelight.errors import InputError
from lobelight.geometry import octahedral, sphere
from lobelight.geometry.adjacency import face_neighbours
from lobelight.geometry.raycast import RayCaster
from lobelight.lobes.sg import Gaussians
from lobelight.model import HitTexels, Model, hit_tiles, load, visibility_tiles
from lobelight.render import _reflection

SHARP = {"diffuse": [0.0, 0.0, 0.0], "model": "ggx", "alpha": 0.03, "specular": [0.9, 0.8, 0.6]}


def test_octahedral_round_trip_and_bilinear_at_texel_centres():
    d = torch.nn.functional.normalize(
        torch.randn(5000, 3, generator=torch.Generator().manual_seed(0)), dim=-1
    )
    torch.testing.assert_close(octahedral.decode(octahedral.encode(d)), d, atol=1e-6, rtol=0)
    res = 8
    tiles = torch.rand(2, res, res, generator=torch.Generator().manual_seed(1))
    centres = octahedral.texel_directions(res)[:, :, 0]  # (R, R, 3)
    got = octahedral.bilinear(tiles, torch.ones(res, res, dtype=torch.long), centres)
    torch.testing.assert_close(got, tiles[1], atol=1e-5, rtol=0)


def test_visibility_tiles_of_a_sphere_are_its_hemispheres():
    # a convex mesh sees the environment exactly above each vertex's horizon: the tile's
    # texels are 1 above it, 0 below, fractional only where the horizon crosses a texel
    mesh = scene.builtin("sphere", subdivisions=2).mesh
    tiles = visibility_tiles(mesh, res=16).float() / 255
    d = octahedral.texel_directions(16)[:, :, 0]  # (R, R, 3)
    cos = torch.einsum("vc,rkc->vrk", mesh.normals, d)
    assert float(tiles[cos > 0.3].min()) == 1.0
    assert float(tiles[cos < -0.3].max()) == 0.0


def test_albedo_table_and_mixture_against_quadrature():
    # the table by stratified importance sampling against a midpoint quadrature of f cos over
    # the hemisphere (independent of the sampler); the mixture's light sums to one
    spec = brdf.GGX(alpha=0.05, specular=torch.tensor([0.9, 0.8, 0.6]))
    sr = brdf.sharp_lobe(spec)
    assert sr is not None
    assert abs(float(sr.weights.sum()) - 1) < 1e-6 and bool((sr.weights >= 0).all())
    # polar coordinates about each view's mirror direction, rings dense near it: the lobe,
    # a few degrees wide, spans hundreds of rings and all 256 azimuths
    n_th, n_ph = 3000, 256
    u = (torch.arange(n_th, dtype=torch.float64) + 0.5) / n_th
    th, dth = math.pi * u**2, 2 * math.pi * u / n_th  # theta = pi u^2
    ph = (torch.arange(n_ph, dtype=torch.float64) + 0.5) / n_ph * (2 * math.pi)
    t, p = torch.meshgrid(th, ph, indexing="ij")
    local = torch.stack([t.sin() * p.cos(), t.sin() * p.sin(), t.cos()], -1).reshape(-1, 3)
    dw = (t.sin() * dth[:, None] * (2 * math.pi / n_ph)).reshape(-1)
    s64 = spec.to("cpu", torch.float64)
    n = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    for nv in (0.2, 0.6, 0.95):
        wo = torch.tensor([math.sqrt(1 - nv * nv), 0.0, nv], dtype=torch.float64)
        r = 2 * nv * n - wo  # the mirror direction, and a frame about it
        e1 = torch.nn.functional.normalize(
            torch.linalg.cross(r, torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)), dim=0
        )
        e2 = torch.linalg.cross(r, e1)
        w = local[:, :1] * e1 + local[:, 1:2] * e2 + local[:, 2:] * r
        f = s64.eval(w, wo.expand_as(w), n.expand_as(w))  # 0 below the horizon
        want = (f * (w[:, 2].clamp_min(0) * dw)[:, None]).sum(0)
        got = sr.directional_albedo(torch.tensor(nv)).double()
        # sampling error of 4096 stratified samples, and the table's linear interpolation
        torch.testing.assert_close(got, want, rtol=0.01, atol=0)


def test_only_sharp_lobes_are_shaded_per_pixel():
    assert brdf.sharp_lobe(brdf.GGX(alpha=0.03, specular=0.9)) is not None
    assert brdf.sharp_lobe(brdf.GGX(alpha=0.25, specular=0.9)) is None
    per_vertex = brdf.GGX(alpha=torch.full((10,), 0.03), specular=0.9)
    assert brdf.sharp_lobe(per_vertex) is None
    assert brdf.sharp_lobe(None) is None
    # a glTF lobe varying per vertex: per pixel at its sharp vertices (half-maximum
    # sharpness >= SHARP_LAM: alpha up to about 0.064), None where none is sharp
    alpha = torch.tensor([0.001, 0.01, 0.06, 0.07, 0.3])
    lobe = brdf.sharp_lobe(brdf.GGXSchlick(alpha=alpha, f0=0.9))
    assert lobe.sharp.tolist() == [True, True, True, False, False]
    assert brdf.sharp_lobe(brdf.GGXSchlick(alpha=torch.full((5,), 0.1))) is None
    assert brdf.sharp_lobe(brdf.GGXSchlick(alpha=alpha, f0=0.9), per_vertex=False) is None
    # its sharpness scales as 1 / alpha^2 from the lobe measured at one roughness: against
    # each vertex's own measurement (the profile's self-similarity: sharpness within 1 %,
    # shares of light within 0.005)
    for i in (1, 2):
        own = brdf.sharp_lobe(brdf.GGXSchlick(alpha=float(alpha[i]), f0=0.9))
        torch.testing.assert_close(lobe.lam[i], own.lam, rtol=0.01, atol=0)
        torch.testing.assert_close(lobe.weights, own.weights, rtol=0, atol=5e-3)


def test_a_varying_lobe_s_albedo_against_its_own_quadrature():
    # f0 A + B from the split table at a point, bilinear in log alpha between the table's
    # levels, against the directional albedo integrated for that roughness and F0 alone
    # (the same importance sampling, no split, no interpolation): within 0.3 % where the
    # lobe is shaded per pixel, 1.5 % at alpha 0.2 (a rough hit's lobe), the interpolation's
    # error between levels
    f0 = torch.tensor([0.9, 0.6, 0.04])
    nv = (torch.arange(64) + 0.5) / 64
    for a, tol in ((0.002, 3e-3), (0.0137, 3e-3), (0.05, 3e-3), (0.2, 1.5e-2)):
        alpha = torch.tensor([a, 0.01])  # a sharp second vertex: the lobe exists
        lobe = brdf.sharp_lobe(brdf.GGXSchlick(alpha=alpha, f0=f0.expand(2, 3)))
        corners = torch.zeros(64, 3, dtype=torch.long)
        got = lobe.at(corners, torch.tensor([[1.0, 0.0, 0.0]]).expand(64, 3)).directional_albedo(nv)
        own = brdf.sharp_lobe(brdf.GGXSchlick(alpha=a, f0=f0.tolist()))
        want = own.directional_albedo(nv) if own is not None else _table(a, f0)
        assert float(((got - want).abs() / want).max()) < tol, a


def _table(alpha: float, f0: torch.Tensor) -> torch.Tensor:
    from lobelight.brdf._sharp import _albedo_table

    return _albedo_table(brdf.GGXSchlick(alpha=alpha, f0=f0.tolist()).to("cpu", torch.float64))


def _step_sky(height: int = 256) -> envmap.EnvMap:
    """Bright above an elevation of 20 degrees, dark below: a sharp edge to reflect."""
    rows = (torch.arange(height) + 0.5) / height * math.pi  # polar angle from +y
    bright = rows < math.radians(70.0)
    col = torch.where(
        bright[:, None], torch.tensor([1.0, 0.9, 0.8]), torch.tensor([0.05, 0.05, 0.1])
    )
    return envmap.EnvMap(
        col[:, None, :].expand(height, 2 * height, 3).contiguous(), layout="latlong", name="step"
    )


def _bare_model(sc) -> Model:
    """The scene's mesh and material with no fitted transport: what a renderer shows of it
    is the per-pixel direct reflection alone."""
    v = sc.mesh.n_vertices
    g = Gaussians(
        torch.zeros(v, 92, 1, 3),
        torch.zeros(v, 92, 1, 3) + torch.tensor([0.0, 0.0, 1.0]),
        torch.ones(v, 92, 1),
    )
    return Model(
        sc.mesh, sphere.geodesic_views(), g, torch.zeros(v, 25, 3), sc.materials, {"scene": sc.name}
    )


def _no_hits(m: Model) -> Model:
    """The model with hit tiles that find nothing: the object is never seen in the lobe."""
    face, dist = m.hits()
    m._hits = (torch.full_like(face, -1), torch.zeros_like(dist))
    return m


def _torus() -> scene.Mesh:
    tm = trimesh.creation.torus(
        major_radius=1.0, minor_radius=0.45, major_sections=96, minor_sections=48
    )
    return scene.mesh_from_arrays(tm.vertices, tm.faces, name="torus")


#: A view of the torus from above, its inner side in sight.
TORUS_CAM = render.Camera.look_at((0.0, 2.2, 2.6), (0.0, 0.0, 0.0), fov=45)


def _sharp_torus() -> scene.Scene:
    mesh = _torus()
    return scene.Scene(mesh, scene.uniform(SHARP, mesh.n_vertices), name="torus")


def _mitsuba(sc, env, cam, w, h, tmp_path, spp=256, max_depth=2):
    mi = pytest.importorskip("mitsuba", reason="Mitsuba 3 is the independent reference")
    from lobelight.reference.mitsuba import load_mitsuba, scene_dict

    load_mitsuba()
    path = envmap.save(env, tmp_path / "env.exr")
    d = scene_dict(sc, path, cam, width=w, height=h, spp=spp, max_depth=max_depth, workdir=tmp_path)
    return torch.from_numpy(np.asarray(mi.render(mi.load_dict(d)), dtype=np.float32))


def _ours(sc, env, cam, w, h, *, hits=False):
    light = render.Lighting(env, base_res=256)
    m = _bare_model(sc) if hits else _no_hits(_bare_model(sc))
    with render.Renderer(m, light, w, h, backend="torch", samples=16) as r:
        img, cov = r.render(cam, return_mask="coverage", background=False)
    return img, cov


def _gl_against_torch(m, light, cam, w, h, *, background=True):
    """Both renderers on the GL image's object pixels, one sample each: the torch path's
    radiance there (P, 3) and the GL's largest channel error relative to the torch's largest
    channel (P,)."""
    with render.Renderer(m, light, w, h, backend="gl", samples=1) as r:
        img, mask = r.render(cam, return_mask=True, background=background)
    rows, cols = mask.nonzero().unbind(-1)
    px = torch.stack([rows, cols], -1)
    with render.Renderer(m, light, w, h, backend="torch", samples=1) as r:
        ref, hit = r.render_pixels(cam, px)
    assert bool(hit.all())
    got = img[px[:, 0], px[:, 1]]
    return ref, (got - ref).abs().amax(-1) / ref.amax(-1).clamp_min(1e-6)


def _edge_rows(img: torch.Tensor, cols, lo: int, hi: int) -> list[float]:
    """Per column, the sub-pixel row where the luminance first falls through half-way between
    its values at rows ``lo`` and ``hi``."""
    out = []
    for c in cols:
        y = img[lo:hi, c].mean(-1)
        mid = 0.5 * (float(y[0]) + float(y[-1]))
        i = int(((y[:-1] >= mid) & (y[1:] < mid)).nonzero()[0])
        out.append(lo + i + (float(y[i]) - mid) / (float(y[i]) - float(y[i + 1])))
    return out


@pytest.mark.slow
def test_reflected_edge_lands_where_the_path_tracer_puts_it(tmp_path):
    # a coarse mirror-like sphere (162 vertices: triangles span many pixels) reflecting a sky
    # with a sharp edge: the edge's row in the image, per column, within half a pixel of
    # Mitsuba's (direct light only on a convex shape: nothing else differs; measured within
    # 0.2 pixel, and a pixel is what the eye resolves)
    sc0 = scene.builtin("sphere", subdivisions=2)
    sc = scene.Scene(sc0.mesh, scene.uniform(SHARP, sc0.mesh.n_vertices), name="mirror-sphere")
    env = _step_sky()
    cam = render.Camera.look_at((0.0, 0.0, 3.2), (0.0, 0.0, 0.0), fov=45)
    w = h = 96
    ref = _mitsuba(sc, env, cam, w, h, tmp_path)
    img, _ = _ours(sc, env, cam, w, h)
    cols = range(40, 57, 4)  # columns through the sphere's middle
    lo, hi = 20, 48  # rows from the bright upper reflection down to the dark band
    got, want = _edge_rows(img, cols, lo, hi), _edge_rows(ref, cols, lo, hi)
    assert max(abs(a - b) for a, b in zip(got, want, strict=True)) < 0.5, (got, want)


def test_visibility_tiles_travel_in_the_model_file(tmp_path):
    sc0 = scene.builtin("sphere", subdivisions=1)
    sc = scene.Scene(sc0.mesh, scene.uniform(SHARP, sc0.mesh.n_vertices), name="s")
    m = _bare_model(sc)
    m.save(tmp_path / "m.npz")  # a sharp material's model carries its tiles
    back = load(tmp_path / "m.npz")
    assert back.visibility_held is not None and torch.equal(back.visibility_held, m.visibility())
    # a malformed array is refused, naming the file
    arrays = dict(np.load(tmp_path / "m.npz"))
    arrays["visibility"] = arrays["visibility"][:, :, :5]
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(InputError, match="visibility must be"):
        load(tmp_path / "bad.npz")


@pytest.mark.slow
def test_concave_shape_shows_itself_in_its_reflection(tmp_path):
    # the torus's inner side reflects the torus, which reflects the sky: Mitsuba with one
    # bounce more than direct light (max_depth 3) against ours with a model that carries no
    # fitted light (the mirror's second bounce comes from the hit tiles alone, and they also
    # decide where the lobe sees the sky). Against the same model with hit tiles that find
    # nothing (the sky in every lobe, nothing occluded) the error must fall to at most
    # 1 / 1.8 of it.
    sc, env, cam, w, h = _sharp_torus(), _step_sky(), TORUS_CAM, 96, 96
    ref = _mitsuba(sc, env, cam, w, h, tmp_path, max_depth=3)
    img, cov = _ours(sc, env, cam, w, h, hits=True)
    blind, _ = _ours(sc, env, cam, w, h)
    mask = cov >= 1.0
    err = float((img - ref).abs()[mask].mean() / ref[mask].mean())
    err_blind = float((blind - ref).abs()[mask].mean() / ref[mask].mean())
    # measured 0.026 against 0.084 without the hits (over every object pixel, most of which
    # see the sky alone); what is left is the lobe's mixture, the hits the walk from the
    # tiles' triangles does not reach, and the reference's noise
    assert err < 0.04 and err_blind > 1.8 * err, (err, err_blind)
    # the hit's own reflection blurred by the pixel's lobe (hit_spread): on the pixels it
    # changes, closer to the path tracer than the hit's point shading (measured 0.135 against
    # 0.166 over 533 pixels)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(_reflection, "hit_spread", lambda *args: None)
        point, _ = _ours(sc, env, cam, w, h, hits=True)
    seen = mask & ((img - point).abs().amax(-1) > 1e-6)
    assert int(seen.sum()) > 200
    err_seen = float((img - ref).abs()[seen].mean() / ref[seen].mean())
    err_point = float((point - ref).abs()[seen].mean() / ref[seen].mean())
    assert err_seen < 0.95 * err_point, (err_seen, err_point)


def test_face_curvature_of_a_sphere_is_one_over_its_radius():
    # on a sphere of radius rho the normal is p / rho: the corners' normals turn by the chord
    # over rho, whatever the triangle; a flat triangle (equal normals) has none
    from lobelight.render._reflection import face_curvature

    rho = 2.5
    mesh = scene.builtin("sphere", subdivisions=2).mesh
    pos = mesh.vertices[mesh.faces].double() * rho
    nrm = torch.nn.functional.normalize(pos, dim=-1)
    k = face_curvature(pos, nrm)
    # the builtin sphere's vertices are float32 on the unit sphere: 1e-6 of their rounding
    torch.testing.assert_close(k, torch.full_like(k, 1 / rho), rtol=1e-6, atol=0)
    flat = nrm[:, :1].expand(-1, 3, -1)
    assert float(face_curvature(pos, flat).abs().max()) == 0.0


def test_a_hit_s_reflection_is_blurred_by_the_pixel_s_lobe():
    # hit_spread: the pixel lobe's core variance (1 / (lam n.v) for a microfacet lobe), kept
    # by a flat mirror, grown by (1 + 2 kappa t)^2 by a curved one; and a lookup widened by it
    # is the two Gaussians' convolution (variances add)
    from lobelight.render._reflection import SPREAD_GAUSSIAN, _blurred, hit_spread

    sl = brdf.sharp_lobe(brdf.GGX(alpha=0.03, specular=0.9))
    nv = torch.tensor([1.0, 0.5, 0.5])
    dist = torch.tensor([0.0, 0.0, 2.0])
    kappa = torch.tensor([3.0, 0.0, 0.25])
    got = hit_spread(sl, nv, dist, kappa)
    core = 1 / float(sl.lam[SPREAD_GAUSSIAN])
    torch.testing.assert_close(got, torch.tensor([core, 2 * core, 2 * core * 4]))
    lam = torch.tensor([[100.0, 400.0]])
    torch.testing.assert_close(_blurred(lam, torch.tensor([0.01])), torch.tensor([[50.0, 80.0]]))


def test_hit_tiles_find_the_far_side_of_a_torus():
    # a vertex on the torus's inner equator looks across the hole: the ray towards the axis
    # hits the far side's inner equator at 2 (R - r); a sphere (convex) sees nothing of itself
    mesh = _torus()
    face, dist = hit_tiles(mesh)
    v = int(mesh.vertices.norm(dim=-1).argmin())  # nearest the axis: the inner equator
    p = mesh.vertices[v]
    inward = torch.nn.functional.normalize(-p * torch.tensor([1.0, 1.0, 1.0]), dim=-1)
    texel = int(octahedral.nearest_texel(inward, face.shape[-1]))
    f = int(face[v].reshape(-1)[texel])
    assert f >= 0
    # the texel's centre is within half a texel (~3 degrees) of the axis direction, and the
    # far side is a circle of radius R - r: the distance is 2 (R - r) to a few per cent
    assert abs(float(dist[v].reshape(-1)[texel]) - 2 * 0.55) < 0.03
    hit_point = mesh.vertices[mesh.faces[f]].mean(0)
    assert float(torch.dot(hit_point, p)) < 0  # on the far side
    sph = scene.builtin("sphere", subdivisions=2).mesh
    assert bool((hit_tiles(sph)[0] == -1).all())


@pytest.mark.skipif(not render.gl_available(), reason="needs an OpenGL context")
def test_shaders_match_the_torch_path_where_the_object_sees_itself():
    # a sharp torus whose model carries diffuse light and one indirect Gaussian per view, under
    # a sky with an edge: pixels that see the torus in their lobe are shaded from the hit
    # tiles, in both renderers. The same float32 formulas in a different order: the bound is
    # 1e-3 relative on all but a few pixels, where rounding picks a neighbouring tile texel
    # (measured: none over it on the gallery's teapot without a sun)
    mesh = _torus()
    v = mesh.n_vertices
    gen = torch.Generator().manual_seed(3)
    views = sphere.geodesic_views()
    mu = torch.nn.functional.normalize(torch.randn(v, 92, 2, 3, generator=gen), dim=-1)
    lam = torch.tensor([400.0, 20.0]).expand(v, 92, 2).contiguous()
    w = torch.rand(v, 92, 2, 3, generator=gen) * 0.02 * lam[..., None]
    diffuse = torch.zeros(v, 25, 3)
    diffuse[:, 0] = 0.3
    sc = scene.Scene(mesh, scene.uniform(SHARP, v), name="torus")
    m = Model(mesh, views, Gaussians(w, mu, lam), diffuse, sc.materials, {}, None, 1)
    light = render.Lighting(_step_sky(), base_res=128)
    _, rel = _gl_against_torch(m, light, TORUS_CAM, 80, 80)
    # the scene exercises the hit tiles: many pixels see the torus in their lobe
    face, _ = m.hits()
    assert int((face >= 0).sum()) > 0.05 * face.numel()
    assert float((rel > 1e-3).float().mean()) < 0.01, float(rel.max())


#: A Phong lobe as sharp as the mirror: one Gaussian of the mixture's five carries its light.
PHONG = {"diffuse": [0.2, 0.1, 0.05], "model": "phong", "specular": 0.6, "exponent": 600.0}


def test_shader_defines_name_the_live_gaussians_and_whether_hits_are_found():
    # a Phong lobe is one Gaussian of five, a GGX lobe all five: the shaders' loops run over
    # those alone; HIT_TILES says whether the hits' code is compiled in
    phong = brdf.sharp_lobe(scene.uniform(PHONG, 3).specular)
    ggx = brdf.sharp_lobe(scene.uniform(SHARP, 3).specular)
    d = _reflection.sharp_shader_defines(phong, hit_tiles=False)
    live = [i for i, w in enumerate(phong.weights.tolist()) if w != 0.0]
    assert d["MIXTURE"] == 5 and d["HIT_TILES"] == 0
    assert (d["MIXTURE_LIVE"], d["SHARP_LIVE"]) == (1, str(live[0])) and len(live) == 1
    d = _reflection.sharp_shader_defines(ggx)
    assert (d["MIXTURE_LIVE"], d["SHARP_LIVE"], d["HIT_TILES"]) == (5, "0, 1, 2, 3, 4", 1)


def test_the_sun_s_shape_is_read_where_a_live_gaussian_resolves_it():
    # Phong's mixture carries its light in one Gaussian; the sharper ones, of weight 0, read
    # nothing: a sun that only they would resolve (lam sigma^2 >= SUN_RESOLVED) leaves the
    # shaders' shape lookups out
    phong = brdf.sharp_lobe(scene.uniform(PHONG, 3).specular)
    lam = phong.lam[phong.weights != 0]
    assert lam.numel() == 1 and float(phong.lam.max()) > 2 * float(lam[0])
    between = math.sqrt(_reflection.SUN_RESOLVED / float(lam[0])) * 0.8
    assert float(phong.lam.max()) * between**2 >= _reflection.SUN_RESOLVED
    assert not _reflection.sun_shape_resolved(phong, between)
    assert _reflection.sun_shape_resolved(phong, between / 0.7)


@pytest.mark.skipif(not render.gl_available(), reason="needs an OpenGL context")
@pytest.mark.parametrize("hits", [True, False])
def test_shaders_match_the_torch_path_on_a_phong_lobe(hits):
    # a Phong torus, its mixture one live Gaussian of five (the shaders' loops run over it
    # alone), with its hit tiles (the hits' code compiled in) and without (compiled out): both
    # renderers, one sample, the same float32 formulas; the bound as for the GGX torus above
    mesh = _torus()
    sc = scene.Scene(mesh, scene.uniform(PHONG, mesh.n_vertices), name="torus")
    m = _bare_model(sc) if hits else _no_hits(_bare_model(sc))
    light = render.Lighting(_step_sky(), base_res=128)
    _, rel = _gl_against_torch(m, light, TORUS_CAM, 80, 80, background=False)
    assert float((rel > 1e-3).float().mean()) < 0.01, float(rel.max())
    # each case takes its path: the torus's inner side finds itself in its hit tiles
    face, _ = m.hits()
    assert bool((face >= 0).any()) == hits


def _gltf_torus(alpha: torch.Tensor, f0) -> scene.Scene:
    mesh = _torus()
    v = mesh.n_vertices
    spec = brdf.GGXSchlick(alpha=alpha.expand(v).contiguous(), f0=f0)
    return scene.Scene(mesh, scene.Materials(torch.full((v, 3), 0.2), spec), name="torus")


def _torus_pixels(sc, light, *, backend: str, px=None):
    with render.Renderer(_bare_model(sc), light, 80, 80, backend=backend, samples=1) as r:
        if px is None:
            return r.render(TORUS_CAM, return_mask=True)
        return r.render_pixels(TORUS_CAM, px)


def test_a_lobe_per_vertex_of_one_roughness_renders_as_the_constant_lobe():
    # the torus with a glTF lobe of alpha 0.03 and F0 (0.9, 0.7, 0.5) at every vertex, held
    # per vertex and as one constant: the per-vertex lobe (the mixture measured at alpha
    # 0.03, its sharpness scaled, F0 A + B from the split table) must render what the
    # constant lobe (its own mixture and albedo table) renders, object seen in the lobe
    # included; the bound, 2e-3 relative on 99 % of the pixels, is the two tables' sampling
    # of the same integral (1e-7 apart) and the mixtures' (measured at F0 0.9 and 1: the
    # Fresnel term moves their shares by under 1e-3)
    f0 = [0.9, 0.7, 0.5]
    light = render.Lighting(_step_sky(), base_res=128)
    one = _gltf_torus(torch.tensor(0.03), f0)
    v = one.mesh.n_vertices
    each = _gltf_torus(torch.full((v,), 0.03), torch.tensor(f0).expand(v, 3).contiguous())
    assert brdf.sharp_lobe(each.materials.specular).sharp.all()
    img, mask = _torus_pixels(one, light, backend="torch")
    rows, cols = mask.nonzero().unbind(-1)
    px = torch.stack([rows, cols], -1)
    got, hit = _torus_pixels(each, light, backend="torch", px=px)
    assert bool(hit.all())
    ref = img[rows, cols]
    rel = (got - ref).abs().amax(-1) / ref.amax(-1).clamp_min(1e-6)
    assert float(torch.quantile(rel, 0.99)) < 2e-3, float(rel.max())


def test_shaders_match_the_torch_path_on_a_lobe_varying_per_vertex():
    # a glTF lobe whose roughness runs from a mirror (alpha 0.005) to a rough lobe (0.3)
    # around the torus, and whose F0 varies: pixels at sharp corners shaded per pixel from
    # their sharp corners' blended lobe, the rest by the fitted Gaussians, in the share of
    # their sharp corners, and the hits by their own corners' lobes; the two renderers
    # agree as on the constant lobe (1e-3 relative on all but 1 % of the pixels)
    mesh = _torus()
    x = mesh.vertices[:, 0]
    alpha = 0.005 * (0.3 / 0.005) ** ((x - x.min()) / (x.max() - x.min()))
    f0 = torch.stack([0.9 - 0.5 * (x > 0).float(), torch.full_like(x, 0.7), 0.3 + 0.0 * x], -1)
    sc = _gltf_torus(alpha, f0)
    lobe = brdf.sharp_lobe(sc.materials.specular)
    assert 0.2 < float(lobe.sharp.float().mean()) < 0.8  # both kinds of vertex
    light = render.Lighting(_step_sky(), base_res=128)
    img, mask = _torus_pixels(sc, light, backend="gl")
    rows, cols = mask.nonzero().unbind(-1)
    px = torch.stack([rows, cols], -1)
    ref, hit = _torus_pixels(sc, light, backend="torch", px=px)
    assert bool(hit.all())
    # the bare model's Gaussians carry nothing: the light is the per-pixel lobe's, on the
    # pixels with a sharp corner
    lit = ref.amax(-1) > 1e-3
    assert 0.2 < float(lit.float().mean()) < 0.9
    got = img[rows, cols]
    rel = (got - ref).abs().amax(-1) / ref.amax(-1).clamp_min(1e-6)
    assert float((rel > 1e-3).float().mean()) < 0.01, float(rel.max())


def test_hit_tiles_travel_in_the_model_file(tmp_path):
    # stored as the texels that hit (a few percent of a tile), read back as the whole tiles,
    # bit for bit; the tiles held whole read the same
    mesh = _torus()
    sc = scene.Scene(mesh, scene.uniform(SHARP, mesh.n_vertices), name="t")
    m = _bare_model(sc)
    m.save(tmp_path / "m.npz")
    back = load(tmp_path / "m.npz")
    face, dist = m.hits()
    assert back.hits_held is not None
    assert torch.equal(back.hits_held[0], face)
    assert torch.equal(back.hits_held[1].view(torch.int16), dist.view(torch.int16))
    arrays = dict(np.load(tmp_path / "m.npz"))
    hit = face.reshape(face.shape[0], -1) >= 0
    assert arrays["hit_face"].shape == (int(hit.sum()),) and 0 < hit.float().mean() < 0.5
    assert np.array_equal(arrays["hit_count"], hit.sum(1).numpy())
    whole = dict(arrays, hit_face=face.numpy(), hit_distance=dist.numpy())
    del whole["hit_count"], whole["hit_texel"]
    np.savez(tmp_path / "whole.npz", **whole)
    again = load(tmp_path / "whole.npz").hits_held
    assert torch.equal(again[0], face)
    assert torch.equal(again[1].view(torch.int16), dist.view(torch.int16))

    def refused(match, **change):
        bad = {k: a for k, a in dict(arrays, **change).items() if a is not None}
        np.savez(tmp_path / "bad.npz", **bad)
        with pytest.raises(InputError, match=match):
            load(tmp_path / "bad.npz")

    refused("triangle ids outside", hit_face=arrays["hit_face"] + 10**6)
    refused("triangle ids outside", hit_face=arrays["hit_face"] * 0 - 1)  # -1 is no hit
    refused("together", hit_distance=None)
    refused("together", hit_count=None)
    texel = arrays["hit_texel"].copy()
    texel[[0, 1]] = texel[[1, 0]]  # the first vertex's first two texels swapped
    assert arrays["hit_count"][np.flatnonzero(arrays["hit_count"])[0]] >= 2
    refused("ascend", hit_texel=texel)
    refused("outside 0..1023", hit_texel=arrays["hit_texel"] | np.uint16(1 << 15))
    count = arrays["hit_count"].copy()
    count[np.flatnonzero(count)[0]] += 1
    refused("adding up", hit_count=count)
    refused("need the visibility tiles", visibility=None)
    whole_bad = dict(whole, hit_face=whole["hit_face"] + 10**6)
    np.savez(tmp_path / "whole_bad.npz", **whole_bad)
    with pytest.raises(InputError, match="triangle ids outside"):
        load(tmp_path / "whole_bad.npz")


@pytest.mark.parametrize("width", [16 * 5, 4096])
def test_hit_atlases_hold_the_tiles_that_find_the_object_at_their_slots(tmp_path, width):
    # the shaders read a hit tile at its vertex's slot: slots in vertex order for the vertices
    # whose tile holds a hit, slot s's tile that vertex's own at atlas row s // per_row and
    # column s % per_row (several rows of five tiles, or one row of 4096 texels), misses -1
    # and 0; laid from the model file's texels that hit, without the tiles made whole; a
    # mesh that never sees itself (a sphere) keeps one tile of misses and no slot
    from lobelight.render._gl import hit_atlases

    mesh = _torus()
    m = _bare_model(scene.Scene(mesh, scene.uniform(SHARP, mesh.n_vertices), name="t"))
    face, dist = m.hits()
    m.save(tmp_path / "m.npz")
    back = load(tmp_path / "m.npz")
    slots, fa, da, per_row = hit_atlases(back.hit_texels(), width)
    assert back._hits is None  # the file's texels, not whole tiles
    r = face.shape[-1]
    has = (face.reshape(face.shape[0], -1) >= 0).any(1).numpy()
    assert 0 < has.mean() < 1  # the torus: some vertices see it, some do not
    assert np.array_equal(slots >= 0, has)
    assert np.array_equal(slots[has], np.arange(int(has.sum())))
    assert per_row == min(int(has.sum()), width // r)
    assert fa.shape == da.shape == (-(-int(has.sum()) // per_row) * r, per_row * r)
    placed = np.zeros(fa.shape, bool)
    for v in np.nonzero(has)[0]:
        y, x = (slots[v] // per_row) * r, (slots[v] % per_row) * r
        assert np.array_equal(fa[y : y + r, x : x + r], face[v].numpy())
        assert np.array_equal(
            da[y : y + r, x : x + r].view(np.int16), dist[v].numpy().view(np.int16)
        )
        placed[y : y + r, x : x + r] = True
    assert (fa[~placed] == -1).all() and (da[~placed] == 0).all()
    # the same from whole tiles (a model made in memory)
    again = hit_atlases(m.hit_texels(), width)
    assert all(np.array_equal(a, b) for a, b in zip(again[:3], (slots, fa, da), strict=True))
    ball = scene.builtin("sphere", subdivisions=2).mesh
    slots, fa, da, per_row = hit_atlases(HitTexels.of_tiles(*hit_tiles(ball, res=16)))
    assert (slots == -1).all() and fa.shape == (16, 16) and (fa == -1).all() and per_row == 1


def _softbox(height: int = 256) -> envmap.EnvMap:
    """A dim sky and a uniform rectangle 18 by 5 degrees behind the camera of
    :func:`_softbox_scene`, brighter than the sky by 600 times: a studio's softbox, taken out
    of the map as a sun (its farthest corner within the extraction's 10 degrees)."""
    h, w = height, 2 * height
    dirs = _LatlongCells(h, w).frames()[0].double().reshape(h, w, 3)
    c = torch.nn.functional.normalize(torch.tensor([0.0, 0.25, 1.0], dtype=torch.float64), dim=0)
    ey = torch.nn.functional.normalize(
        torch.linalg.cross(c, torch.tensor([1.0, 0, 0]).double()), dim=0
    )
    ex = torch.linalg.cross(ey, c)
    u, v = torch.atan2(dirs @ ex, dirs @ c), torch.atan2(dirs @ ey, dirs @ c)
    inside = (u.abs() < math.radians(9.0)) & (v.abs() < math.radians(2.5)) & ((dirs @ c) > 0)
    data = torch.full((h, w, 3), 0.5, dtype=torch.float64)
    data[inside] = 300.0
    return envmap.EnvMap(data.float(), layout="latlong", name="softbox")


def _softbox_scene():
    sc0 = scene.builtin("sphere", subdivisions=3)
    sc = scene.Scene(sc0.mesh, scene.uniform(SHARP, sc0.mesh.n_vertices), name="mirror-sphere")
    cam = render.Camera.look_at((0.0, 0.0, 3.2), (0.0, 0.0, 0.0), fov=45)
    return sc, _softbox(), cam


def _spread(img: torch.Tensor, mask: torch.Tensor) -> tuple[float, float]:
    """The RMS width and height in pixels of the brightest part of ``img (H, W, 3)`` on
    ``mask``: luminance above 2 % of its peak (the sky's reflection stays below that)."""
    y = img.mean(-1) * mask
    y = (y - 0.02 * y.max()).clamp_min(0)
    r, c = torch.meshgrid(
        torch.arange(y.shape[0]).float(), torch.arange(y.shape[1]).float(), indexing="ij"
    )
    s = y.sum()
    mr, mc = (y * r).sum() / s, (y * c).sum() / s
    return float(((y * (c - mc) ** 2).sum() / s).sqrt()), float(
        ((y * (r - mr) ** 2).sum() / s).sqrt()
    )


def test_a_sharp_lobe_shows_a_softbox_s_shape_as_the_path_tracer_does(tmp_path):
    # the softbox is taken out as a sun (a disc to the shadows); the sharp lobe reads its
    # shape in the map. Mitsuba, direct light on a convex sphere, sees an elongated highlight
    # (1.7 times as wide as tall); a disc's highlight would be round (measured 1.02) with a
    # relative L1 error of 0.30. Ours: the elongation within 10 % (measured 4 %) and the
    # error under 0.1 (measured 0.065: the mixture's Gaussians against GGX's exact shape)
    sc, env, cam = _softbox_scene()
    w = h = 96
    assert envmap.extract_sun(env)[0] is not None
    ref = _mitsuba(sc, env, cam, w, h, tmp_path)
    light = render.Lighting(env, base_res=256, sun=True)
    with render.Renderer(_no_hits(_bare_model(sc)), light, w, h, backend="torch", samples=16) as r:
        img, cov = r.render(cam, return_mask="coverage", background=False)
    mask = cov >= 1.0
    (wx, wy), (rx, ry) = _spread(img, mask), _spread(ref, mask)
    assert rx / ry > 1.5, (rx, ry)  # the scene shows what it is meant to
    assert abs((wx / wy) / (rx / ry) - 1) < 0.1, (wx, wy, rx, ry)
    err = float((img - ref).abs()[mask].mean() / ref[mask].mean())
    assert err < 0.1, err


@pytest.mark.skipif(not render.gl_available(), reason="needs an OpenGL context")
def test_shaders_match_the_torch_path_on_a_sun_s_shape():
    # the same scene in both renderers, one sample: the sun's shape read from the whole map's
    # chain, its disc and the analytic highlight's tail in the same float32 formulas
    # (measured within 3e-5 relative everywhere; the bound allows rounding at the terminator's
    # shadow test on a few pixels)
    sc, env, cam = _softbox_scene()
    light = render.Lighting(env, base_res=256, sun=True)
    m = _no_hits(_bare_model(sc))
    ref, rel = _gl_against_torch(m, light, cam, 64, 64, background=False)
    assert float(ref.amax()) > 50 * float(ref.median())  # the highlight is in the picture
    assert float((rel > 1e-3).float().mean()) < 0.01, float(rel.max())


def test_a_hit_is_placed_where_the_pixels_ray_meets_the_hit_triangles_plane():
    # a triangle in the plane z = 1 seen from the origin: the ray's own distance to the plane,
    # whatever the tile's; the tile's distance kept for a ray nearly along the plane, one
    # leaving the plane behind it, and one crossing the plane off the triangle (at (4, 0, 1),
    # barycentrics (-0.5, 1.25, 0.25): another triangle is hit there)
    v = torch.tensor([[-1.0, -1.0, 1.0], [3.0, -1.0, 1.0], [-1.0, 3.0, 1.0]])
    mesh = scene.mesh_from_arrays(v, torch.tensor([[0, 1, 2]]), name="tri")
    a = math.radians(30.0)
    r = torch.tensor(
        [
            [0.0, 0.0, 1.0],
            [math.sin(a), 0.0, math.cos(a)],
            [1.0, 0.0, 0.05],
            [0.0, 0.0, -1.0],
            [4.0 / math.sqrt(17.0), 0.0, 1.0 / math.sqrt(17.0)],
        ]
    )
    p = torch.zeros(5, 3)
    tile = torch.full((5,), 0.7)
    t = _reflection._plane_distance(mesh, torch.zeros(5, dtype=torch.long), p, r, tile)
    torch.testing.assert_close(t, torch.tensor([1.0, 1.0 / math.cos(a), 0.7, 0.7, 0.7]))


def test_face_neighbours_match_edges_by_position():
    # a square of two triangles whose shared edge's corners are stored twice (a seam), a
    # boundary everywhere else, and an edge three triangles share (non-manifold): no neighbour
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    assert face_neighbours(v, np.array([[0, 1, 2], [4, 3, 5]])).tolist() == [
        [1, -1, -1],
        [-1, 0, -1],
    ]
    fan = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    v5 = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]], np.float32)
    assert (face_neighbours(v5, fan)[:, 2] == -1).all()  # the edge (0, 1) of all three
    # a closed mesh: every edge has exactly one neighbour across it, and the relation is mutual
    mesh = _torus()
    nb = mesh.face_neighbours
    f = mesh.faces
    assert bool((nb >= 0).all())
    for i in range(3):
        a, b = f[:, (i + 1) % 3], f[:, (i + 2) % 3]
        g = f[nb[:, i]]  # the neighbour holds both corners of the edge
        assert bool(((g == a[:, None]).any(1) & (g == b[:, None]).any(1)).all())
        back = nb[nb[:, i]]
        assert bool((back == torch.arange(f.shape[0])[:, None]).any(1).all())


def test_a_closed_outward_surface_is_told_from_open_inverted_and_split_ones():
    # the torus encloses positive volume with its triangles counter-clockwise from outside; the
    # same triangles wound the other way enclose negative volume; a hole opens it; and a cube
    # whose faces' corners are stored apart (split at every edge, as a flat-shaded mesh) is
    # closed once merged by position (geometry.adjacency.encloses_outward: the web page
    # leaves the triangles seen from behind out only for a closed outward surface)
    from lobelight.geometry.adjacency import encloses_outward

    mesh = _torus()
    v, f = mesh.vertices.numpy(), mesh.faces.numpy()
    assert encloses_outward(v, f)
    assert not encloses_outward(v, f[:, ::-1])
    assert not encloses_outward(v, f[4:])
    box = trimesh.creation.box()
    split = box.vertices[box.faces].reshape(-1, 3)  # three corners per triangle, none shared
    assert encloses_outward(split, np.arange(split.shape[0]).reshape(-1, 3))
    assert not encloses_outward(split, np.zeros((0, 3), np.int64))


@pytest.mark.skipif(not render.gl_available(), reason="needs an OpenGL context")
def test_the_desktop_leaves_out_a_closed_surface_s_triangles_seen_from_behind():
    # the torus is closed and wound outward: the GL renderer draws it without the triangles
    # seen from behind (its cull), and the picture is the same to the bit as with them
    mesh = _torus()
    sc = scene.Scene(mesh, scene.uniform(PHONG, mesh.n_vertices), name="torus")
    light = render.Lighting(_step_sky(), base_res=64, sun=True)
    images = []
    with render.Renderer(_bare_model(sc), light, 96, 72, backend="gl", samples=1) as r:
        gl = r.gl
        assert gl.cull
        for cull in (True, False):
            gl.cull = cull
            images.append(r.render(TORUS_CAM, return_mask=True))
    (a, ma), (b, mb) = images
    assert bool(ma.any()) and bool((ma == mb).all())
    assert float((a - b).abs().max()) == 0.0


def test_a_hit_is_walked_to_the_triangle_the_pixels_ray_meets():
    # rays across the torus's hole from points inside its triangles, each walk started where
    # the renderer starts it: at the triangle a corner's hit tile names for the ray's texel.
    # Where a walk arrives it is at the ray's first hit, as Embree finds it (the same triangle,
    # or the same point on an edge two triangles share); it arrives for nearly every ray that
    # hits (measured 97.4 % in the 8 steps it takes, 99.6 % in 16, 65 % in 4: the rest run out
    # of steps or graze the far side) and for none that misses
    mesh = _torus()
    face, _ = hit_tiles(mesh)
    gen = torch.Generator().manual_seed(5)
    n = 16000
    tri = torch.randint(0, mesh.n_faces, (n,), generator=gen)
    b = torch.rand(n, 3, generator=gen)
    b = b / b.sum(-1, keepdim=True)
    c = mesh.faces[tri]
    p = (mesh.vertices[c] * b[..., None]).sum(1)
    inward = torch.cat([-p[:, :2], torch.zeros_like(p[:, 2:])], -1)
    r = torch.nn.functional.normalize(inward + 0.3 * torch.randn(n, 3, generator=gen), dim=-1)
    texel = octahedral.nearest_texel(r, face.shape[-1])
    start = face.reshape(face.shape[0], -1)[c[:, 0], texel]
    # a reflected ray leaves the surface above its tangent plane
    nrm = torch.nn.functional.normalize((mesh.normals[c] * b[..., None]).sum(1), dim=-1)
    keep = (start >= 0) & ((r * nrm).sum(-1) > 0.2)
    p, r, start = p[keep], r[keep], start[keep]
    assert int(keep.sum()) > 1000
    arrived, g, t = _reflection.walk_to_hit(mesh, mesh.face_neighbours, start, p, r)
    caster = RayCaster(mesh, offset=0.0, engine="embree")
    want_tri, want_t, _ = caster.first_hit(p + 1e-5 * r, r)
    want_t = want_t + 1e-5
    hits = want_tri >= 0
    assert 0 < int((~hits).sum()) and not bool((arrived & ~hits).any())
    assert float(arrived[hits].float().mean()) > 0.95
    a = arrived & hits
    at, want_at = p[a] + t[a, None] * r[a], p[a] + want_t[a, None] * r[a]
    same = (g[a] == want_tri[a]) | ((at - want_at).norm(dim=-1) < 1e-4)
    assert bool(same.all()), float(same.float().mean())
    torch.testing.assert_close(t[a], want_t[a], atol=1e-4, rtol=0)
    # the walk moves most hits off the tile's triangle (measured 94 %): the tile's texel is 6
    # degrees wide, and its ray leaves from the corner, not from the pixel's point
    assert float((g[a] != start[a]).float().mean()) > 0.8


def test_a_corner_that_misses_starts_its_walk_from_its_footprint():
    # one texel of a tile finds triangle 7: a direction whose bilinear footprint holds it
    # starts there, one whose footprint does not finds none; of two texels in the footprint
    # the first in hit_free's reading order wins
    res = 8
    tiles = torch.full((1, res, res), -1, dtype=torch.int32)
    tiles[0, 3, 4] = 7
    centres = octahedral.texel_directions(res)[:, :, 0]  # (R, R, 3): row, column
    at = torch.stack([centres[3, 4], centres[3, 3], centres[2, 4], centres[6, 1]])
    got = _reflection.footprint_face(tiles, torch.zeros(4, dtype=torch.long), at)
    # a texel centre's footprint starts at that texel: (3, 4) itself, and (3, 3) and (2, 4)
    # have (3, 4) as their right and lower neighbours; (6, 1) is far away
    assert got.tolist() == [7, 7, 7, -1]
    tiles[0, 3, 3] = 5  # now first in the footprint of (3, 3), before its neighbour (3, 4)
    got = _reflection.footprint_face(tiles, torch.zeros(1, dtype=torch.long), centres[3, 3][None])
    assert got.tolist() == [5]
