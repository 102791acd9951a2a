"""Gaussian flipping (Green et al. 2006, sections 4.2 and 7): the order of the N Gaussians.

The data term does not see which Gaussian is "first"; the mean and sigma alignment terms across
views (M, V) and the spatial term across vertices (S) do, and the renderer interpolates
Gaussians slot by slot, so a lobe handed from one slot to the other between neighbouring views
or vertices is interpolated through the wrong lobe. :func:`lobelight.fit._optimize.relabel`
reorders a fit's Gaussians where that lowers eq. (6), which a local optimiser cannot do.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from lobelight import brdf, fit, scene
from lobelight.fit import Gaussians, Weights, _optimize, _relax
from lobelight.geometry import sphere
from lobelight.scene import _shapes

VIEWS = sphere.geodesic_views()
NBR = sphere.geodesic_neighbor_table()


def _coherent_pair() -> Gaussians:
    """One vertex whose two Gaussians, a sharp lobe and a broad one 0.6 rad apart, are the same
    in every view: a perfectly coherent fit (M = V = 0)."""
    j = VIEWS.shape[0]
    mu = torch.nn.functional.normalize(torch.tensor([[0.0, 1.0, 0.0], [0.7, 1.0, 0.0]]), dim=-1)
    mu = mu.expand(1, j, 2, 3).contiguous()
    lam = torch.tensor([200.0, 20.0]).expand(1, j, 2).contiguous()
    w = torch.tensor([[1.0, 0.5, 0.2], [0.3, 0.3, 0.3]]).expand(1, j, 2, 3).contiguous()
    return Gaussians(w, mu, lam)


def _swapped(g: Gaussians, views: torch.Tensor) -> Gaussians:
    """``g`` with its two Gaussians exchanged in ``views`` (bool (J,))."""
    s = views[None, :, None]
    return Gaussians(
        torch.where(s[..., None], g.w.flip(2), g.w),
        torch.where(s[..., None], g.mu.flip(2), g.mu),
        torch.where(s, g.lam.flip(2), g.lam),
    )


def _same(a: Gaussians, b: Gaussians) -> bool:
    return all(torch.equal(x, y) for x, y in ((a.w, b.w), (a.mu, b.mu), (a.lam, b.lam)))


def test_relabel_restores_views_whose_gaussians_were_exchanged():
    # the lobes exchanged in 16 views, no two of them neighbours (what an optimiser does when a
    # lobe lies several widths from where it was started, view by view): M and V, with every
    # other view held, prefer the original order in each
    g = _coherent_pair()
    order = torch.randperm(VIEWS.shape[0], generator=torch.Generator().manual_seed(1))
    pick = torch.zeros(VIEWS.shape[0], dtype=torch.bool)
    for v in order.tolist():
        nb = NBR[v][NBR[v] >= 0]
        if not bool(pick[nb].any()) and int(pick.sum()) < 16:
            pick[v] = True
    bad = _swapped(g, pick)
    assert not _same(bad, g)
    assert _same(_optimize.relabel(bad, NBR), g)
    # reordering never touches the data term: the same lobes, per view, as a set
    assert _same(_optimize.relabel(g, NBR), g)


def test_relabel_uses_the_spatial_term_for_a_vertex_swapped_as_a_whole():
    # every view exchanged: M and V cannot tell (the vertex is coherent across its views);
    # only S, against a processed neighbour in the original order, can
    g = _coherent_pair()
    bad = _swapped(g, torch.ones(VIEWS.shape[0], dtype=torch.bool))
    nbr_mu, nbr_mask = g.mu[:, None], torch.ones(1, 1, dtype=torch.bool)  # (B, Q, J, N, 3)
    assert _same(_optimize.relabel(bad, NBR, nbr_mu=nbr_mu, nbr_mask=nbr_mask), g)
    # without S nothing prefers either order, and nothing moves
    no_s = Weights(delta=0.0)
    assert _same(_optimize.relabel(bad, NBR, weights=no_s, nbr_mu=nbr_mu, nbr_mask=nbr_mask), bad)


def _sharp_cap() -> scene.Scene:
    """40 vertices of a 642-vertex sphere (a cap 0.5 rad wide, normals 0.14 rad apart) with a
    sharp mirror lobe (Lafortune exponent 200, width ~0.07 rad) and a broad retro-reflective
    lobe (exponent 20): between neighbouring vertices the mirror lobe moves by about four of
    its widths in every view, so a vertex started from its neighbour's fit finds the lobes
    where the neighbour's other Gaussian is, in some views."""
    v, f = _shapes.icosphere(3)
    axis = np.array([-0.2, 0.3, 0.9]) / np.linalg.norm([-0.2, 0.3, 0.9])
    keep = v @ axis > math.cos(0.5)
    faces = f[keep[f].all(1)]
    used = np.unique(faces)
    remap = np.full(len(v), -1)
    remap[used] = np.arange(len(used))
    mesh = scene.mesh_from_arrays(v[used], remap[faces])
    lobes = [
        {"cx": -1.0, "cy": -1.0, "cz": 1.0, "exponent": 200.0, "rho": [0.5 * 201 / math.tau] * 3},
        {"cx": 1.0, "cy": 1.0, "cz": 1.0, "exponent": 20.0, "rho": [0.3 * 21 / math.tau] * 3},
    ]
    mats = scene.Materials(torch.full((mesh.n_vertices, 3), 0.1), brdf.Lafortune(lobes))
    return scene.Scene(mesh, mats)


def test_flood_fill_reorders_the_lobes_the_optimiser_hands_over(monkeypatch):
    sc = _sharp_cap()
    assert sc.mesh.n_vertices == 40
    # no S and no relaxation: the reordering by M and V alone, in the flood fill's one pass
    kw = dict(n=2, weights=Weights(delta=0.0), relax=False)
    fitted = fit.fit_mesh(sc, **kw)
    # regression: vertices of one wavefront once read each other's unfitted state (zero means)
    # as processed neighbours, and a vertex started from one lost both lobes (relative error
    # squared 0.99 at 10 of these 40 vertices); measured now 7e-4
    assert float(fitted.data_error.max()) < 0.01
    monkeypatch.setattr(_optimize, "relabel", lambda g, *args, **kwargs: g)
    unordered = fit.fit_mesh(sc, **kw)
    # flipped (edge, view) pairs of Gaussians that carry light (count_flips). Measured 9 with
    # the reordering and 9 without it: with the cap's rings graded from the lobe's peak the
    # data resolve both lobes and a vertex started from its neighbour's lobes keeps them in
    # order, so here the reordering has nothing left to mend (its action on swapped views and
    # vertices is checked by the relabel tests above). It must never add flips, and 15 leaves
    # room for the LM's small hand-overs (the counts move by a few with beta +-10 %)
    assert fitted.flips_before <= unordered.flips_before
    assert fitted.flips_before <= 15


def _coherent_mesh() -> tuple[scene.Mesh, Gaussians]:
    """A 42-vertex sphere whose every vertex holds the coherent pair of :func:`_coherent_pair`:
    no flip anywhere, M = V = 0."""
    v, f = _shapes.icosphere(1)
    mesh = scene.mesh_from_arrays(v, f)
    g = _coherent_pair()
    nv = mesh.n_vertices
    return mesh, Gaussians(*(x.expand(nv, *x.shape[1:]).contiguous() for x in (g.w, g.mu, g.lam)))


def test_mesh_reordering_mends_swapped_views_and_a_vertex_swapped_as_a_whole():
    mesh, g = _coherent_mesh()
    nv, j = g.lam.shape[:2]
    assert fit.count_flips(mesh, g) == 0
    # scattered (vertex, view) nodes exchanged, mended by M and V; and vertex 0 exchanged in
    # every view: coherent across its views, so none of them gains by moving alone, and only
    # the whole-vertex move against the flip count mends it
    gen = torch.Generator().manual_seed(3)
    pick = torch.rand(nv, j, generator=gen) < 0.05
    pick[0] = True
    s = pick[..., None]
    bad = Gaussians(
        torch.where(s[..., None], g.w.flip(2), g.w),
        torch.where(s[..., None], g.mu.flip(2), g.mu),
        torch.where(s, g.lam.flip(2), g.lam),
    )
    assert fit.count_flips(mesh, bad) > 200
    calls = []
    fixed = _relax.reorder_mesh(mesh, bad, NBR, progress=lambda *a: calls.append(a))
    assert _same(fixed, g)
    # one call per sweep made, the last one closing the stage at the sweeps it made
    stages, done, totals = zip(*calls, strict=True)
    assert set(stages) == {"reorder"} and done == tuple(range(1, len(calls) + 1))
    assert totals[:-1] == (64,) * (len(calls) - 1) and totals[-1] == done[-1] < 64


def test_relaxation_reduces_flips_on_a_sphere():
    # The smoothness term S plus the relaxation reduce flips: sphere:2 (162 vertices), two
    # Gaussians per view. The relaxation refits each vertex with S against all its neighbours,
    # keeping the new lobes only where they add no flipped pair, then reorders the whole mesh.
    # Measured (2-core CPU): flipped pairs 273 -> 220 (0.81x), among lobes at least half a
    # width apart 51 -> 0, mean fit error 0.1487. The paper's refit alone adds flips
    # (docs/method.md), so the bounds below fail for it; 0.95 leaves room for platform
    # differences. (On sphere:1 the flood fill already ends where the relaxation would: 124
    # flipped pairs before and after.)
    mf = fit.fit_mesh(scene.load("sphere:2"), n=2, relax=True)
    assert mf.flips_after < 0.95 * mf.flips_before
    assert mf.separated_flips_after <= 0.7 * mf.separated_flips_before
