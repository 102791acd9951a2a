"""Indirect glossy transport as its own Gaussian per view, and the sun's light through it.

The indirect Gaussian is the moment estimate of the paths that bounce off the object
(``Transport.indirect_lobes``); a renderer that shades the sun's glossy light per pixel lets the
sun light it (``render._sun_glossy.sun_through``), since the fitted lobes see the map without
the sun. Checked here: for one view the Gaussian keeps its paths' light and points where a
mirror seen in a mirror sends it, and a lone path lies along itself; the sun through a
Gaussian against a quadrature of a disc; rendering with the sun per pixel against rendering
with the sun left in the map; the model file keeps the count. The paths shared across views,
the sharpness cap and the smoothness they buy: tests/test_indirect_sharing.py.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from lobelight import brdf, envmap, fit, model, render, scene, transport
from lobelight.errors import InputError
from lobelight.geometry import cubemap, sphere
from lobelight.lobes import sg
from lobelight.render._gl import gl_available
from lobelight.render._sun_glossy import sun_through
from lobelight.scene import Materials, Scene
from test_interreflection import _corner, _nearest
from test_render import CAM, synthetic_model


def _mirror_corner(alpha: float):
    mesh, r = _corner(9)
    v_n = mesh.n_vertices
    spec = brdf.GGX(alpha=torch.full((v_n,), alpha), specular=torch.full((v_n, 3), 0.9))
    sc = Scene(
        mesh, Materials(torch.zeros(v_n, 3), spec), "builtin", scene.builtin("sphere:0").camera
    )
    return sc, r


def test_the_indirect_gaussian_keeps_the_paths_light_for_one_view():
    # with one view its paths are shared with no other (the balance heuristic over one view's
    # density is the path's own weight): the integral is the paths' throughput sum over their
    # count, the binned density's total for the same paths, to float rounding (the binned
    # density itself is checked against the path tracer in tests/test_interreflection.py)
    sc, r = _mirror_corner(0.3)
    tr = transport.Transport(sc)
    v = torch.tensor(
        [_nearest(sc.mesh, [0.25, 0.0, 0.25], r), _nearest(sc.mesh, [0.5, 0.5, 0.0], r)]
    )
    kw = dict(paths=256)
    for view in sphere.geodesic_views()[::9]:
        g = tr.indirect_lobes(v, view[None], generator=torch.Generator().manual_seed(5), **kw)
        ind = tr.indirect(v, view[None], res=8, generator=torch.Generator().manual_seed(5), **kw)
        binned = (ind * cubemap.texel_solid_angles(8).reshape(-1)[:, None]).sum(2)  # (B, 1, 3)
        carried = (g.w * sg.integral(g.lam)[..., None]).sum(2)
        torch.testing.assert_close(carried, binned, rtol=1e-4, atol=1e-7)
        lo, hi = transport.INDIRECT_LAM_RANGE
        assert bool(((g.lam >= lo) & (g.lam <= hi)).all())
    assert float(binned.amax()) > 0.05  # the walls reflect a real share


def test_the_indirect_gaussian_points_where_a_mirror_in_a_mirror_escapes():
    # a floor vertex seen so that its mirror direction hits the wall x = 0: reflected by the
    # floor (normal +y) and then by that wall (normal +x), the light escapes along (1, 1, 0)
    sc, r = _mirror_corner(0.02)
    tr = transport.Transport(sc)
    v = _nearest(sc.mesh, [0.25, 0.0, 0.25], r)
    view = torch.nn.functional.normalize(r @ torch.tensor([1.0, 1.0, 0.0]), dim=0)
    out = torch.nn.functional.normalize(r @ torch.tensor([1.0, 1.0, 0.0]), dim=0)
    g = tr.indirect_lobes(torch.tensor([v]), view[None], paths=64,
                          generator=torch.Generator().manual_seed(2))  # fmt: skip
    mu, lam = g.mu[0, 0, 0], float(g.lam[0, 0, 0])
    angle = math.degrees(math.acos(min(1.0, float(mu @ out))))
    # two GGX 0.02 reflections spread the light by a few degrees: the lobe is that sharp
    assert angle < 2.0, angle
    assert 100 < lam <= transport.INDIRECT_LAM_RANGE[1], lam
    # nearly all the light goes that way: two reflections of 0.9 (GGX 0.02 loses ~1 % each)
    e = g.w[0, 0, 0] * sg.integral(g.lam[0, 0, 0])
    torch.testing.assert_close(e, torch.full((3,), 0.81), rtol=0.03, atol=0)


@pytest.mark.parametrize("alpha", [0.05, 0.3])
def test_a_lone_path_gets_a_gaussian_along_it_no_sharper_than_its_lobe(alpha):
    # a path that escapes alone tells no width; spread over the sphere it would put its light
    # where the object blocks it and on a sun there. Its Gaussian lies along the path with
    # LONE_PATH_LAM, or the lobe that gathered it where that is wider (GGX 0.3: sharpness ~5),
    # its light the path's: the same paths (same seed) through both calls, one view per call
    # (no sharing across views)
    sc, r = _mirror_corner(alpha)
    tr = transport.Transport(sc)
    v = torch.tensor([_nearest(sc.mesh, p, r) for p in ([0.25, 0.0, 0.25], [0.6, 0.0, 0.1])])
    n_lone = 0
    for view in sphere.geodesic_views()[::7]:
        slot, d, thr = tr.escapes(
            v, view[None], paths=2, generator=torch.Generator().manual_seed(3)
        )
        g = tr.indirect_lobes(v, view[None], paths=2, generator=torch.Generator().manual_seed(3))
        count = torch.bincount(slot, minlength=2)
        lone = (count == 1).nonzero().squeeze(-1)
        n_lone += lone.numel()
        if lone.numel() == 0:
            continue
        k = torch.full((2,), -1, dtype=torch.int64).scatter_reduce(
            0, slot, torch.arange(slot.numel()), "amax"
        )[lone]
        spec = sc.materials.specular.take(v[lone])
        views = view[None].expand(lone.numel(), 3)
        cap = transport.gathering_sharpness(spec, sc.mesh.normals[v[lone]], views)
        want = torch.minimum(torch.full_like(cap, transport.LONE_PATH_LAM), cap)
        lam = g.lam[lone, 0, 0]
        # the cap from the table by elevation, against the lobe's own samples: 3 %
        torch.testing.assert_close(lam, want, rtol=0.03, atol=0)
        torch.testing.assert_close(g.mu[lone, 0, 0], d[k], rtol=0, atol=1e-5)
        e = (g.w * sg.integral(g.lam)[..., None])[lone, 0, 0]
        torch.testing.assert_close(e, thr[k] / 2, rtol=1e-4, atol=1e-7)
        if alpha < 0.1:
            # a sharp lobe keeps the narrow Gaussian: a sun 90 degrees off the path gets
            # exp(-LONE_PATH_LAM) of the lobe's peak, not the ~e^-0.5 of the widest lobe
            assert bool((lam == transport.LONE_PATH_LAM).all())
            other = torch.randn(d[k].shape, generator=torch.Generator().manual_seed(4))
            side = torch.nn.functional.normalize(torch.linalg.cross(d[k], other), dim=-1)
            peak = sg.evaluate(d[k], g.mu[lone, 0, 0], lam)
            assert bool((sg.evaluate(side, g.mu[lone, 0, 0], lam) < 1e-20 * peak).all())
    assert n_lone >= 3, n_lone


@pytest.mark.parametrize("lam", [5.0, 60.0, 600.0])
def test_the_sun_through_a_gaussian_matches_a_disc_quadrature(lam):
    # a uniform disc of radius 2 degrees (RMS angle r / sqrt 2) at several angles from the
    # lobe: against a fine quadrature of the disc, within 2 % of the lobe's peak response
    radius = math.radians(2.0)
    e_sun = torch.tensor([1.0, 2.0, 3.0])
    mu = torch.tensor([0.0, 0.0, 1.0])
    sig = 1.0 / math.sqrt(lam)
    # a local grid over the disc, (t, phi) polar about the sun's axis
    t = (torch.arange(200, dtype=torch.float64) + 0.5) / 200 * radius
    ph = (torch.arange(256, dtype=torch.float64) + 0.5) / 256 * 2 * math.pi
    tt, pp = torch.meshgrid(t, ph, indexing="ij")
    area = torch.sin(tt) * (radius / 200) * (2 * math.pi / 256)
    got, want = [], []
    for off in np.linspace(0, 3 * max(sig, radius), 7):
        s = torch.tensor([math.sin(off), 0.0, math.cos(off)], dtype=torch.float64)
        a = torch.nn.functional.normalize(
            torch.linalg.cross(s, torch.tensor([0, 1.0, 0], dtype=torch.float64)), dim=0
        )
        b = torch.linalg.cross(s, a)
        d = (torch.cos(tt)[..., None] * s + torch.sin(tt)[..., None]
             * (torch.cos(pp)[..., None] * a + torch.sin(pp)[..., None] * b))  # fmt: skip
        g = torch.exp(lam * (d @ mu.double() - 1))
        disc = (g * area).sum() / area.sum()  # the disc's radiance is E / its solid angle
        want.append(float(disc) * e_sun)
        sun = envmap.Sun(s.float(), e_sun, radius, radius / math.sqrt(2))
        carried = sg.integral(torch.tensor(lam))[None].expand(3)  # weight 1
        got.append(sun_through(carried, mu, torch.tensor(lam), s.float(), sun))
    got, want = torch.stack(got), torch.stack(want).float()
    assert float((got - want).abs().max()) <= 0.02 * float(want[0].max()), (got, want)


def _sunny_env() -> envmap.EnvMap:
    # a dim sky with a small, very bright sun: its glossy light through the lobes dominates
    return envmap.builtin(height=64)


def test_indirect_lobes_see_the_sun_when_it_is_shaded_per_pixel(monkeypatch):
    # the sun's light through a model's indirect lobes (its broad lobe declared indirect) when
    # the sun is shaded per pixel and the lookups see the map without it: the image with them
    # minus the image without (the per-pixel direct sun and the lookups cancel) against what
    # the sun adds to the lookups of the whole map (the whole map's image minus the image of
    # the map without its sun). Without the lobe visibility correction, whose factor on the
    # direct lobes depends on which lobes are direct (tests/test_lobe_visibility.py)
    for backend in (render._torch, render._gl):
        monkeypatch.setattr(backend, "lobe_visibility_applies", lambda model: False)
    m = synthetic_model()
    mi = dataclasses.replace(m, indirect_gaussians=1)
    env = _sunny_env()
    per_pixel = render.Lighting(env, base_res=64, sun=True)
    assert per_pixel.sun is not None
    rest = envmap.extract_sun(env)[1]
    kw = dict(diffuse=False, background=False)

    def glossy(mod, lighting, backend="torch"):
        with render.Renderer(mod, lighting, 64, 48, backend=backend, samples=1) as r:
            return r.render(CAM, 20.0, return_mask=True, **kw)

    with_sun, mask = glossy(mi, per_pixel)
    without, _ = glossy(m, per_pixel)
    got = (with_sun - without)[mask]
    whole, _ = glossy(m, render.Lighting(env, base_res=64))
    no_sun, _ = glossy(m, render.Lighting(rest, base_res=64))
    # the sun through the mirror lobe as well: the broad lobe's share alone is wanted, so
    # the mirror lobe's weight is zero in both of these
    g = m.gaussians
    w = g.w.clone()
    w[:, :, 0] = 0
    broad = dataclasses.replace(m, gaussians=fit.Gaussians(w, g.mu, g.lam))
    whole, _ = glossy(broad, render.Lighting(env, base_res=64))
    no_sun, _ = glossy(broad, render.Lighting(rest, base_res=64))
    want = (whole - no_sun)[mask]
    assert float(want.sum()) > 0.3 * float(whole[mask].sum())  # the sun: a large share
    # the prefiltered lookups' accuracy for the sun at lam = 3 on a 64^2 chain against its
    # Gaussian stand-in: within 2 % on the whole, 5 % of the brightest pixel per pixel
    assert abs(float(got.sum() - want.sum())) <= 0.02 * float(want.sum())
    assert float((got - want).abs().max()) <= 0.05 * float(want.max())
    if not gl_available():
        return
    img_gl, mask_gl = glossy(mi, per_pixel, "gl")
    without_gl, _ = glossy(m, per_pixel, "gl")
    both = mask & mask_gl
    # the shader does the same float32 arithmetic in another order (tests/test_render.py);
    # the differences leave out the sun's direct light, whose shadow map and shadow rays
    # differ at shadow edges
    torch.testing.assert_close(
        (img_gl - without_gl)[both],
        (with_sun - without)[both],
        rtol=1e-3,
        atol=1e-4 * float(with_sun.max()),  # a difference of two images: their rounding
    )


def test_the_model_file_keeps_the_indirect_count(tmp_path):
    m = dataclasses.replace(synthetic_model(1), indirect_gaussians=1)
    m.save(tmp_path / "m.npz")
    back = model.load(tmp_path / "m.npz")
    assert back.indirect_gaussians == 1 and back.direct_gaussians == 1 and back.n_gaussians == 2
    with pytest.raises(InputError, match="indirect_gaussians"):
        dataclasses.replace(m, indirect_gaussians=2)
    # a file that claims every Gaussian indirect is refused, naming the field
    with np.load(tmp_path / "m.npz", allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    meta = __import__("json").loads(bytes(arrays["meta"]).decode())
    meta["indirect_gaussians"] = 2
    arrays["meta"] = np.frombuffer(__import__("json").dumps(meta).encode(), dtype=np.uint8)
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(InputError, match="indirect_gaussians"):
        model.load(tmp_path / "bad.npz")
