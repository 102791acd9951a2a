"""The two ray-casting engines, Embree and NVIDIA Warp, give the same answers.

Both intersect in float32 (Embree always; Warp's BVH holds float32 vertices and rays), and
both report only a triangle index that :class:`~lobelight.geometry.raycast.RayCaster` turns
into distance and barycentrics by the same float64 code. So where the engines name the same
triangle, ``t`` and ``bary`` must be bit for bit equal; where they name different ones, the ray
must pass within float32 rounding of a triangle's edge, where either neighbour (or, at an
outline, the surface behind) is a right answer.
"""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
import torch

wp = pytest.importorskip("warp")

from conftest import SESSION_TMP, random_dirs  # noqa: E402 - after the skip
from lobelight import fit, scene  # noqa: E402
from lobelight.errors import InputError  # noqa: E402
from lobelight.geometry import _warp_rays, raycast  # noqa: E402
from lobelight.scene import Mesh, Scene, _shapes, uniform  # noqa: E402

# Warp compiles the kernels into its on-disk cache on first use: the session's folder, like
# every other cache of the suite (conftest), not ~/.cache/warp. Read when Warp initialises,
# which nothing before these tests does.
wp.config.kernel_cache_dir = str(SESSION_TMP / "warp")

#: How near a triangle's edge a ray must pass for either engine's answer to be right, as a
#: fraction of the mesh's diagonal, for a ray square to the triangle. Float32 rounds the
#: vertices and rays to ~6e-8 of the coordinates (up to ~3 here) and the edge tests of both
#: intersectors add a few roundings more: a few 1e-7 of the diagonal; 1e-5 leaves 20x to
#: spare, and is still far below the triangles' sizes (~4e-3 of it on the knot).
EDGE = 1e-5


@pytest.fixture(scope="module")
def knot() -> Mesh:
    """The knot over its ground plane, 22,784 triangles: self-occlusion, a flat plane of
    coplanar triangles, outlines."""
    return scene.load("knot:2").mesh


def _casters(mesh: Mesh):
    return raycast.RayCaster(mesh, engine="embree"), raycast.RayCaster(mesh, engine="warp")


def _edge_distance(mesh: Mesh, tri: torch.Tensor, o: torch.Tensor, d: torch.Tensor):
    """Signed distance from where each ray crosses the plane of the triangle it hit to that
    triangle's nearest edge, (R,) float64: negative outside it, inf on a miss. The caster's
    barycentrics are clamped onto the triangle: these are computed afresh (Moller-Trumbore in
    float64), unclamped, so that a wrong triangle shows."""
    v = mesh.vertices.double()[mesh.faces[tri.clamp(min=0)]]  # (R, 3, 3)
    o, d = o.double(), d.double()
    e1, e2 = v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]
    p = torch.linalg.cross(d, e2)
    det = (e1 * p).sum(-1)
    s = o - v[:, 0]
    b1 = (s * p).sum(-1) / det
    b2 = (d * torch.linalg.cross(s, e1)).sum(-1) / det
    bary = torch.stack([1 - b1 - b2, b1, b2], -1)
    area2 = torch.linalg.cross(e1, e2).norm(dim=-1)
    opposite = (v[:, [2, 0, 1]] - v[:, [1, 2, 0]]).norm(dim=-1)  # the edge facing each corner
    dist = (bary * area2[:, None] / opposite).amin(-1)
    return torch.where(tri >= 0, dist, torch.full_like(dist, float("inf")))


def _square(mesh: Mesh, tri: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    """|cos| of each ray to the normal of the triangle it hits, (R,) (1 on a miss), at least
    1e-6."""
    c = (mesh.face_normals[tri.clamp(min=0)].double() * d.double()).sum(-1).abs()
    return torch.where(tri >= 0, c, torch.ones_like(c)).clamp(min=1e-6)


def _assert_same_hits(mesh: Mesh, o: torch.Tensor, d: torch.Tensor, *, most: float = 0.01):
    """Both engines' occlusion and first hits on rays ``(R, 3)``: the same, but where a ray
    passes within :data:`EDGE` of an edge of a triangle one of them reports; fewer than
    ``most`` of the rays that hit may differ. Returns how many differ."""
    embree, warp = _casters(mesh)
    tri_e, t_e, bary_e = embree.first_hit(o, d)
    tri_w, t_w, bary_w = warp.first_hit(o, d)
    occ_e, occ_w = embree.occluded(o, d), warp.occluded(o, d)
    for tri, t, bary, occ in [(tri_e, t_e, bary_e, occ_e), (tri_w, t_w, bary_w, occ_w)]:
        # each engine agrees with itself: any-hit and closest-hit run the same triangle test
        assert torch.equal(occ, tri >= 0)
        miss = tri < 0
        assert bool((tri[miss] == -1).all() and torch.isinf(t[miss]).all())
        assert bool((bary[miss] == 0).all() and torch.isfinite(t[~miss]).all())
    same = tri_e == tri_w
    # the same triangle: the same float64 code on the same rays, so exactly the same numbers
    assert torch.equal(t_e[same], t_w[same]) and torch.equal(bary_e[same], bary_w[same])
    differ = ~same
    # a ray an error e off in float32 crosses a triangle's plane e / |cos| off along it
    tol_e = EDGE * mesh.scale / _square(mesh, tri_e, d)
    tol_w = EDGE * mesh.scale / _square(mesh, tri_w, d)
    dist_e, dist_w = _edge_distance(mesh, tri_e, o, d), _edge_distance(mesh, tri_w, o, d)
    # every hit is on the triangle reported, up to rounding
    assert bool((dist_e >= -tol_e).all() and (dist_w >= -tol_w).all())
    at_e, at_w = dist_e < tol_e, dist_w < tol_w
    # where they differ, the nearer hit is at an edge: the other engine took the neighbour
    # across it, or slipped past it (an outline) to the surface behind or to a miss
    nearer_at_edge = torch.where(t_e <= t_w, at_e, at_w)
    assert bool(nearer_at_edge[differ].all()), f"{int((differ & ~nearer_at_edge).sum())} rays"
    # both at an edge of two neighbours: the same point, up to the same rounding
    fe, fw = mesh.faces[tri_e.clamp(min=0)], mesh.faces[tri_w.clamp(min=0)]
    neighbours = (fe[:, :, None] == fw[:, None, :]).any(-1).sum(-1) >= 2
    both = differ & at_e & at_w & neighbours
    gap = (t_e[both] - t_w[both]).abs().double()
    assert bool((gap <= torch.maximum(tol_e, tol_w)[both]).all())
    hits = int((occ_e | occ_w).sum())
    assert int(differ.sum()) <= most * max(hits, 1), (int(differ.sum()), hits)
    return int(differ.sum())


def _from_surface(mesh: Mesh, caster, n_rays: int, seed: int):
    """Visibility rays: from random vertices, random directions above the vertex normal."""
    g = torch.Generator().manual_seed(seed)
    vid = torch.randint(0, mesh.n_vertices, (n_rays,), generator=g)
    d = random_dirs(n_rays, dtype=torch.float32, seed=seed).to(mesh.device)
    n = mesh.normals[vid]
    d = torch.where(((d * n).sum(-1) < 0)[:, None], -d, d)
    return caster.spawn(mesh.vertices[vid], n, d), d


def _from_outside(mesh: Mesh, n_rays: int, seed: int):
    """Rays from a sphere around the mesh toward random points of its bounding box (and
    beyond it: misses too)."""
    g = torch.Generator().manual_seed(seed)
    lo, hi = mesh.bounds.cpu()
    centre = (lo + hi) / 2
    o = centre + mesh.scale * random_dirs(n_rays, dtype=torch.float32, seed=seed)
    aim = lo + (hi - lo) * (1.4 * torch.rand(n_rays, 3, generator=g) - 0.2)
    return o.to(mesh.device), torch.nn.functional.normalize(aim - o, dim=-1).to(mesh.device)


def test_random_rays_give_the_same_hits(knot, device):
    mesh = knot.to(device)
    embree, warp = _casters(mesh)
    assert (embree.engine, warp.engine) == ("embree", "warp")
    o1, d1 = _from_surface(mesh, embree, 20_000, seed=1)
    o2, d2 = _from_outside(mesh, 20_000, seed=2)
    o, d = torch.cat([o1, o2]), torch.cat([d1, d2])
    # random rays pass within 1e-5 of an edge about once in 10^4 (the edges' share of the
    # area): a handful may differ, not more
    _assert_same_hits(mesh, o, d, most=1e-3)
    tri, t, bary = warp.first_hit(o, d)
    assert tri.device == t.device == bary.device == o.device  # results where the rays are
    occ = embree.occluded(o, d)
    assert 0.2 < float(occ.float().mean()) < 0.8  # hits and misses both tested


def test_grazing_rays(knot):
    # rays that meet a triangle at 1e-2 to 1e-5 rad from its plane, aimed at a random point
    # inside it: on the flat ground (coplanar neighbours) and on the curved tube
    g = torch.Generator().manual_seed(4)
    n_rays = 6000
    f = torch.randint(0, knot.n_faces, (n_rays,), generator=g)
    w = torch.rand(n_rays, 3, generator=g) + 0.05
    w = w / w.sum(-1, keepdim=True)
    target = (knot.vertices[knot.faces[f]] * w[..., None]).sum(1)
    n = knot.face_normals[f]
    u = torch.nn.functional.normalize(torch.linalg.cross(n, torch.randn(n_rays, 3, generator=g)))
    angle = 10 ** (-2 - 3 * torch.rand(n_rays, 1, generator=g))
    d = torch.nn.functional.normalize(u * torch.cos(angle) - n * torch.sin(angle), dim=-1)
    o = target - 0.05 * knot.scale * d
    # a grazing ray crosses many triangles' planes near an edge: more may differ
    _assert_same_hits(knot, o, d, most=0.05)


@pytest.mark.parametrize("where", ["edges", "vertices"])
def test_rays_aimed_exactly_at_shared_edges_and_vertices(knot, where):
    g = torch.Generator().manual_seed(5)
    n_rays = 6000
    f = torch.randint(0, knot.n_faces, (n_rays,), generator=g)
    a, b = knot.vertices[knot.faces[f, 0]], knot.vertices[knot.faces[f, 1]]
    target = a + torch.rand(n_rays, 1, generator=g) * (b - a) if where == "edges" else a
    n = knot.face_normals[f]
    w = random_dirs(n_rays, dtype=torch.float32, seed=5)
    w = torch.where(((w * n).sum(-1) < 0)[:, None], -w, w)
    o, d = target + 0.3 * w, -w
    # every ray is on an edge: either neighbour is right, and so is the surface behind an
    # outline, so any number may differ; each one is checked
    differ = _assert_same_hits(knot, o, d, most=1.0)
    assert differ > 0.1 * n_rays  # the tie is real: the engines break it differently


def test_a_mesh_with_degenerate_triangles():
    # an icosphere with zero-area triangles added: corners repeated; three corners on a line
    # lying along a real triangle's edge (a needle); and slivers, whose third corner is the
    # float32 midpoint of a real edge (off it by rounding: a real, if ill-conditioned, triangle)
    v, f = _shapes.icosphere(2)
    e0, e1 = f[:40, 0], f[:40, 1]
    needle = [[1.5, 0.0, 0.0], [1.5, 0.5, 0.0], [1.5, 1.0, 0.0], [1.5, 0.5, 0.5]]
    mid = ((v[e0] + v[e1]) / 2).astype(np.float32)
    vt = torch.from_numpy(np.concatenate([v, needle, mid]).astype(np.float32))
    n, m = len(v), np.arange(len(v) + 4, len(v) + 44)
    zero = np.concatenate([np.stack([e0, e0, e1], 1), [[n, n + 1, n + 2], [n + 2, n + 1, n]]])
    faces = np.concatenate([f, [[n, n + 2, n + 3]], zero, np.stack([e0, m, e1], 1)])
    mesh = Mesh(vt, torch.from_numpy(faces).long(), torch.nn.functional.normalize(vt, dim=-1))
    o, d = _from_outside(mesh, 4000, seed=6)
    # and rays aimed at the needle and at the slivers (the real edges they lie along)
    target = torch.cat([vt[n] + torch.rand(200, 1) * (vt[n + 2] - vt[n]), vt[m]])
    w = random_dirs(len(target), dtype=torch.float32, seed=7)
    # from the side the needle's triangle faces (+x), from outside the sphere for the slivers
    outward = torch.where(
        torch.arange(len(target))[:, None] < 200, torch.tensor([1.0, 0, 0]), target
    )
    w = torch.where(((w * outward).sum(-1) < 0)[:, None], -w, w)
    o, d = torch.cat([o, target + 0.5 * w]), torch.cat([d, -w])
    _assert_same_hits(mesh, o, d, most=0.1)
    is_zero = torch.zeros(len(faces), dtype=torch.bool)
    is_zero[len(f) + 1 : len(f) + 1 + len(zero)] = True
    for caster in _casters(mesh):
        tri, t, bary = caster.first_hit(o, d)
        hit = tri >= 0
        assert not bool(is_zero[tri[hit]].any())  # nothing to hit
        assert bool(torch.isfinite(t[hit]).all() and (bary[hit] >= 0).all())
        torch.testing.assert_close(bary[hit].sum(-1), torch.ones(int(hit.sum())))
        assert int((tri == len(f)).sum()) > 20  # the needle's real triangle is hit


def test_misses_on_both_engines(knot):
    # rays pointing away from the mesh, from outside its bounding box
    o, d = _from_outside(knot, 500, seed=8)
    for caster in _casters(knot):
        tri, t, bary = caster.first_hit(o, -d)
        assert bool((tri == -1).all() and torch.isinf(t).all() and (bary == 0).all())
        assert not bool(caster.occluded(o, -d).any())
        empty = caster.first_hit(o[:0], d[:0])  # no rays at all
        assert [x.shape for x in empty] == [(0,), (0,), (0, 3)]


def test_choosing_an_engine(knot, monkeypatch):
    assert raycast.ENGINES == ("auto", "embree", "warp") and raycast.warp_available()
    assert raycast.get_default_engine() == "auto"
    assert raycast.RayCaster(knot).engine == "embree"  # auto, mesh on the CPU
    assert raycast.resolve_engine("auto", "cuda") == "warp"
    with raycast.default_engine("warp"):
        assert raycast.RayCaster(knot).engine == "warp"
        assert raycast.RayCaster(knot, engine="embree").engine == "embree"  # asked wins
        with raycast.default_engine("embree"):
            assert raycast.resolve_engine(None, "cuda") == "embree"
        assert raycast.get_default_engine() == "warp"
    assert raycast.get_default_engine() == "auto"
    with pytest.raises(InputError, match="unknown ray-casting engine 'optix'"):
        raycast.RayCaster(knot, engine="optix")
    with pytest.raises(InputError, match="unknown"):
        raycast.set_default_engine("Warp")
    with pytest.raises(InputError, match="CPU or a CUDA device, not meta"):
        raycast.resolve_engine("warp", "meta")
    monkeypatch.setattr(_warp_rays, "wp", None)  # as without warp-lang installed
    assert not raycast.warp_available()
    assert raycast.resolve_engine("auto", "cuda") == "embree"
    with pytest.raises(InputError, match=r"'warp'.*pip install warp-lang") as e:
        raycast.RayCaster(knot, engine="warp")
    assert "\n" not in str(e.value)
    with pytest.raises(InputError, match="pip install warp-lang"):
        raycast.set_default_engine("warp")
    assert raycast.get_default_engine() == "auto"


def test_warp_prints_nothing():
    # Warp prints a banner when it starts and a line per module it loads: in a fresh process,
    # since this one's Warp has started already
    code = (
        "import torch; from lobelight import scene; from lobelight.geometry import raycast; "
        "m = scene.load('sphere:1').mesh; "
        "raycast.RayCaster(m, engine='warp').first_hit(torch.zeros(4, 3), torch.eye(3)[[0]])"
    )
    env = {**os.environ, "WARP_CACHE_PATH": wp.config.kernel_cache_dir}
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert p.returncode == 0, p.stderr
    assert p.stdout == ""


def test_warp_is_imported_only_when_asked_for():
    # importing Warp takes a third of a second: a run on Embree alone does not pay it
    code = (
        "import sys, torch; from lobelight import scene; from lobelight.geometry import raycast; "
        "m = scene.load('sphere:1').mesh; "
        "raycast.RayCaster(m).first_hit(torch.zeros(4, 3), torch.eye(3)[[0]]); "
        "print('warp' in sys.modules); raycast.RayCaster(m, engine='warp'); "
        "print('warp' in sys.modules)"
    )
    env = {**os.environ, "WARP_CACHE_PATH": wp.config.kernel_cache_dir}
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert p.returncode == 0, p.stderr
    assert p.stdout.split() == ["False", "True"]


def _ball_on_floor() -> Scene:
    """A glossy ball over a floor: the ball shadows and reflects onto the floor, and the
    floor onto the ball (21 vertices)."""
    sv, sf = _shapes.icosphere(0, radius=0.5)
    pv, pf = _shapes.ground_plane(2.0, 0.0, n=3)
    v = np.concatenate([sv + np.array([0.0, 0.55, 0.0]), pv])
    mesh = scene.mesh_from_arrays(v, np.concatenate([sf, pf + len(sv)]), weld=False)
    spec = {"diffuse": [0.5] * 3, "model": "ggx", "specular": [0.5] * 3, "alpha": 0.2}
    return Scene(mesh, uniform(spec, mesh.n_vertices), "builtin", scene.builtin("sphere:0").camera)


@pytest.mark.usefixtures("one_torch_thread")  # the fit's many small tensor operations
def test_a_bake_is_the_same_with_either_engine():
    sc = _ball_on_floor()
    models = {}
    for engine in ("embree", "warp"):
        with raycast.default_engine(engine):
            models[engine] = fit.fit_model(sc, 1, progress=None, relax=False)
    a, b = models["embree"], models["warp"]
    # the rays are the same (same seed), and the engines name the same triangle but for rays
    # within float32 rounding of an edge, where either answer is right (tests above); a
    # visibility sample that flips there moves its vertex's transfer by one direction's
    # quadrature weight times its cosine, small for the grazing rays that can flip, and the fit
    # follows its data smoothly: 1e-4 of each array's largest value allows a few such flips.
    # Measured on this scene: identical (the flips are rarer than one in the bake's ~10^5 rays)
    ga, gb = a.gaussians, b.gaussians
    for x, y in [(a.diffuse, b.diffuse), (ga.w, gb.w), (ga.mu, gb.mu), (ga.lam, gb.lam)]:
        assert x.shape == y.shape
        torch.testing.assert_close(x, y, rtol=1e-4, atol=1e-4 * float(x.abs().max()))
