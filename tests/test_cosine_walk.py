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


@pytest.mark.parametrize("mode", ["aggressive", "conservative"])
@pytest.mark.parametrize("depth", [3, 5])
def test_walk_finds_the_flat_lists_leaves(mode, depth):
    """The walk (float64 inside) against the flat lists run in float64 and in float32 (what
    eager shading runs): the same cells, per-point counts and solid angles. A few cells may
    differ where a corner or a bounding cap grazes a cone to float32 rounding (measured: none
    here; before the bounding cap's radius was computed from its tangent, 40 of ~9,000 leaves
    differed in float32)."""
    x, axis, theta, dist, spheres = _scene(1500, seed=depth)
    exclude = torch.full((x.shape[0],), -1)
    exclude[::7] = 3  # some points ignore an occluder (their own sphere)
    kw = dict(depth=depth, mode=mode, exclude=exclude)
    f64 = [z.double() for z in (x, axis, theta, dist, spheres)]
    flat = _visibility.shadow_leaves(*f64, **kw)  # fusion off: the flat lists
    flat32 = _visibility.shadow_leaves(x, axis, theta, dist, spheres, **kw)
    with fusion(True):
        walked = _visibility.shadow_leaves(x, axis, theta, dist, spheres, **kw)
    a, b = _cells(flat), _cells(walked)
    assert len(a) > 2000  # not vacuous: many shadowed points, leaves of all depths
    assert len(set(flat.depth.tolist())) == depth + 1
    assert len(a ^ b) <= 3, sorted(a ^ b)[:6]
    assert len(_cells(flat32) ^ b) <= 3
    torch.testing.assert_close(walked.count, torch.bincount(walked.point, minlength=len(x)))
    torch.testing.assert_close(walked.count, flat.count, atol=3, rtol=0)
    # grouped by point
    assert bool((walked.point[1:] >= walked.point[:-1]).all())
    # the leaves' solid angles per point sum alike (float32 geometry from the same cells)
    ga, gb = flat.geometry(), walked.geometry()
    assert bool(torch.isfinite(gb[1]).all()) and bool((gb[1] > 0).all())
    oa = torch.zeros(len(x), dtype=torch.float64).index_add(0, flat.point, ga[2])
    ob = torch.zeros(len(x)).index_add(0, walked.point, gb[2]).double()
    torch.testing.assert_close(ob, oa, rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize("mode", ["aggressive", "conservative"])
def test_useful_depth_cuts_the_tree_alike(monkeypatch, mode):
    """Cut short at a point's useful depth (``shadow_leaves(peak=, threshold=)``), a mask keeps
    exactly its full mask's leaves of that depth or less, in the walk and in the flat lists
    (partly covered cells at the cut are neither leaves nor split, as at an aggressive mask's
    last level; -1 drops the point). The depths here are random per point, all of -1..depth."""
    depth = 4
    x, axis, theta, dist, spheres = _scene(1200, seed=11)
    g = torch.Generator().manual_seed(3)
    last = torch.randint(-1, depth + 1, (x.shape[0],), generator=g)
    monkeypatch.setattr(_visibility, "useful_depth", lambda peak, span, t, d: last)
    kw = dict(depth=depth, mode=mode)
    cut = dict(peak=torch.ones(x.shape[0]), threshold=1.0)
    full = _visibility.shadow_leaves(x, axis, theta, dist, spheres, **kw)
    keep = full.depth <= last[full.point]
    want = _cells(full._replace(point=full.point[keep], depth=full.depth[keep],
                                u=full.u[keep], v=full.v[keep]))  # fmt: skip
    flat = _visibility.shadow_leaves(x, axis, theta, dist, spheres, **kw, **cut)
    with fusion(True):
        walked = _visibility.shadow_leaves(x, axis, theta, dist, spheres, **kw, **cut)
    assert len(want) > 1000 and int((~keep).sum()) > 1000  # not vacuous: both kinds abound
    assert _cells(flat) == want
    assert len(_cells(walked) ^ want) <= 3  # float64 inside the walk (see the test above)
    torch.testing.assert_close(walked.count, torch.bincount(walked.point, minlength=len(x)))


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
