"""The compiled per-point walk of the visibility quad-tree (``cosine._walk``, numba, CPU).

It must find the same shadow leaves as the flat-list quad-tree of ``_visibility`` (which the
GPU runs and ``test_cosine_lighting`` checks against coverage and Monte Carlo): the same tests
in another order and in float64, so a leaf can differ only where a corner lies on an
occluder's outline to float32 rounding. Compared here as sets of cells.
"""

from __future__ import annotations

import pytest
import torch

from lobelight.cosine import _visibility, _walk
from lobelight.cosine._fused import fusion
from lobelight.cosine._light import _geometry

pytestmark = pytest.mark.skipif(not _walk.available(), reason="numba is not installed")


def _scene(n: int, seed: int):
    """Points on a plane under a cluster of spheres, lit by a sphere light above and aside."""
    g = torch.Generator().manual_seed(seed)
    xz = (torch.rand(n, 2, generator=g) * 2 - 1) * 1.5
    x = torch.stack([xz[:, 0], torch.zeros(n), xz[:, 1]], -1)
    c = torch.rand(24, 3, generator=g) * torch.tensor([1.2, 0.4, 1.2]) + torch.tensor(
        [-0.6, 0.7, -0.6]
    )
    spheres = torch.cat([c, 0.1 + 0.15 * torch.rand(24, 1, generator=g)], -1)
    axis, dist, theta = _geometry(x, torch.tensor([[0.8, 3.0, 0.3]]), torch.tensor([0.5]))
    return x, axis[:, 0], theta[:, 0], dist[:, 0], spheres


def _cells(lv) -> set:
    return set(
        zip(
            lv.point.tolist(),
            lv.depth.tolist(),
            lv.u.double().tolist(),
            lv.v.double().tolist(),
            strict=True,
        )
    )


def _cells_per_point(lv, n: int) -> list[set]:
    out = [set() for _ in range(n)]
    for p, d, u, v in _cells(lv):
        out[p].add((d, u, v))
    return out


def _solid_angle(lv, on, n: int) -> torch.Tensor:
    """(n,) float64 solid angle of each point's leaf cells, measured on the squares of ``on``
    (a float64 run), so that leaves of any precision are measured alike."""
    geo = on._replace(point=lv.point, depth=lv.depth, u=lv.u.double(), v=lv.v.double())
    return torch.zeros(n, dtype=torch.float64).index_add(0, lv.point, geo.geometry()[2])


# Unit roundoffs of float32 and float64.
U32, U64 = 2.0**-24, 2.0**-53


def _bracket(x, axis, theta, dist, spheres, roundoff: float, **kw):
    """The float64 flat lists with every occluder's angular radius shrunk and grown by the
    largest angle that rounding with unit roundoff ``roundoff`` can move a decision.

    Every decision of the tree compares the cosine of an angle with the cosine of a cone's
    (or cone plus cap's) radius; each side is a few dot products, normalisations and square
    roots of numbers at most ~1, so its absolute error is below ``16 roundoff`` (eight
    roundings, doubled for slack). An error ``e`` in a cosine moves the angle it stands for by
    at most ``e / sin(angle)``, and the smallest angle at a cone's edge is its radius ``phi``:
    so no decision moves by more than ``delta = 2 * 16 roundoff / sin(phi_min)`` (both sides).
    A sphere's radius grown or shrunk by ``delta * d_max`` moves every cone's edge by at least
    ``delta`` (d asin(r / d) / dr >= 1 / d). Covered solid angle is monotone in the cones (a
    cell inside a smaller cone is inside the larger), so any run in that precision lies, point
    by point, between the two runs returned here; points whose cells are the same in both are
    decided away from every edge and must come out identically.
    """
    d = torch.linalg.vector_norm(spheres[None, :, :3].double() - x[:, None].double(), dim=-1)
    r = spheres[:, 3].double()
    sin_phi_min = float((r[None] / d).min())
    delta = 2 * 16 * roundoff / sin_phi_min
    dr = delta * float(d.max())
    f64 = [z.double() for z in (x, axis, theta, dist)]
    lo, hi = spheres.double().clone(), spheres.double().clone()
    lo[:, 3] -= dr
    hi[:, 3] += dr
    return (
        _visibility.shadow_leaves(*f64, lo, **kw),
        _visibility.shadow_leaves(*f64, hi, **kw),
    )


def _assert_within(got, lo, hi, ref, n: int) -> None:
    """``got``'s leaves lie between the bracketing runs ``lo`` and ``hi`` (:func:`_bracket`) in
    solid angle per point, and are the reference ``ref``'s exactly where the bracket is tight."""
    og, olo, ohi = (_solid_angle(lv, ref, n) for lv in (got, lo, hi))
    slack = 1e-12 * ohi.clamp_min(1.0)  # float64 sums of the same cells in another order
    assert bool((og >= olo - slack).all() and (og <= ohi + slack).all())
    c_got, c_lo, c_hi, c_ref = (_cells_per_point(lv, n) for lv in (got, lo, hi, ref))
    # not vacuous: the bracket is narrow (measured: 0.1-0.2 % of the covered solid angle in
    # float32, none in float64) and decides many points to the cell
    assert float((ohi - olo).sum()) < 0.01 * float(ohi.sum())
    tight = [p for p in range(n) if c_lo[p] == c_hi[p]]
    assert len(tight) > 0.4 * n
    assert all(c_got[p] == c_ref[p] for p in tight)


@pytest.mark.parametrize("mode", ["aggressive", "conservative"])
@pytest.mark.parametrize("depth", [3, 5])
def test_walk_finds_the_flat_lists_leaves(mode, depth):
    """The walk (float64 inside) against the flat lists run in float64 and in float32 (what
    eager shading runs): the same cells wherever rounding cannot decide otherwise, and cells
    between the bracketing runs of :func:`_bracket` where a corner or a bounding cap lies on a
    cone's edge to within rounding."""
    x, axis, theta, dist, spheres = _scene(1500, seed=depth)
    n = x.shape[0]
    exclude = torch.full((n,), -1)
    exclude[::7] = 3  # some points ignore an occluder (their own sphere)
    kw = dict(depth=depth, mode=mode, exclude=exclude)
    f64 = [z.double() for z in (x, axis, theta, dist, spheres)]
    flat = _visibility.shadow_leaves(*f64, **kw)  # fusion off: the flat lists
    flat32 = _visibility.shadow_leaves(x, axis, theta, dist, spheres, **kw)
    with fusion(True):
        walked = _visibility.shadow_leaves(x, axis, theta, dist, spheres, **kw)
    assert len(_cells(flat)) > 2000  # not vacuous: many shadowed points, leaves of all depths
    assert len(set(flat.depth.tolist())) == depth + 1
    _assert_within(walked, *_bracket(x, axis, theta, dist, spheres, U64, **kw), flat, n)
    _assert_within(flat32, *_bracket(x, axis, theta, dist, spheres, U32, **kw), flat, n)
    torch.testing.assert_close(walked.count, torch.bincount(walked.point, minlength=n))
    # grouped by point
    assert bool((walked.point[1:] >= walked.point[:-1]).all())
    # the leaves' float32 solid angles (the shading's) sum as float64 ones of the same cells:
    # relative error of a few float32 roundings per leaf
    cf, cw = _cells_per_point(flat, n), _cells_per_point(walked, n)
    same = torch.tensor([a == b for a, b in zip(cf, cw, strict=True)])
    gb = walked.geometry()
    assert bool(torch.isfinite(gb[1]).all()) and bool((gb[1] > 0).all())
    oa = _solid_angle(flat, flat, n)
    ob = torch.zeros(n).index_add(0, walked.point, gb[2]).double()
    torch.testing.assert_close(ob[same], oa[same], rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize("mode", ["aggressive", "conservative"])
def test_useful_depth_cuts_the_tree_alike(monkeypatch, mode):
    """Cut short at a point's useful depth (``shadow_leaves(peak=, threshold=)``), a mask keeps
    exactly its full mask's leaves of that depth or less, in the walk and in the flat lists
    (partly covered cells at the cut are neither leaves nor split, as at an aggressive mask's
    last level; -1 drops the point). The depths here are random per point, all of -1..depth."""
    depth = 4
    x, axis, theta, dist, spheres = _scene(1200, seed=11)
    n = x.shape[0]
    g = torch.Generator().manual_seed(3)
    last = torch.randint(-1, depth + 1, (n,), generator=g)
    monkeypatch.setattr(_visibility, "useful_depth", lambda peak, span, t, d: last)
    kw = dict(depth=depth, mode=mode)
    cut = dict(peak=torch.ones(n), threshold=1.0)
    full = _visibility.shadow_leaves(x, axis, theta, dist, spheres, **kw)
    keep = full.depth <= last[full.point]
    want = _cells(full._replace(point=full.point[keep], depth=full.depth[keep],
                                u=full.u[keep], v=full.v[keep]))  # fmt: skip
    flat = _visibility.shadow_leaves(x, axis, theta, dist, spheres, **kw, **cut)
    with fusion(True):
        walked = _visibility.shadow_leaves(x, axis, theta, dist, spheres, **kw, **cut)
    assert len(want) > 1000 and int((~keep).sum()) > 1000  # not vacuous: both kinds abound
    assert _cells(flat) == want  # the same float32 arithmetic, cut or not
    # the walk computes in float64: against the float64 flat lists, cut alike
    f64 = [z.double() for z in (x, axis, theta, dist, spheres)]
    flat64 = _visibility.shadow_leaves(*f64, **kw, **cut)
    _assert_within(walked, *_bracket(x, axis, theta, dist, spheres, U64, **kw, **cut), flat64, n)
    torch.testing.assert_close(walked.count, torch.bincount(walked.point, minlength=n))


def test_points_with_many_leaves_are_walked_again(monkeypatch):
    """The first walk keeps ``_ROOM`` leaves per point; points with more are walked a second
    time straight into their rows. With room for 2, most shadowed points take that path."""
    x, axis, theta, dist, spheres = _scene(400, seed=1)
    with fusion(True):
        full = _visibility.shadow_leaves(x, axis, theta, dist, spheres, depth=5)
        monkeypatch.setattr(_walk, "_ROOM", 2)
        tight = _visibility.shadow_leaves(x, axis, theta, dist, spheres, depth=5)
    assert int((full.count > 2).sum()) > 50
    for name in ("point", "depth", "u", "v", "count"):
        torch.testing.assert_close(getattr(tight, name), getattr(full, name), rtol=0, atol=0)


def test_walk_without_leaves():
    """No occluder in reach, or no point: empty leaves, zero counts."""
    x, axis, theta, dist, _ = _scene(50, seed=2)
    far = torch.tensor([[10.0, 1.0, 10.0, 0.2]])  # outside every point's square
    with fusion(True):
        lv = _visibility.shadow_leaves(x, axis, theta, dist, far, depth=5)
        assert lv.point.numel() == 0 and int(lv.count.sum()) == 0
        none = _visibility.shadow_leaves(x[:0], axis[:0], theta[:0], dist[:0], far, depth=5)
        assert none.point.numel() == 0
