"""Transport sampling against independent estimates: albedo by BRDF sampling, path tracing.

Tolerances combine the Monte Carlo standard error of each estimate (3 sigma) with the
quadrature error of the direction set where there is one (stated at each assertion).
"""

from __future__ import annotations

import math

import pytest
import torch

from conftest import REAL_ENVMAPS
from lobelight import brdf, envmap, scene, transport
from lobelight.geometry import cubemap, sphere
from lobelight.lobes import sh
from lobelight.reference import paths as reference
from lobelight.scene import Materials, Scene


def _constant_env(value: float = 1.0) -> envmap.EnvMap:
    return envmap.EnvMap(torch.full((16, 32, 3), value), layout="latlong", name="constant")


def _albedo_mc(b: brdf.BRDF, wo: torch.Tensor, n: torch.Tensor, count: int, seed: int):
    """Directional albedo by importance sampling: mean and standard error of f cos / pdf."""
    g = torch.Generator().manual_seed(seed)
    u = torch.rand(count, *wo.shape[:-1], 2, generator=g)
    _, w, _ = b.sample(wo.expand(count, *wo.shape), n.expand(count, *n.shape), u)
    return w.mean(0), w.std(0) / math.sqrt(count)


def test_direct_glossy_against_constant_light_is_directional_albedo():
    sc = scene.builtin("sphere", subdivisions=2, model="ggx", roughness=0.25)
    tr = transport.Transport(sc)
    vidx = torch.tensor([0, 17, 101])
    views = sphere.geodesic_views()
    # a convex sphere: nothing occludes the upper hemisphere of a vertex
    dirs = cubemap.texel_directions(64).reshape(-1, 3)
    om = cubemap.texel_solid_angles(64).reshape(-1)
    vis = tr.visibility(vidx, dirs)
    up = (sc.mesh.normals[vidx] @ dirs.T) > 1e-3
    assert bool(vis[up].all())
    t = tr.direct(vidx, views, dirs, visibility=vis)  # (B, J, D, 3)
    got = (t * om[:, None]).sum(2)  # (B, J, 3)
    n = sc.mesh.normals[vidx][:, None].expand(-1, views.shape[0], 3)
    ref, se = _albedo_mc(
        sc.materials.specular.take(vidx).map_params(lambda p, k: p if p.ndim <= k else p[:, None]),
        views[None].expand_as(n),
        n,
        4000,
        0,
    )
    ok = ~((views[None] * n).sum(-1) <= 0.05)  # grazing views: the 64^2 quadrature misses
    # the lobe's sliver below the horizon edge; elsewhere the quadrature of a lobe of width
    # alpha = 0.25 (~8 texels) is within 1 %; MC adds 3 standard errors
    err = (got - ref).abs()[ok]
    assert bool((err <= 0.01 * ref[ok] + 3 * se[ok] + 1e-4).all()), float(err.max())
    below = (views[None] * sc.mesh.normals[vidx][:, None]).sum(-1) <= 0
    assert bool((t[below] == 0).all())


def test_direct_glossy_on_a_local_grid_for_a_sharp_lobe():
    # Phong exponent 5000: far narrower than any global cube-map texel (lobelight.fit._data);
    # a local grid around the mirror direction integrates it
    sc = scene.builtin("sphere", subdivisions=2, model="phong", roughness=0.02)
    exponent = float(sc.materials.specular.params["exponent"])
    tr = transport.Transport(sc)
    vidx = torch.tensor([5])
    n = sc.mesh.normals[vidx]
    views = torch.nn.functional.normalize(n + torch.tensor([[0.3, 0.1, -0.2]]), dim=-1)
    refl = 2 * (views * n).sum(-1, keepdim=True) * n - views
    dirs, w = sphere.local_grid(refl, torch.tensor([exponent]), n_theta=48)
    t = tr.direct(vidx, views, dirs[None])  # dirs (B=1, J=1, K, 3)
    got = (t[0, 0] * w[0][:, None]).sum(0)
    ref, se = _albedo_mc(sc.materials.specular, views[0], n[0], 20000, 1)
    assert torch.allclose(got, ref, rtol=0.01, atol=3 * float(se.max())), (got, ref)
    # the same lobe on a 32^2 cube map is badly under-resolved: the reason for local grids
    d32 = cubemap.texel_directions(32).reshape(-1, 3)
    om = cubemap.texel_solid_angles(32).reshape(-1)
    coarse = (tr.direct(vidx, views, d32)[0, 0] * om[:, None]).sum(0)
    assert float((coarse - ref).abs().max() / ref.max()) > 0.05


def test_batches_are_independent_and_views_below_are_flagged():
    sc = scene.builtin("knot")
    views = sphere.geodesic_views()[:20]
    a = transport.sample(sc, [3, 700], views, res=8, indirect=False)
    b = transport.sample(sc, [700], views, res=8, indirect=False)
    torch.testing.assert_close(a.glossy[1:], b.glossy)
    torch.testing.assert_close(a.diffuse[1:], b.diffuse)
    n = sc.mesh.normals[a.vertices]
    assert torch.equal(a.below, (n @ views.T) <= 0)
    assert bool((a.glossy[a.below] == 0).all())


def _occluded_vertex(sc: Scene) -> int:
    """A knot vertex that sees about half of its upper hemisphere."""
    tr = transport.Transport(sc)
    d = cubemap.texel_directions(8).reshape(-1, 3)
    cand = torch.arange(0, 1100, 37)
    vis = tr.visibility(cand, d).float()
    up = ((sc.mesh.normals[cand] @ d.T) > 0).float()
    frac = vis.sum(1) / up.sum(1)
    return int(cand[(frac - 0.5).abs().argmin()])


def test_per_view_directions_agree_with_shared_directions():
    # the per-(vertex, view) path (local grids) packs the views above the horizon and casts
    # rays for them only; on the same directions it must equal the shared-directions path,
    # which evaluates the BRDF where the environment is visible, with its own code
    sc = scene.builtin("knot")
    tr = transport.Transport(sc)
    vidx = torch.tensor([_occluded_vertex(sc), 5, 900])
    views = sphere.geodesic_views()
    d = cubemap.texel_directions(8).reshape(-1, 3)
    shared = tr.direct(vidx, views, d)  # (B, J, D, 3)
    per_view = tr.direct(vidx, views, d.expand(3, views.shape[0], -1, 3))
    torch.testing.assert_close(per_view, shared, rtol=1e-5, atol=1e-7)
    below = (sc.mesh.normals[vidx] @ views.T) <= 0
    assert bool(below.any()) and bool((per_view[below] == 0).all())
    assert bool((per_view[~below] > 0).any())


def test_diffuse_transfer_against_path_tracing():
    sc = scene.builtin("knot")
    v = _occluded_vertex(sc)
    env = _constant_env(1.0)
    tb = transport.sample(sc, [v], sphere.geodesic_views()[:1], res=32, indirect=False)
    # constant light L = 1: its only SH coefficient is L_00 = sqrt(4 pi)
    got = tb.diffuse[0, 0] * math.sqrt(4 * math.pi)
    diffuse_only = Scene(sc.mesh, Materials(sc.materials.diffuse), env.name, sc.camera)
    mean, se = reference.radiance_at(
        diffuse_only, env, [v], sc.mesh.normals[[v]], spp=8192, max_depth=2
    )
    # 32^2 cube quadrature of a binary visibility: ~1 % of the cosine-weighted visible area
    assert torch.allclose(got, mean[0, 0], rtol=0.015, atol=3 * float(se.max())), (got, mean)


def test_diffuse_interreflection_against_path_tracing():
    sc = scene.builtin("knot")
    v = _occluded_vertex(sc)
    env = _constant_env(1.0)
    diffuse_only = Scene(sc.mesh, Materials(sc.materials.diffuse), env.name, sc.camera)
    tr = transport.Transport(diffuse_only)
    dirs = cubemap.texel_directions(16).reshape(-1, 3)
    om = cubemap.texel_solid_angles(16).reshape(-1)
    allv = torch.arange(sc.mesh.n_vertices)
    shadowed = tr.diffuse(allv, dirs, om)
    bounced = transport.diffuse_interreflection(tr, shadowed, bounces=3, res=8)
    got = bounced[v, 0] * math.sqrt(4 * math.pi)
    mean, se = reference.radiance_at(
        diffuse_only, env, [v], sc.mesh.normals[[v]], spp=8192, max_depth=5
    )
    # interreflection adds a visible share here; the 8^2 hit quadrature and the per-vertex
    # (piecewise linear) transfer at hit points are good to ~3 % of the total
    assert float((got - shadowed[v, 0] * math.sqrt(4 * math.pi)).max()) > 0.02
    assert torch.allclose(got, mean[0, 0], rtol=0.03, atol=3 * float(se.max())), (got, mean)


def test_indirect_glossy_against_path_tracing():
    # a mirror-like knot over a diffuse ground: its glossy lobe at an occluded vertex sees the
    # object, so indirect glossy is a real share
    sc = scene.builtin("knot")
    spec = brdf.GGX(
        alpha=0.15,
        specular=sc.materials.specular.params["specular"]
        .amax(1, keepdim=True)
        .expand(-1, 3)
        .gt(0)
        .float()
        * 0.9,
    )
    glossy = Scene(sc.mesh, Materials(sc.materials.diffuse, spec), "constant", sc.camera)
    v = _occluded_vertex(glossy)
    env = _constant_env(1.0)
    n = sc.mesh.normals[v]
    views = torch.nn.functional.normalize(torch.stack([n, n + torch.tensor([0.5, 0, 0.3])]), dim=-1)
    tr = transport.Transport(glossy)
    gen = torch.Generator().manual_seed(3)
    ind = tr.indirect(torch.tensor([v]), views, paths=4096, res=8, generator=gen)
    om = cubemap.texel_solid_angles(8).reshape(-1)
    got = (ind[0] * om[:, None]).sum(1)  # constant light: no binning error
    full, se_f = reference.radiance_at(
        glossy, env, [v], views, spp=8192, max_depth=-1, part="specular", seed=1
    )
    direct, se_d = reference.radiance_at(
        glossy, env, [v], views, spp=8192, max_depth=2, part="specular", seed=2
    )
    ref = full[0] - direct[0]
    se_ref = (se_f[0] ** 2 + se_d[0] ** 2).sqrt()
    assert float(ref.min()) > 0.02  # the test needs a visible indirect share
    # our estimate's own noise: 4096 paths vs 8192 reference samples, same variance per path
    tol = 3 * torch.sqrt(se_ref**2 + 2 * se_f[0] ** 2) + 0.01 * ref
    assert bool(((got - ref).abs() <= tol).all()), (got, ref, tol)


# the all-frequency cases (the bundled maps): a small unclipped sun, and a studio softbox
@pytest.mark.parametrize("path", REAL_ENVMAPS, ids=lambda p: p.name)
def test_direct_glossy_with_real_map_matches_reference(path):
    sc = scene.builtin("knot")
    env = envmap.load(path)
    v = _occluded_vertex(sc)
    n = sc.mesh.normals[v]
    views = torch.nn.functional.normalize(
        torch.stack([n + torch.tensor([0.3, 0.2, 0]), n + torch.tensor([-0.2, 0, 0.4])]), dim=-1
    )
    res = 64
    om = cubemap.texel_solid_angles(res).reshape(-1)
    tb = transport.sample(sc, [v], views, res=res, indirect=False)
    light = env.to_cubemap(res).reshape(-1, 3)  # area-averaged texels
    got = (tb.glossy[0] * (light * om[:, None])[None]).sum(1)  # (J, 3)
    mean, se = reference.radiance_at(sc, env, [v], views, spp=16384, max_depth=2, part="specular")
    # the vertex's Phong exponent is ~100 (lobe ~6 texels wide at 64^2): texel-averaged light
    # against the exact integrand is good to ~3 % on these maps
    assert torch.allclose(got, mean[0], rtol=0.03, atol=3 * float(se.max())), (got, mean, se)


def test_sh_diffuse_matches_projection_identity():
    # unoccluded vertex of a sphere: transfer = (albedo / pi) * clamped-cosine zonal rotated to n
    sc = scene.builtin("sphere", subdivisions=2)
    tr = transport.Transport(sc)
    d = cubemap.texel_directions(64).reshape(-1, 3)
    om = cubemap.texel_solid_angles(64).reshape(-1)
    t = tr.diffuse(torch.tensor([7]), d, om)[0]  # (25, 3)
    n = sc.mesh.normals[7]
    zonal = sh.clamped_cosine_zonal(5)
    ref = sh.zonal_to_sh(zonal, n)  # (25,)
    ref = ref[:, None] * sc.materials.diffuse[7] / math.pi
    # 64^2 quadrature of the clamped cosine's kink: 2e-3 absolute
    torch.testing.assert_close(t, ref.to(t.dtype), rtol=0, atol=2e-3)
