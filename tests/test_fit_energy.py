"""Energy-true lobes: the fitted glossy transport keeps each (vertex, view) function's integral.

The truth is :func:`lobelight.studies.energy.reference_integral`, a dense nested-shell quadrature
of the transport with visibility (checked here against SG integrals and BRDF importance sampling).
Materials are Fresnel-free GGX and Beckmann metals at alpha 0.02 (mirror-like), 0.1 and 0.5
(rough), on a sphere (nothing occludes) and next to a wall (the lobes of views from the open
side point into the wall: visibility cuts them).
"""

from __future__ import annotations

import pytest
import torch

from lobelight import fit, scene, transport
from lobelight.fit._objective import solve_gram
from lobelight.geometry import sphere
from lobelight.lobes import sg
from lobelight.studies import energy

VIEWS = sphere.geodesic_views()
NBR = sphere.geodesic_neighbor_table()
#: Sphere vertices; floor vertices of the wall scene (9 x 9 grid, wall at z = -1): 12 is 0.25
#: from the wall, 22 is 0.5 from it.
SPHERE_VERTICES = torch.tensor([17, 101])
WALL_VERTICES = torch.tensor([12, 22])


@pytest.fixture(scope="module")
def shapes():
    return {
        "sphere": (scene.builtin("sphere", subdivisions=2), SPHERE_VERTICES),
        "wall": (energy.wall_scene(), WALL_VERTICES),
    }


def _ratios(shape, model, alpha, *, conserve=True):
    sc, vidx = shape
    tr = transport.Transport(energy.metal(sc, model, alpha))
    ref = energy.reference_integral(tr, vidx, VIEWS)[..., 0]
    data = fit.gather(tr, vidx, VIEWS)
    g, _ = fit.fit_batch(data, 1, NBR, conserve=conserve)
    seen = (data.weights[..., None] * data.values).sum(2)[..., 0]
    carried = energy.fitted_integral(g)[..., 0]
    # functions with at least 2 % of light (above the horizon, not all but wholly occluded): a
    # lobe inside the wall leaks a few thousandths through its tails, whose ratio is noise
    ok = ref > 0.02
    cosv = (VIEWS[None] * sc.mesh.normals[vidx][:, None]).sum(-1)
    return (seen / ref)[ok], (carried / ref)[ok], cosv[ok]


def test_reference_rule_integrates_sgs_of_any_width():
    axis = torch.nn.functional.normalize(torch.tensor([[0.3, 0.5, 0.8]]), dim=-1)
    off = torch.nn.functional.normalize(axis + torch.tensor([[0.1, 0.0, 0.0]]), dim=-1)
    d, w = energy.reference_rule(axis)
    for lam in (1.0, 30.0, 1e3, 3e4):
        exact = sg.integral(torch.tensor(lam))
        got = (sg.evaluate(d, axis[:, None], torch.tensor(lam)) * w).sum()
        assert abs(float(got / exact) - 1) < 1e-6, lam
        if lam <= 1e3:
            got = (sg.evaluate(d, off[:, None], torch.tensor(lam)) * w).sum()
            assert abs(float(got / exact) - 1) < 1e-5, lam


@pytest.mark.parametrize(("model", "alpha"), [("ggx", 0.02), ("beckmann", 0.5)])
def test_reference_integral_is_the_directional_albedo_without_occlusion(shapes, model, alpha):
    sc, _ = shapes["sphere"]
    tr = transport.Transport(energy.metal(sc, model, alpha))
    vidx = torch.tensor([0, 17])
    ref = energy.reference_integral(tr, vidx, VIEWS)[..., 0]
    mc, se = energy.albedo_mc(tr, vidx, VIEWS, count=4000)
    cosv = (VIEWS[None] * sc.mesh.normals[vidx][:, None]).sum(-1)
    ok = cosv > 0.01  # a view exactly at the horizon is degenerate for both
    # measured: within 1e-4 of the estimate beyond its 3 standard errors (2e-3 at alpha 0.5)
    err = (ref - mc[..., 0]).abs()[ok] - 3 * se[..., 0][ok]
    assert float((err / mc[..., 0][ok]).max()) < 3e-3


@pytest.mark.parametrize("model", ["ggx", "beckmann"])
@pytest.mark.parametrize("alpha", [0.02, 0.1, 0.5])
@pytest.mark.parametrize("where", ["sphere", "wall"])
def test_fitted_lobes_keep_their_integral(shapes, model, alpha, where):
    seen, carried, cosv = _ratios(shapes[where], model, alpha)
    # the fit carries the light of the data it sees (the constraint), to rounding
    torch.testing.assert_close(carried, seen, rtol=1e-4, atol=0)
    # and that is the truth: on average within 2 % (measured mean |1 - ratio|: sphere 0.02-0.6
    # %, wall 0.06-1.4 %, where the visibility cut's edge crosses the cap's rings)
    dev = (carried - 1).abs()
    assert abs(float(carried.mean()) - 1) < 0.02 and float(dev.mean()) < 0.02
    # per function, away from the horizon's last degree (n.v < 0.02, where a sharp lobe is a
    # sliver thinner than either quadrature resolves; measured up to 7 % there): within 3 %
    # without occlusion (measured 2.0 % at worst) and within 20 % where the wall cuts the
    # lobe (measured 15 % at worst, p1-p99 0.90-1.12)
    bound = 0.03 if where == "sphere" else 0.2
    assert float(dev[cosv >= 0.02].max()) < bound


def test_unconstrained_fit_loses_the_tails_light(shapes):
    # the L2 optimum of one Gaussian follows a GGX lobe's peak and drops its tails: what the
    # default fit (conserve=True) exists for; measured mean ratio 0.74 at alpha 0.1
    _, carried, _ = _ratios(shapes["sphere"], "ggx", 0.1, conserve=False)
    assert float(carried.mean()) < 0.85


def test_window_integrates_grazing_views_of_sharp_lobes(shapes):
    # a microfacet lobe at a grazing view is a sliver in light directions (squeezed by 2 v.h
    # across the plane of incidence): the data's quadrature lays its rings over half vectors,
    # where the lobe is round, and keeps the integral; measured within 0.4 % at n.v >= 0.02
    sc, vidx = shapes["sphere"]
    tr = transport.Transport(energy.metal(sc, "ggx", 0.02))
    ref = energy.reference_integral(tr, vidx, VIEWS)[..., 0]
    data = fit.gather(tr, vidx, VIEWS)
    seen = (data.weights[..., None] * data.values).sum(2)[..., 0]
    cosv = (VIEWS[None] * sc.mesh.normals[vidx][:, None]).sum(-1)
    graz = (cosv > 0.02) & (cosv < 0.2)
    assert int(graz.sum()) >= 10
    assert float((seen / ref - 1)[graz].abs().max()) < 0.02


def test_constrained_weights_carry_the_light_and_are_least_squares_on_the_constraint():
    g = torch.Generator().manual_seed(0)
    m = torch.randn(2, 3, 2, 2, generator=g, dtype=torch.float64)
    a = m @ m.transpose(-1, -2) + 0.5 * torch.eye(2, dtype=torch.float64)  # (B, J, 2, 2) SPD
    rhs = torch.rand(2, 3, 2, 3, generator=g, dtype=torch.float64)
    lam = torch.tensor([5.0, 50.0], dtype=torch.float64).expand(2, 3, 2)
    below = torch.zeros(2, 3, dtype=torch.bool)
    light = torch.rand(2, 3, 3, generator=g, dtype=torch.float64)
    w = solve_gram(a, rhs, lam, below, light, ridge=0.0)
    z = sg.integral(lam)
    torch.testing.assert_close((w * z[..., None]).sum(-2), light)

    def cost(x):  # the L2 objective up to a constant: x^T A x - 2 b.x, per channel
        return torch.einsum("bjkc,bjkl,bjlc->bjc", x, a, x) - 2 * (x * rhs).sum(-2)

    # moving along the constraint (a step that keeps sum_k w_k Z_k) never lowers the cost,
    # where the solution is interior (no weight clamped)
    step = torch.stack([z[..., 1], -z[..., 0]], -1)[..., None] * 1e-3  # (B, J, 2, 1)
    inner = (w > 1e-9).all(-2)  # (B, J, 3)
    for sgn in (1, -1):
        moved = cost(w + sgn * step) - cost(w)
        assert bool((moved[inner] >= -1e-12).all())
    # one lobe: the weight is the light over the lobe's integral
    w1 = solve_gram(a[..., :1, :1], rhs[..., :1, :], lam[..., :1], below, light)
    torch.testing.assert_close(w1[..., 0, :], light / z[..., :1])
