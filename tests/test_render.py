"""The renderer: shaders against the torch path, view interpolation, lighting rotation."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from lobelight import envmap, fit, render, scene
from lobelight.errors import InputError
from lobelight.geometry import sphere
from lobelight.lobes import sg, sh
from lobelight.model import Model
from lobelight.render._gl import gl_available

needs_gl = pytest.mark.skipif(not gl_available(), reason="no headless OpenGL context (EGL)")


def synthetic_model(subdivisions: int = 2) -> Model:
    """A sphere whose transport is two analytic Gaussians per view (no fitting: fast): a
    glossy lobe about the mirror direction and a broad one about the normal, weights zero
    below the horizon, as a fitted model has them."""
    sc = scene.builtin("sphere", subdivisions=subdivisions)
    n = sc.mesh.normals  # (V, 3)
    views = sphere.geodesic_views()  # (J, 3)
    cos = n @ views.T  # (V, J)
    refl = 2 * cos[..., None] * n[:, None] - views[None]  # (V, J, 3)
    mu = torch.stack([refl, n[:, None].expand_as(refl)], 2)  # (V, J, 2, 3)
    lam = torch.tensor([300.0, 3.0]).expand(*cos.shape, 2).clone()
    up = (cos > 0).float()[..., None, None]
    w = torch.tensor([[0.9, 0.8, 0.6], [0.05, 0.1, 0.2]]) * up * (lam[..., None] / 6.3)
    diffuse = torch.zeros(n.shape[0], 25, 3)
    diffuse[:, 0] = 0.2
    diffuse[:, 1:4] = 0.1 * n[:, [1, 2, 0], None]
    g = fit.Gaussians(w.contiguous(), torch.nn.functional.normalize(mu, dim=-1), lam)
    return Model(sc.mesh, views, g, diffuse, sc.materials, {"scene": "synthetic"})


@pytest.fixture(scope="module")
def model2():
    return synthetic_model()


@pytest.fixture(scope="module")
def small_env():
    # the built-in sky made at 64 x 128 (its sun splatted exactly at any size), not made at 512
    # and averaged down: the same sky for these tests, without seconds of resampling
    return envmap.builtin(height=64)


@pytest.fixture(scope="module")
def lighting(small_env):
    return render.Lighting(small_env, base_res=64)


CAM = render.Camera.look_at((0.4, 1.8, 3.2), (0.0, 0.1, 0.0), fov=38)


def test_transport_at_stored_views_is_the_stored_record(model2):
    m = model2
    views = sphere.geodesic_views()
    vid = torch.arange(m.mesh.n_vertices).repeat_interleave(92)
    vd = views.repeat(m.mesh.n_vertices, 1)
    g = m.transport(vid, vd)
    ref = m.gaussians
    # at a view, its barycentric is 1 up to float32 rounding (~1e-7 of the neighbours' values)
    atol = 1e-6 * float(ref.w.max())
    torch.testing.assert_close(g.w, ref.w.reshape(-1, 2, 3), rtol=1e-5, atol=atol)
    # a lobe's shape is weighted by the light it carries, so where the record carries none
    # (below the horizon) its neighbours' (at ~1e-7 weight) decide it: compare live lobes
    live = ref.w.reshape(-1, 2, 3).amax(-1) > 0
    assert 0.3 < float(live.float().mean()) < 0.7
    torch.testing.assert_close(g.lam[live], ref.lam.reshape(-1, 2)[live], rtol=1e-4, atol=0)
    torch.testing.assert_close(g.mu[live], ref.mu.reshape(-1, 2, 3)[live], rtol=0, atol=1e-5)


def test_transport_is_continuous_across_view_triangles(model2):
    # two directions a hair apart on either side of a geodesic edge give the same Gaussians:
    # the opposite corner's weight vanishes on the edge in both triangles
    views = sphere.geodesic_views(dtype=torch.float64)
    e = sphere.geodesic_edges()[:20]
    mid = torch.nn.functional.normalize(views[e[:, 0]] + views[e[:, 1]], dim=-1)
    side = torch.nn.functional.normalize(torch.linalg.cross(views[e[:, 0]], views[e[:, 1]]), dim=-1)
    a = (mid + 1e-6 * side).float()
    b = (mid - 1e-6 * side).float()
    # for each edge, the vertex facing it, so that its lobes carry light there
    vid = (model2.mesh.normals @ mid.float().T).argmax(0)
    ga, gb = model2.transport(vid, a), model2.transport(vid, b)
    # the change is of the order of the offset (1e-6) times the values: no jump
    atol = 1e-5 * float(model2.gaussians.w.max())
    torch.testing.assert_close(ga.w, gb.w, rtol=0, atol=atol)
    # widths of lobes carrying light (a lobe without light has a placeholder width)
    live = (ga.w.amax(-1) > 0) & (gb.w.amax(-1) > 0)
    assert int(live.sum()) >= 30
    torch.testing.assert_close(ga.lam[live], gb.lam[live], rtol=1e-4, atol=0)
    torch.testing.assert_close(ga.mu[live], gb.mu[live], rtol=0, atol=1e-4)
    # while moving to a corner view turns the mirror lobes' means: the test can fail
    far = model2.transport(vid, views[e[:, 0]].float())
    assert float((far.mu - ga.mu)[live].abs().max()) > 1e-2


def dead_slot_model() -> Model:
    """The synthetic sphere with slot 0 alive (a sharp mirror lobe) at even views only; at odd
    views it is dead (weight 0) with a broad placeholder width, as a fit with two Gaussians
    leaves unused slots. Blending peak weights and widths independently spreads the sharp
    lobe's peak (~500) over the broad width there: the carried light grows ~100x."""
    m = synthetic_model()
    g = m.gaussians
    w, lam = g.w.clone(), g.lam.clone()
    lam[..., 0] = 3000.0
    w[..., 0, :] = torch.tensor([0.5, 0.4, 0.3]) * (3000.0 / (2 * math.pi)) * (w[..., 0, :1] > 0)
    odd = torch.arange(92) % 2 == 1
    w[:, odd, 0] = 0.0
    lam[:, odd, 0] = 2.0
    return Model(m.mesh, m.views, fit.Gaussians(w, g.mu, lam), m.diffuse, m.materials, {})


def test_interpolation_conserves_the_light_each_lobe_carries():
    m = dead_slot_model()
    gen = torch.Generator().manual_seed(3)
    vid = torch.randint(0, m.mesh.n_vertices, (4000,), generator=gen)
    vd = torch.nn.functional.normalize(torch.randn(4000, 3, generator=gen), dim=-1)
    g = m.transport(vid, vd)
    got = g.w * sg.integral(g.lam)[..., None]  # (P, 2, 3)
    # the barycentric blend of the stored records' light, averaged over the records above the
    # vertex's horizon (the others have no data), computed here independently
    idx, bary = sphere.locate_views(vd)
    rec = m.gaussians.w * sg.integral(m.gaussians.lam)[..., None]  # (V, J, 2, 3)
    above = torch.einsum("pcx,px->pc", m.views[idx], m.mesh.normals[vid]) > 0
    say = torch.where((vd * m.mesh.normals[vid]).sum(-1) > 0, (bary * above).sum(1), 1.0)
    want = (rec[vid[:, None], idx] * bary[..., None, None]).sum(1) / say[:, None, None]
    # float32 quotients and products of ~1e3 and ~1e-3: a few ulps
    torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-7)
    # the test can fail: blending the peak weights with the widths breaks it by far
    pw = (m.gaussians.w[vid[:, None], idx] * bary[..., None, None]).sum(1)
    ps = (m.gaussians.lam[vid[:, None], idx].rsqrt() * bary[..., None]).sum(1)
    old = pw * sg.integral(ps.pow(-2))[..., None]
    assert float(old.sum() / want.sum()) > 10
    # where every record carries light the shape is the plain blend of the live records
    both = (rec[vid[:, None], idx, 0].amax(-1) > 0).all(-1)
    assert int(both.sum()) > 0
    torch.testing.assert_close(
        g.lam[both, 0], torch.full_like(g.lam[both, 0], 3000.0), rtol=1e-4, atol=0
    )


def test_views_below_the_horizon_do_not_darken_the_blend():
    # every record above a vertex's horizon carries the same light, those below none (no data,
    # as a fit leaves them): at any view above the horizon the blend must carry that light
    # exactly, also where the view's triangle has corners below (counted as dark, they left
    # 64 % of it on average at n.v < 0.1, 84 % at 0.1-0.2)
    m = synthetic_model()
    g = m.gaussians
    # above the horizon as the fit decides it (views at n.v = +-1e-17 lie on the sphere's
    # horizon: a matrix product would round some of them to the other side)
    up = ((m.views[None] * m.mesh.normals[:, None]).sum(-1) > 0)[..., None]  # (V, J, 1)
    lam = torch.full_like(g.lam, 50.0)
    w = (up / sg.integral(lam))[..., None].expand(-1, -1, 2, 3).contiguous()
    flat = Model(m.mesh, m.views, fit.Gaussians(w, g.mu, lam), m.diffuse, m.materials, {})
    gen = torch.Generator().manual_seed(5)
    vid = torch.randint(0, m.mesh.n_vertices, (4000,), generator=gen)
    vd = torch.nn.functional.normalize(torch.randn(4000, 3, generator=gen), dim=-1)
    cos = (vd * m.mesh.normals[vid]).sum(-1)
    near = (cos > 0) & (cos < 0.3)
    assert int(near.sum()) > 100
    got = flat.transport(vid, vd)
    e = (got.w * sg.integral(got.lam)[..., None])[..., 0]  # (P, 2)
    # above the horizon (where a corner always is) the light is 1 to float32 rounding
    idx, bary = sphere.locate_views(vd)
    corner_up = torch.einsum("pcx,px->pc", m.views[idx], m.mesh.normals[vid]) > 0
    assert bool(corner_up[cos > 0].any(1).all())
    up = cos > 0
    torch.testing.assert_close(e[up], torch.ones_like(e[up]), rtol=1e-5, atol=0)
    # the test can fail: counted as dark, the corners below leave the plain blend's light
    plain = (bary * corner_up).sum(1)
    assert float(plain[near].min()) < 0.7


def test_evaluate_sums_the_interpolated_gaussians(model2):
    d = sphere.fibonacci(50)[0]
    vid = torch.tensor([3, 7])
    vd = torch.nn.functional.normalize(torch.tensor([[0.2, 0.9, 0.3], [-0.5, 0.5, 0.7]]), dim=-1)
    g = model2.transport(vid, vd)
    got = model2.evaluate(vid, vd, d.expand(2, 50, 3))
    want = sum(
        sg.evaluate(d[None], g.mu[:, None, k], g.lam[:, None, k])[..., None] * g.w[:, None, k]
        for k in range(2)
    )
    torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-7)


@needs_gl
@pytest.mark.parametrize(("rotation", "dead"), [(None, False), (65.0, False), (None, True)])
def test_shaders_match_the_torch_path(model2, lighting, rotation, dead):
    # the bound: <= 1e-3 relative on sampled pixels. Both paths do the same float32
    # arithmetic in a different order; the rasteriser's barycentrics and the ray's differ by
    # rounding only, so the expected gap is ~1e-5. With dead slots the live-record rule of
    # blend_lobes (per pixel: premultiplied varyings) is exercised too
    if dead:
        model2 = dead_slot_model()
    w, h = 96, 72
    gl = render.Renderer(model2, lighting, w, h, backend="gl")
    img, mask = gl.render(CAM, rotation, return_mask=True)
    gl.close()
    gen = torch.Generator().manual_seed(1)
    rows, cols = mask.nonzero().unbind(-1)
    pick = torch.randperm(rows.numel(), generator=gen)[:400]
    px = torch.stack([rows[pick], cols[pick]], -1)
    tr = render.Renderer(model2, lighting, w, h, backend="torch")
    ref, hit = tr.render_pixels(CAM, px, rotation)
    assert bool(hit.all())
    got = img[px[:, 0], px[:, 1]]
    rel = (got - ref).abs().amax(-1) / ref.amax(-1).clamp_min(1e-6)
    assert float(rel.max()) <= 1e-3
    # the whole coverage agrees except where a pixel centre grazes a silhouette
    full, full_mask = tr.render(CAM, rotation, return_mask=True)
    assert int((full_mask != mask).sum()) <= 2
    # parts add up to the whole
    d = tr.render(CAM, rotation, glossy=False, background=False)
    s = tr.render(CAM, rotation, diffuse=False, background=False)
    torch.testing.assert_close((d + s)[full_mask], full[full_mask], rtol=1e-5, atol=1e-6)


def test_the_interreflected_transfer_sees_the_sun(model2, small_env):
    # a bounce transfer is lit by the map without the sun (inside ``diffuse``) and by the sun
    # alone, a point of irradiance E at R s: ``bounce . E Y(R s)``; the shader agrees
    lighting = render.Lighting(small_env, base_res=64, sun=True)
    assert lighting.sun is not None
    bounce = torch.zeros_like(model2.diffuse)
    bounce[:, 0] = 0.05
    bounce[:, 1:4] = 0.02 * model2.mesh.normals[:, [1, 2, 0], None]
    mb = dataclasses.replace(model2, bounce=bounce)
    rot = render.as_rotation(30.0)
    vd0 = render._torch.vertex_stage(model2, lighting, CAM.origin, rot)
    vd1 = render._torch.vertex_stage(mb, lighting, CAM.origin, rot)
    y = sh.basis((rot @ lighting.sun.direction.float())[None], 5)[0]  # (25,)
    want = (bounce * (y[:, None] * lighting.sun.irradiance.float()[None])).sum(-2)
    assert float(want.abs().max()) > 1e-3
    torch.testing.assert_close(vd1.diffuse - vd0.diffuse, want, rtol=1e-4, atol=1e-6)
    if not gl_available():
        return
    # the bounce's share of each pixel (the sun's direct light, by a shadow map in GL and by
    # rays in torch, differs at shadow edges and cancels here)
    w, h = 64, 48

    def share(backend, px=None):
        out = []
        for m in (mb, model2):
            r = render.Renderer(m, lighting, w, h, backend=backend, samples=1)
            if px is None:
                img, mask = r.render(CAM, rot, return_mask=True, glossy=False)
                out.append((img, mask))
            else:
                out.append(r.render_pixels(CAM, px, rot, glossy=False))
            r.close()
        return out

    (img_b, mask), (img_0, _) = share("gl")
    rows, cols = mask.nonzero().unbind(-1)
    px = torch.stack([rows[::7], cols[::7]], -1)
    (ref_b, hit), (ref_0, _) = share("torch", px)
    got = (img_b - img_0)[px[:, 0], px[:, 1]][hit]  # a pixel centre grazing a silhouette may miss
    ref = (ref_b - ref_0)[hit]
    assert int(hit.sum()) > 0.9 * hit.numel()
    torch.testing.assert_close(got, ref, rtol=1e-3, atol=1e-5)


def test_constant_environment_gives_the_lobe_integrals(model2, monkeypatch):
    # under L = 1 the glossy part at a vertex is sum_k w_k 2 pi / lam_k (1 - e^{-2 lam_k})
    # exactly and the diffuse part is sqrt(4 pi) times the transfer's first coefficient: the
    # Gaussians' integration, without the lobe visibility correction's factor on their light
    # (tests/test_lobe_visibility.py)
    monkeypatch.setattr(render._torch, "lobe_visibility_applies", lambda model: False)
    env = envmap.EnvMap(torch.ones(6, 16, 16, 3), layout="cubemap", name="white")
    light = render.Lighting(env, base_res=16)
    m = model2
    vd = render._torch.vertex_stage(m, light, CAM.origin, torch.eye(3))
    faces = m.mesh.faces
    tri = torch.arange(faces.shape[0])
    bary = torch.zeros(tri.shape[0], 3)
    bary[:, 0] = 1.0  # at the first corner: exactly the vertex's Gaussians
    got = render._torch.pixel_stage(m, light, vd, tri, bary, torch.eye(3), diffuse=False)
    view = torch.nn.functional.normalize(torch.tensor(CAM.origin) - m.mesh.vertices, dim=-1)
    g = m.transport(torch.arange(m.mesh.n_vertices), view)
    want = (g.w * sg.integral(g.lam)[..., None]).sum(1)[faces[:, 0]]
    torch.testing.assert_close(got, want, rtol=2e-4, atol=1e-6)
    dif = render._torch.pixel_stage(m, light, vd, tri, bary, torch.eye(3), glossy=False)
    want_d = m.diffuse[faces[:, 0], 0] * math.sqrt(4 * math.pi)
    torch.testing.assert_close(dif, want_d, rtol=1e-4, atol=1e-6)


def test_rotating_the_light_equals_rendering_a_rotated_map(model2, small_env, lighting):
    # rotating means (never re-prefiltering) against prefiltering the rotated map itself: the
    # rotated map is resampled (bilinear), so agreement is to the prefilter's accuracy on
    # smooth lighting (a few 1e-2 at worst near the sun's edge; the mean far less)
    rot = render.as_rotation(40.0)
    a = render.Renderer(model2, lighting, 64, 48, backend="torch")
    rotated = render.Lighting(small_env.rotate(rot), base_res=64)
    b = render.Renderer(model2, rotated, 64, 48, backend="torch")
    ia, ma = a.render(CAM, rot, background=False, return_mask=True)
    ib = b.render(CAM, None, background=False)
    rel = (ia[ma] - ib[ma]).norm(dim=-1) / ib[ma].norm(dim=-1)
    assert float(rel.mean()) < 0.02
    # and it is not the identity: the unrotated render differs a lot
    i0 = a.render(CAM, None, background=False)
    assert float(((i0[ma] - ib[ma]).norm(dim=-1) / ib[ma].norm(dim=-1)).mean()) > 0.1


@pytest.mark.parametrize("order", [1, 3, 5, 8])
def test_fast_sh_rotation_equals_sh_rotate(order):
    # the per-frame rotation (monomials at the rule's nodes) against the library's rotation
    # matrix; both are exact, so only float64 rounding separates them
    from scipy.spatial.transform import Rotation

    from lobelight.lobes import sh

    c = torch.randn(
        order * order, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(order)
    )
    rot = sh.Rotator(c)
    for k in range(4):
        r = torch.tensor(Rotation.random(random_state=k).as_matrix())
        ref = sh.rotate(c, r)
        assert float((rot.rotate(r) - ref).abs().max()) < 1e-10 * float(ref.abs().max())


def test_bad_inputs(model2, lighting):
    with pytest.raises(InputError, match="backend"):
        render.Renderer(model2, lighting, 8, 8, backend="vulkan")
    with pytest.raises(InputError, match="env"):
        render.Renderer(model2, "sky.hdr", 8, 8, backend="torch")
    other = render.Lighting(lighting.env, sh_order=3, prefiltered=lighting.prefiltered)
    with pytest.raises(InputError, match="SH"):
        render.Renderer(model2, other, 8, 8, backend="torch")
    with pytest.raises(InputError, match="rotation"):
        render.as_rotation(torch.eye(3) * 2)
    with pytest.raises(InputError, match="resolution"):
        render.Renderer(model2, lighting, 0, 8, backend="torch")


def test_tonemap_and_image_files(tmp_path):
    img = torch.rand(5, 7, 3) * 4
    out = render.tonemap(img, exposure=-1, curve="aces")
    assert out.dtype.name == "uint8" and out.shape == (5, 7, 3)
    assert render.tonemap(torch.zeros(1, 1, 3), curve="srgb")[0, 0, 0] == 0
    assert render.tonemap(torch.ones(1, 1, 3), curve="srgb")[0, 0, 0] == 255
    # 0.5 linear is 0.7354 in sRGB
    assert abs(int(render.tonemap(torch.full((1, 1, 3), 0.5), curve="srgb")[0, 0, 0]) - 188) <= 1
    for ext in ("png", "jpg", "exr", "hdr"):
        p = render.save_image(tmp_path / f"a.{ext}", img)
        assert p.stat().st_size > 0
    with pytest.raises(InputError, match="unsupported"):
        render.save_image(tmp_path / "a.bmp", img)
    assert not list(tmp_path.glob(".*tmp*"))


def test_mirror_frame_follows_the_reflection_inside_a_triangle():
    # three corners whose lobe sits exactly on their own mirror directions (offsets 0): at any
    # point the blended mean is the point's mirror direction, while blending the corners'
    # means directly lands degrees away when their mirror directions differ by ~60 deg (the
    # default knot's triangles); and a corner's own lobe comes back exactly at the corner
    from lobelight.model import blend_lobes
    from lobelight.render._torch import mirror_direction

    gen = torch.Generator().manual_seed(5)
    normals = torch.nn.functional.normalize(
        torch.tensor([[0.0, 0.0, 1.0]]) + 0.6 * torch.randn(200, 3, 3, generator=gen), dim=-1
    )  # (P, 3 corners, 3)
    view = torch.nn.functional.normalize(torch.tensor([0.2, 0.1, 1.0]), dim=0).expand(200, 3, 3)
    base = mirror_direction(normals, view)  # (P, 3, 3)
    b = torch.rand(200, 3, generator=gen)
    b = b / b.sum(-1, keepdim=True)
    target = mirror_direction((normals * b[..., None]).sum(1), view[:, 0])  # (P, 3)
    e = torch.ones(200, 3, 1, 3)
    mu = base[:, :, None]  # (P, 3, 1, 3)
    sigma = torch.full((200, 3, 1), 0.05)
    _, got, _ = blend_lobes(e, mu, sigma, b, frame=(base, target))
    torch.testing.assert_close(got[:, 0], target, rtol=0, atol=1e-5)
    _, plain, _ = blend_lobes(e, mu, sigma, b)
    off = torch.rad2deg(torch.arccos((plain[:, 0] * target).sum(-1).clamp(max=1)))
    assert float(off.max()) > 2.0  # the test can fail: the plain blend is off by degrees
    corner = torch.zeros(200, 3)
    corner[:, 1] = 1.0
    _, at, _ = blend_lobes(e, mu, sigma, corner, frame=(base, base[:, 1]))
    torch.testing.assert_close(at[:, 0], base[:, 1], rtol=0, atol=1e-5)


def test_tile_atlas_puts_each_vertex_tile_at_its_place():
    # vertex v's tile sits at texel (v % per_row, v // per_row) * R, the shader's addressing
    # (reflection.glsl tile_footprint); the rest of the last row is zeros; a dtype converts
    from lobelight.render._gl import _tile_atlas

    r, per_row = 4, 3
    for v in (1, 3, 7):
        tiles = torch.arange(v * r * r, dtype=torch.int32).reshape(v, r, r).numpy() + 1
        atlas = _tile_atlas(tiles, per_row, np.float32)
        assert atlas.dtype == np.float32 and atlas.flags.c_contiguous
        assert atlas.shape == (-(-v // per_row) * r, per_row * r)
        placed = np.zeros(atlas.shape, bool)
        for i in range(v):
            y, x = (i // per_row) * r, (i % per_row) * r
            assert (atlas[y : y + r, x : x + r] == tiles[i]).all()
            placed[y : y + r, x : x + r] = True
        assert (atlas[~placed] == 0).all()


@needs_gl
@pytest.mark.parametrize("band_bytes", [64 << 10, 4 << 20])
def test_the_records_texture_holds_the_records_in_order(model2, monkeypatch, band_bytes):
    # the records written band by band (many small bands, a partial last one; or one band)
    # read back as gaussian_records' texels in order, zero-padded to the shared width
    from lobelight.render import _gl

    monkeypatch.setattr(_gl, "RECORD_BAND_BYTES", band_bytes)
    table = torch.zeros_like(model2.diffuse[:1])
    width = _gl.transfer_width(model2, table)
    ctx = _gl.create_context()
    try:
        tex = _gl.upload_records(ctx, model2, width)
        got = np.frombuffer(tex.read(), np.float32).reshape(-1, 4)
    finally:
        ctx.release()
    rec = _gl.gaussian_records(model2)
    assert got.shape[0] % width == 0 and got.shape[0] >= rec.shape[0]
    if band_bytes < 1 << 20:
        assert got.shape[0] // width > 1  # several bands
    np.testing.assert_array_equal(got[: rec.shape[0]], rec)
    assert (got[rec.shape[0] :] == 0).all()
    # the record's texels: the light it carries and its width, then its axis and horizon flag
    g = model2.gaussians
    r = rec.reshape(*g.lam.shape, 2, 4)
    np.testing.assert_allclose(r[..., 0, 3], g.lam.rsqrt().numpy(), rtol=1e-6)
    np.testing.assert_array_equal(r[..., 1, :3], g.mu.numpy())
    above = (model2.views[None] * model2.mesh.normals[:, None]).sum(-1) > 0
    above = above[..., None].expand(g.lam.shape).float()
    np.testing.assert_array_equal(r[..., 1, 3], above.numpy())


@needs_gl
def test_the_chain_s_atlas_holds_each_level_s_faces_at_its_place():
    # a chain whose levels shrink (a 32 base, 6 levels): each level's six padded faces side by
    # side in their band, alpha 1 and ones past them; the texture written band by band holds
    # the image, and the layout is the image's
    from lobelight.render import _gl

    pf = envmap.prefilter(torch.rand(6, 32, 32, 3, generator=torch.Generator().manual_seed(3)),
                          base_res=32, cache=False)  # fmt: skip
    img, rows, res = _gl.atlas_image(pf)
    (h, w), rows2, res2 = _gl.atlas_layout(pf)
    assert img.shape == (h, w, 4) and w == 6 * (32 + 2)
    np.testing.assert_array_equal(rows, rows2)
    np.testing.assert_array_equal(res, res2)
    sizes = [int(p.shape[1]) for p in pf.padded]
    assert len(set(sizes)) > 1  # bands of several heights: ones past the narrower ones
    filled = np.zeros(img.shape[:2], bool)
    for y, pad in zip(rows.astype(int), pf.padded, strict=True):
        size = pad.shape[1]
        for f in range(6):
            np.testing.assert_array_equal(img[y : y + size, f * size : (f + 1) * size, :3], pad[f])
        filled[y : y + size, : 6 * size] = True
    assert (img[..., 3] == 1).all() and (img[~filled] == 1).all()
    ctx = _gl.create_context()
    try:
        tex, uniforms = _gl.upload_prefiltered(ctx, pf)
        got = np.frombuffer(tex.read(), np.float32).reshape(h, w, 4)
    finally:
        ctx.release()
    np.testing.assert_array_equal(got, img)
    assert uniforms["atlas_size"] == (float(w), float(h))


def _with_gaussians(model: Model, n: int) -> Model:
    """``model`` with its Gaussians repeated to ``n`` per view (each copy a third of the
    light, so the image stays in range)."""
    g = model.gaussians
    k = -(-n // g.w.shape[2])

    def rep(t):
        return torch.cat([t] * k, 2)[:, :, :n].contiguous()

    g = fit.Gaussians(rep(g.w) * (g.w.shape[2] / n), rep(g.mu), rep(g.lam))
    return Model(model.mesh, model.views, g, model.diffuse, model.materials, {})


@needs_gl
@pytest.mark.parametrize("n", [2, 7])
def test_the_captured_vertex_stage_equals_the_shading_pass_s_own(model2, lighting, monkeypatch, n):
    # the shading pass reads the vertex stage's results captured once per frame (prt.glsl
    # STAGE_PASS, FROM_STAGE); computed in the shading pass itself (the path of a model whose
    # stage one capture cannot hold) the same float32 arithmetic gives the same image, to
    # float32 rounding of the same operations in another program (bound 1e-6 relative to the
    # brightest pixel), with several samples per pixel and up to the largest capture
    from lobelight.render import _gl

    model = _with_gaussians(model2, n)
    images = {}
    for staged in (True, False):
        monkeypatch.setattr(_gl, "stage_fits", lambda m, staged=staged: staged)
        ren = render.Renderer(model, lighting, 64, 48, backend="gl", samples=2)
        assert ren.gl.staged is staged
        images[staged] = ren.render(CAM, 30.0)
        ren.close()
    top = float(images[False].abs().max())
    assert top > 0
    assert float((images[True] - images[False]).abs().max()) <= 1e-6 * top


@needs_gl
def test_a_sharp_model_wider_than_one_capture_is_refused(model2, lighting):
    # eight Gaussians per view: 18 vectors a vertex, over one transform feedback's 64
    # components; a sharp material's reflection reads the capture, so the model is refused by
    # name, where a rough one falls back to the shading pass (test above)
    sharp = scene.uniform(
        {"diffuse": [0.5, 0.5, 0.5], "model": "ggx", "alpha": 0.03, "specular": 0.9},
        model2.mesh.n_vertices,
    )
    wide = _with_gaussians(model2, 8)
    wide.materials = sharp
    with pytest.raises(InputError, match=r"8 Gaussians per view.*at most 7"):
        render.Renderer(wide, lighting, 32, 24, backend="gl")
    rough = _with_gaussians(model2, 8)
    ren = render.Renderer(rough, lighting, 32, 24, backend="gl")
    assert not ren.gl.staged
    ren.close()


@needs_gl
def test_a_read_model_renders_without_its_expansion_or_whole_hit_tiles(tmp_path, lighting):
    """The records texture of a model read from a file is packed from its stored rows
    (:class:`lobelight.model._stored.StoredGaussians`) and its hit atlases laid from its
    texels that hit (:class:`lobelight.model.HitTexels`): the texels of the expanded
    model's records, the frame of the model made whole, and neither the expansion nor the
    whole tiles (the model's largest arrays) ever made."""
    from lobelight import model
    from lobelight.bench.synthetic import synthetic_model
    from lobelight.render import _gl

    path = tmp_path / "m.npz"
    synthetic_model(300, 3, vary=True).save(path)  # a sharp Phong lobe: hit tiles saved
    m = model.load(path)
    width = _gl.transfer_width(m, torch.zeros_like(m.diffuse[:1]))
    ctx = _gl.create_context()
    try:
        got = np.frombuffer(_gl.upload_records(ctx, m, width).read(), np.float32).reshape(-1, 4)
    finally:
        ctx.release()
    cam = CAM
    with render.Renderer(m, lighting, 48, 48, backend="gl", samples=1) as r:
        img, mask = r.render(cam, return_mask=True)
    assert 0.1 < float(mask.float().mean()) < 0.9  # the object and the sky around it
    assert m.gaussians._expanded is None and m._hits is None and m._hit_texels is not None
    want = _gl.gaussian_records(m)  # from the stored rows too
    whole = model.load(path)  # made whole, and its atlases laid from the whole tiles
    whole.gaussians.expanded()
    whole.hits()
    whole._hit_texels = None
    np.testing.assert_array_equal(got[: want.shape[0]], want)
    # the same arithmetic on the same numbers; a vectorised kernel and its scalar tail may
    # round the lobe's integral differently (one float32 rounding)
    np.testing.assert_allclose(want, _gl.gaussian_records(whole), rtol=1e-6, atol=0)
    with render.Renderer(whole, lighting, 48, 48, backend="gl", samples=1) as r:
        torch.testing.assert_close(img, r.render(cam), rtol=1e-5, atol=1e-6)


def test_the_records_of_gaussians_in_any_memory_order_are_the_same(model2):
    """Gaussians whose arrays are not C-ordered (a transposed fit's, say) give the records of
    their C-ordered copy: they are made C-ordered once, not once per band."""
    from lobelight.render import _gl

    g = model2.gaussians
    # the same values, held (J, V, N) in memory and seen as (V, J, N)
    strided = sg.Gaussians(
        *(x.transpose(0, 1).contiguous().transpose(0, 1) for x in (g.w, g.mu, g.lam))
    )
    assert not strided.w.is_contiguous()
    assert strided.contiguous().w.is_contiguous() and g.contiguous().w is g.w
    other = dataclasses.replace(model2, gaussians=strided)
    np.testing.assert_array_equal(_gl.gaussian_records(other), _gl.gaussian_records(model2))
