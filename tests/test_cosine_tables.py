"""Tests of lobelight.cosine: cosine lobes, the product and spherical-cap tables, lookup, cache.

References are independent of the code under test:

* scipy adaptive quadrature over the sphere in polar coordinates about one lobe's axis, with the
  azimuthal range where the other lobe is positive found analytically (:func:`ref_product_2d`);
  it checks the module's separated "closed-form theta times 1-D lune integral" quadrature;
* scipy adaptive quadrature of the separated 1-D integrals (:func:`ref_lune`) for the
  statistics over many random products (the separation itself is checked by the 2-D reference);
* dense brute-force searches for the product axis and the cap exponent, and scipy's
  Levenberg-Marquardt on ``(p, e)`` (the paper's method) for the product fit;
* quasi-uniform (Fibonacci) sphere sums for L2 residuals.

The default tables are built once per test session into the session's temporary cache and
shared with the other modules.
"""

from __future__ import annotations

import math
import zipfile

import numpy as np
import pytest
import torch
from scipy import integrate, optimize, special

from lobelight import cosine as C
from lobelight.bench import bench_tables
from lobelight.cosine import _tables
from lobelight.errors import InputError
from lobelight.geometry import sphere as S

F64 = torch.float64

# A tiny grid: 19 exponents x 22 angles, fitted in well under a second; for the plumbing tests
# (cache, indexing, symmetry), not for accuracy.
SMALL = C.TableParams(
    per_decade=3,
    angle_uniform=12,
    angle_grading=1.0,
    angle_pi_grading=0.5,
    cap_nodes=50,
    quad_nodes=16,
)


@pytest.fixture(scope="module")
def tables():
    """The default tables from the session's private cache (conftest sets ``LOBELIGHT_CACHE``
    to a temporary folder, never the user's): built once per session, here or by another
    module that shades with them, and read back from the file."""
    t = C.get_tables()
    assert t.info["unconverged_fits"] == 0
    return t


@pytest.fixture(autouse=True)
def _fresh_memo():
    """Each test sees an empty in-memory table cache (files are what the tests are about)."""
    _tables._MEMO.clear()
    yield
    _tables._MEMO.clear()


DEFAULT = C.TableParams()


def table_samples(n: int, seed: int, params: C.TableParams = DEFAULT):
    """Random ``(e1, e2, angle)`` uniform in the table's own coordinates
    (``log10(e + 0.1)`` and angle): every region of the table gets its share."""
    g = torch.Generator().manual_seed(seed)
    u0, u1 = params._u_range
    u = torch.rand(n, 2, dtype=F64, generator=g) * (u1 - u0) + u0
    e = (10**u - params.e_offset).clamp_min(0)
    angle = torch.rand(n, dtype=F64, generator=g) * math.pi
    return e[:, 0], e[:, 1], angle


def relevant(e1, e2, integral):
    """Products holding at least 0.1 % of the smaller lobe's energy: the ones a shading sum sees
    (the rest are culled by any sensible threshold, paper section 4.3)."""
    return integral >= 1e-3 * torch.minimum(C.integral(e1), C.integral(e2))


# --------------------------------------------------------------------------------------------
# independent references


def ref_product_2d(e1: float, e2: float, alpha: float, power: int = 1) -> float:
    """``∫ (c1 c2)^power dw`` by nested scipy quadrature, polar angle ``t`` about ``a1``.

    ``a2 . w = cos t cos alpha + sin t sin alpha cos phi`` is positive for ``|phi| < phi_m(t)``
    (closed form), so the inner integral runs over exactly that range and the integrand is
    smooth inside it; break points sit at the product's peak and its width.
    """
    ca, sa = math.cos(alpha), math.sin(alpha)
    k1, k2 = power * e1, power * e2
    width = 1 / math.sqrt(k1 + k2 + 1)
    beta = float(C.product_peak(torch.tensor(e1, dtype=F64), e2, alpha)[0])  # guides break points

    def inner(t):  # ∫ c2 dphi at polar angle t; absolute 1e-15: near the lune's tip it is ~0
        st, ct = math.sin(t), math.cos(t)
        if sa * st < 1e-300:
            return 2 * math.pi * max(ct * ca, 0.0) ** k2 if ct * ca > 0 or k2 == 0 else 0.0
        x = -ct * ca / (st * sa)
        if x >= 1:
            return 0.0
        phi_m = math.pi if x <= -1 else math.acos(x)

        def f(phi):
            v = ct * ca + st * sa * math.cos(phi)
            return v**k2 if v > 0 else (1.0 if k2 == 0 else 0.0)

        if 0 < k2 < 1 and phi_m < math.pi:
            # v ~ (phi_m - phi) at the edge: integrate (v / (phi_m - phi))^k2 against the
            # algebraic weight (phi_m - phi)^k2 (QUADPACK's QAWS), smooth inside
            def smooth(phi):
                d = phi_m - phi
                if d <= 0:
                    return (st * sa * math.sin(phi_m)) ** k2
                # cos(phi) - cos(phi_m) without cancellation
                gap = 2 * math.sin((phi_m + phi) / 2) * math.sin(d / 2)
                return (st * sa * gap / d) ** k2

            val, _ = integrate.quad(
                smooth, 0, phi_m, weight="alg", wvar=(0, k2), epsabs=1e-15, epsrel=1e-10, limit=200
            )
            return 2 * val
        pts = [p for p in (width / st, 3 * width / st, 10 * width / st) if p < phi_m]
        val, _ = integrate.quad(
            f, 0, phi_m, points=pts or None, limit=200, epsabs=1e-15, epsrel=1e-10
        )
        return 2 * val

    def outer(t):
        return math.cos(t) ** k1 * inner(t) * math.sin(t)

    t0 = max(alpha - math.pi / 2, 0.0)  # below t0 the lobes do not overlap
    if 0 < k1 < 1:
        # cos(t)^k1 ~ (pi/2 - t)^k1 at the horizon: algebraic weight (QAWS), smooth remainder
        def smooth(t):
            d = math.pi / 2 - t
            return (math.cos(t) / d) ** k1 * inner(t) * math.sin(t) if d > 0 else inner(t)

        val, _ = integrate.quad(
            smooth, t0, math.pi / 2, weight="alg", wvar=(0, k1), epsabs=0, epsrel=1e-10, limit=400
        )
        return val
    pts = sorted({min(max(beta + k * width, t0), math.pi / 2) for k in (-10, -3, -1, 0, 1, 3, 10)})
    pts = [p for p in pts if t0 < p < math.pi / 2]
    val, _ = integrate.quad(
        outer, t0, math.pi / 2, points=pts or None, limit=400, epsabs=0, epsrel=1e-11
    )
    return val


def _log_k(n):
    """log ∫_0^pi sin^n (closed form, scipy)."""
    return 0.5 * math.log(math.pi) + special.gammaln((n + 1) / 2) - special.gammaln(n / 2 + 1)


def ref_lune(e1, e2, alpha, beta, e_r, power=1):
    """``log ∫ (c1 c2)^power max(a_r.w,0)^e_r dw`` by scipy's adaptive quadrature of the
    separated form (module docstring of ``lobelight.cosine._lobe``; checked against
    :func:`ref_product_2d` below). ``a_r`` is at ``beta`` from ``a1``; the integrand is scaled
    by its own peak so that products of 1e-300 and less keep their digits."""
    k1, k2 = power * e1, power * e2
    lo, hi = alpha - math.pi / 2, math.pi / 2

    def logf(lam):
        c1, c2 = math.cos(lam), math.cos(lam - alpha)
        out = 0.0
        for k, c in ((k1, c1), (k2, c2)):
            if k:
                out += k * math.log(c) if c > 0 else -math.inf
        return out

    peak = logf(min(max(beta, lo + 1e-12), hi - 1e-12))

    def f(lam):
        g = logf(lam) - peak
        cr = math.cos(lam - beta)
        return math.exp(g + (e_r * math.log(cr) if e_r else 0.0)) if cr > 0 else 0.0

    width = 1 / math.sqrt(k1 + k2 + e_r + 1)
    pts = sorted({min(max(beta + k * width, lo), hi) for k in (-30, -10, -3, -1, 0, 1, 3, 10, 30)})
    pts = [p for p in pts if lo < p < hi]
    val, _ = integrate.quad(f, lo, hi, points=pts or None, limit=500, epsabs=0, epsrel=1e-10)
    return math.log(val) + peak + _log_k(k1 + k2 + e_r + 1) if val > 0 else -math.inf


# --------------------------------------------------------------------------------------------
# single lobes


@pytest.mark.parametrize("e", [0.0, 0.3, 1.0, 7.5, 100.0, 1e5])
def test_integral_closed_form_matches_quadrature(e):
    # 2 pi ∫_0^{pi/2} cos^e sin dtheta by adaptive quadrature; float64 quad reaches ~1e-12.
    width = 1 / math.sqrt(e + 1)
    pts = [min(k * width, math.pi / 2) for k in (1, 3, 10)]
    ref, _ = integrate.quad(
        lambda t: math.cos(t) ** e * math.sin(t), 0, math.pi / 2, points=pts, epsrel=1e-13
    )
    assert float(C.integral(torch.tensor(e, dtype=F64))) == pytest.approx(2 * math.pi * ref, 1e-10)
    s = torch.tensor([2.0, 3.0], dtype=F64)
    torch.testing.assert_close(C.integral(torch.tensor(e, dtype=F64), s), 2 * math.pi * ref * s)


def test_evaluate_horizon_scale_and_numpy():
    axis = np.array([0.0, 1.0, 0.0])
    dirs = np.array([[0.0, 1.0, 0.0], [0.6, 0.8, 0.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    out = C.evaluate(dirs, axis, 2.0)
    assert isinstance(out, np.ndarray)  # numpy in, numpy out
    np.testing.assert_allclose(out, [1.0, 0.64, 0.0, 0.0])
    # e = 0 is the open hemisphere (the paper's c_unit, eq. 40)
    np.testing.assert_allclose(C.evaluate(dirs, axis, 0.0), [1, 1, 0, 0])
    np.testing.assert_allclose(C.evaluate(dirs, axis, 2.0, np.full(4, 3.0)), 3 * out)
    with pytest.raises(InputError, match="axis"):
        C.evaluate(dirs, np.zeros(2), 1.0)


def test_from_vector_puts_the_length_into_the_scale():
    # Lafortune lobes: max(v.w, 0)^e = |v|^e max((v/|v|).w, 0)^e
    v = torch.tensor([0.3, 1.2, -0.4], dtype=F64)
    dirs = S.fibonacci(200, dtype=F64)[0]
    axis, scale = C.from_vector(v, 3.5)
    direct = ((dirs @ v).clamp_min(0)) ** 3.5
    torch.testing.assert_close(C.evaluate(dirs, axis, 3.5, scale), direct)


# --------------------------------------------------------------------------------------------
# the product: peak, exact integral, fit


@pytest.mark.parametrize(
    "e1, e2, alpha",
    [(1.0, 1.0, 0.7), (0.5, 3.0, 1.4), (0.0, 4.0, 1.0), (2.0, 0.0, 2.2), (40.0, 10.0, 0.4),
     (1e3, 3e3, 0.05), (1e4, 1e4, 0.02), (5.0, 2e4, 1.55), (0.7, 0.2, 2.9)],
)  # fmt: skip
def test_product_integral_matches_sphere_quadrature(e1, e2, alpha):
    # The module integrates over the lune after separating theta (closed form); the reference is
    # 2-D adaptive quadrature in other coordinates. Both are float64: 1e-8 leaves room for the
    # references' own tolerance (1e-11 per level, the inner level summed by the outer).
    ref = ref_product_2d(e1, e2, alpha)
    got = float(C.product_integral(torch.tensor(e1, dtype=F64), e2, alpha))
    assert got == pytest.approx(ref, rel=1e-8)


def test_product_peak_is_the_maximiser():
    # Brute force: log(c1 c2) on 400001 points of the arc (-inf where a lobe is 0); the closed
    # form must be at least as high (to float64 rounding) and within two grid steps of the best
    # point. The first three cases: both exponents 0 (every point of the lune is a maximum, the
    # convention is the bisector), and a zero exponent with the axes more than pi/2 apart (the
    # peak is on that lobe's horizon).
    g = torch.Generator().manual_seed(3)
    n = 24
    e1 = torch.cat([torch.tensor([0.0, 0.0, 3.0]), 10 ** (torch.rand(n, generator=g) * 6 - 1)])
    e2 = torch.cat([torch.tensor([0.0, 2.0, 0.0]), 10 ** (torch.rand(n, generator=g) * 6 - 1)])
    alpha = torch.cat([torch.tensor([1.0, 2.5, 2.0]), torch.rand(n, generator=g) * 3.1])
    e1, e2, alpha = e1.double(), e2.double(), alpha.double()
    beta, log_peak = C.product_peak(e1, e2, alpha)
    grid = alpha[:, None] * torch.linspace(0, 1, 400001, dtype=F64)  # (m, k) angles from a1
    c1, c2 = torch.cos(grid), torch.cos(alpha[:, None] - grid)
    vals = torch.special.xlogy(e1[:, None], c1.clamp_min(0)) + torch.special.xlogy(
        e2[:, None], c2.clamp_min(0)
    )
    vals = torch.where((c1 > 0) & (c2 > 0), vals, -math.inf)
    best = vals.max(-1)
    assert torch.all(log_peak >= best.values - 1e-9 * best.values.abs().clamp_min(1))
    at = grid[torch.arange(len(e1)), best.indices]
    step = float(alpha.max()) / 400000
    torch.testing.assert_close(beta[1:], at[1:], atol=2 * step, rtol=0)
    assert float(beta[0]) == pytest.approx(0.5)  # the bisector
    assert float(beta[1]) == pytest.approx(math.pi / 2)  # on a1's horizon
    assert float(beta[2]) == pytest.approx(2.0 - math.pi / 2)  # on a2's horizon


def test_same_axis_product_is_exact(tables):
    # Parallel axes: c1 c2 = s1 s2 max(a.w,0)^(e1+e2), a cosine lobe, so the fit is exact.
    e1 = torch.tensor([0.0, 0.0, 0.5, 3.0, 1e2, 7e3, 1e5, 1e5], dtype=F64)
    e2 = torch.tensor([0.0, 2.0, 0.5, 11.0, 30.0, 250.0, 1e5, 3e5], dtype=F64)
    zero = torch.zeros_like(e1)
    beta, scale, exponent, rel = C.fit_product(e1, e2, zero)
    assert torch.all(beta == 0)
    # direct fit: Newton stops at a step of 1e-9 in log(1 + e); q is a float64 ratio of sums
    torch.testing.assert_close(exponent, e1 + e2, rtol=1e-8, atol=1e-9)
    torch.testing.assert_close(scale, torch.ones_like(scale), rtol=1e-8, atol=0)
    # rel = sqrt(1 - <f,g>^2 / (|f|^2 |g|^2)): a quadrature error of ~1e-10 in the ratio (sharp
    # lobes, 65-node rules) leaves a floor of ~2e-5
    assert torch.all(rel < 1e-4)
    # the table, through axes and scales; float32 storage -> 1e-6
    a = torch.tensor([0.0, 0.6, 0.8], dtype=F64)
    s1, s2 = torch.full_like(e1, 2.5), torch.full_like(e1, 0.4)
    axis, exp_t, scale_t = C.product(a, e1, a, e2, s1, s2, tables=tables)
    torch.testing.assert_close(axis, a.expand_as(axis))
    torch.testing.assert_close(exp_t, e1 + e2, rtol=1e-6, atol=1e-6)
    torch.testing.assert_close(scale_t, s1 * s2, rtol=1e-6, atol=0)
    # exact integral: 2 pi s1 s2 / (e1 + e2 + 1) = ∫ c1 c2, in both scale modes
    exact = C.integral(e1 + e2) * s1 * s2
    torch.testing.assert_close(C.integral(exp_t, scale_t), exact, rtol=2e-6, atol=0)
    _, exp_i, scale_i = C.product(a, e1, a, e2, s1, s2, tables=tables, preserve_integral=True)
    torch.testing.assert_close(C.integral(exp_i, scale_i), exact, rtol=2e-6, atol=0)
    # tanh-sinh on the lune: measured 8e-12 at e1 + e2 = 4e5, 1e-15 for broad lobes
    torch.testing.assert_close(
        C.product_integral(e1, e2, zero) * s1 * s2, exact, rtol=1e-10, atol=0
    )


@pytest.mark.parametrize("e1, e2, alpha", [(1.0, 2.0, 0.8), (6.0, 15.0, 0.5), (0.5, 30.0, 1.3)])
def test_fit_matches_levenberg_marquardt_on_the_sphere(e1, e2, alpha):
    # The paper's second step: LM on (p, e) minimising ∫ (c1 c2 - p cos^e)^2 over the sphere,
    # here scipy's LM on a 60000-point Fibonacci sum (weights 4 pi / n) with the axis from the
    # closed form. The sum's error (~1e-4 relative for these widths) bounds the agreement.
    dirs, w = S.fibonacci(60000, dtype=F64)
    a1 = torch.tensor([0.0, 1.0, 0.0], dtype=F64)
    a2 = torch.tensor([math.sin(alpha), math.cos(alpha), 0.0], dtype=F64)
    beta, scale, exponent, _ = C.fit_product(torch.tensor(e1, dtype=F64), e2, alpha)
    ar = torch.tensor([math.sin(float(beta)), math.cos(float(beta)), 0.0], dtype=F64)
    f = (C.evaluate(dirs, a1, e1) * C.evaluate(dirs, a2, e2)).numpy()
    cos_r = (dirs @ ar).clamp_min(0).numpy()
    sw = np.sqrt(w.numpy())

    def resid(x):
        p, e = x
        return sw * (f - p * np.where(cos_r > 0, cos_r ** max(e, 0.0), 0.0))

    lm = optimize.least_squares(resid, x0=[1.0, e1 + e2], method="lm", xtol=1e-12, ftol=1e-12)
    p_lm, e_lm = lm.x
    assert float(exponent) == pytest.approx(e_lm, rel=2e-3)
    assert float(scale) == pytest.approx(p_lm, rel=2e-3)


# --------------------------------------------------------------------------------------------
# the product table


def test_small_table_is_exact_at_nodes_and_symmetric():
    # At grid nodes trilinear interpolation returns the node: lookup == direct fit up to the
    # float32 storage (1e-6), for both orders of (e1, e2) - this pins the triangle indexing.
    t = C.build_tables(SMALL)
    ex, an = SMALL.exponent_nodes(), SMALL.angle_nodes()
    g = torch.Generator().manual_seed(5)
    i, j = torch.randint(0, len(ex), (2, 200), generator=g)
    k = torch.randint(0, len(an) - 1, (200,), generator=g)
    e1, e2, alpha = ex[i], ex[j], an[k]
    _, s_fit, e_fit, _ = C.fit_product(e1, e2, alpha, nodes=SMALL.quad_nodes)
    for a, b in ((e1, e2), (e2, e1)):
        _, s_tab, e_tab = t.product(a, b, alpha)
        torch.testing.assert_close(e_tab, e_fit, rtol=1e-5, atol=1e-6)
        torch.testing.assert_close(s_tab, s_fit, rtol=1e-5, atol=1e-30)
    # swapping the lobes mirrors the axis: beta(e2, e1) = alpha - beta(e1, e2)
    torch.testing.assert_close(t.product(e2, e1, alpha)[0], alpha - t.product(e1, e2, alpha)[0])


def test_table_lookups_match_direct_fits_off_grid(tables):
    # 600 random points uniform in table coordinates. Tolerances from a 20000-point run of the
    # same comparison (mean 1.9e-4, 99th percentile ~2e-3, max 8.6e-2 in the corner where both
    # exponents are < 0.1: c1 c2 is nearly flat over the lune there, its peak - the paper's axis -
    # jumps with e1/e2 and the fit itself is poor, relative L2 error > 0.5), with margin.
    e1, e2, alpha = table_samples(600, seed=11)
    _, s_fit, e_fit, _ = C.fit_product(e1, e2, alpha)
    _, s_tab, e_tab = tables.product(e1, e2, alpha)
    i_fit, i_tab = C.integral(e_fit, s_fit), C.integral(e_tab, s_tab)
    exact = C.product_integral(e1, e2, alpha)
    keep = relevant(e1, e2, exact)
    err = (i_tab / i_fit - 1).abs()[keep]
    assert keep.sum() > 200
    assert float(err.mean()) < 1e-3
    assert float(err.quantile(0.95)) < 2e-3
    assert float(err.max()) < 0.15
    # away from the flat corner the exponent and the integral interpolate to < 2 %
    main = (torch.maximum(e1, e2) > 0.1)[keep]
    assert float(err[main].max()) < 2e-2
    assert float(((e_tab / e_fit - 1).abs()[keep][main]).quantile(0.95)) < 2e-3


def test_exponents_beyond_the_table(tables):
    # Above 1e5 the lookup keeps e1 : e2 (the sharp limit depends on the ratio only). Measured
    # <= 2e-5 against direct fits for these; 1e-3 bounds it with margin.
    e1 = torch.tensor([3e5, 1e6, 1e6, 2e5, 5e5], dtype=F64)
    e2 = torch.tensor([3e5, 1e6, 2.0, 1e5, 0.5], dtype=F64)
    alpha = torch.tensor([0.002, 0.001, 0.3, 0.004, 1.0], dtype=F64)
    _, s_fit, e_fit, _ = C.fit_product(e1, e2, alpha)
    _, s_tab, e_tab = tables.product(e1, e2, alpha)
    torch.testing.assert_close(e_tab, e_fit, rtol=1e-3, atol=0)
    torch.testing.assert_close(s_tab, s_fit, rtol=1e-3, atol=0)


def test_product_table_accuracy_against_adaptive_quadrature(tables):
    """The approximation error of the table, against scipy adaptive quadrature.

    Measures, on 250 products uniform in table coordinates (unit scales):

    * the paper's measure (its section 4.1): ``|∫ c1 c2 - ∫ c_r|``, the absolute difference of
      integrals (the paper: mean 7.1e-4, median 0, for its own random products);
    * the relative L2 error ``||c1 c2 - c_r|| / ||c1 c2||`` over the sphere, on products that
      hold at least 0.1 % of the smaller lobe's energy.

    With the paper's L2-best scale the integral measure is ~1.5e-3 on this (hard) sample: a
    single lobe is not the product, and the L2 fit does not keep its integral - the direct fit
    does the same, so the table adds nothing. With ``preserve_integral`` the measure is ~1e-4,
    better than the paper's figure. The numbers are printed (``pytest -rP`` shows them).
    """
    e1, e2, alpha = table_samples(250, seed=21)
    beta, s_l2, e_r = tables.product(e1, e2, alpha)
    _, s_int, _ = tables.product(e1, e2, alpha, preserve_integral=True)
    _, log_peak = C.product_peak(e1, e2, alpha)
    rows = []
    for k in range(len(e1)):
        a, b, al, be, er = (float(x[k]) for x in (e1, e2, alpha, beta, e_r))
        if al >= math.pi or not math.isfinite(float(log_peak[k])):
            continue
        i_f = ref_lune(a, b, al, be, 0.0)  # log ∫ c1 c2
        i_ff = ref_lune(a, b, al, be, 0.0, power=2)  # log ∫ (c1 c2)^2
        i_fg = ref_lune(a, b, al, be, er)  # log ∫ c1 c2 cos^e_r
        i_gg = math.log(2 * math.pi / (2 * er + 1))
        rows.append((k, i_f, i_ff, i_fg, i_gg))
    k = torch.tensor([r[0] for r in rows])
    i_f, i_ff, i_fg, i_gg = (torch.tensor([r[j] for r in rows], dtype=F64) for j in range(1, 5))
    exact = i_f.exp()
    # paper measure, both scale modes
    paper_l2 = (C.integral(e_r[k], s_l2[k]) - exact).abs()
    paper_int = (C.integral(e_r[k], s_int[k]) - exact).abs()
    # relative L2 error of the table's lobe (L2 scale): 1 - 2 p <f,g>/|f|^2 + p^2 |g|^2/|f|^2
    p = s_l2[k]
    rel2 = 1 - 2 * p * (i_fg - i_ff).exp() + p * p * (i_gg - i_ff).exp()
    rel_l2 = rel2.clamp_min(0).sqrt()
    keep = relevant(e1[k], e2[k], exact)
    stats = {
        "paper_measure_mean": float(paper_l2.mean()),
        "paper_measure_max": float(paper_l2.max()),
        "paper_measure_median": float(paper_l2.median()),
        "paper_measure_mean_preserve_integral": float(paper_int.mean()),
        "rel_l2_mean": float(rel_l2[keep].mean()),
        "rel_l2_max": float(rel_l2[keep].max()),
    }
    print("product-table accuracy:", {k: f"{v:.3g}" for k, v in stats.items()})
    # Bounds: the paper's mean (7.1e-4) for the integral-preserving lookup; for the L2 scale
    # the direct fit's own mean on 20000 such samples (1.5e-3) plus margin, since the table
    # must add (almost) nothing to the fit's error.
    assert stats["paper_measure_mean_preserve_integral"] < 7.1e-4
    assert stats["paper_measure_mean"] < 3e-3
    # the direct fit's relative L2 error on such samples: mean 0.12, max 0.98 (the fit, not the
    # table: the table adds 1.6e-5 on average); keep the table honest against a drift
    _, _, _, rel_fit = C.fit_product(e1[k], e2[k], alpha[k])
    assert float((rel_l2 - rel_fit)[keep].mean()) < 1e-3
    assert float((rel_l2 - rel_fit)[keep].max()) < 5e-2


def test_quadrature_references_agree():
    # The separated 1-D reference used above against the 2-D one, on a few products.
    for e1, e2, alpha in ((0.5, 3.0, 1.4), (40.0, 10.0, 0.4), (2.0, 0.0, 2.2)):
        beta = float(C.product_peak(torch.tensor(e1, dtype=F64), e2, alpha)[0])
        one_d = math.exp(ref_lune(e1, e2, alpha, beta, 0.0))
        assert one_d == pytest.approx(ref_product_2d(e1, e2, alpha), rel=1e-8)
        one_d_sq = math.exp(ref_lune(e1, e2, alpha, beta, 0.0, power=2))
        assert one_d_sq == pytest.approx(ref_product_2d(e1, e2, alpha, power=2), rel=1e-8)


def test_lookup_dtypes_devices_and_numpy(tables, device):
    e1, e2, alpha = table_samples(64, seed=2)
    ref = tables.product(e1, e2, alpha)
    dev_tables = tables.to(device)
    got = dev_tables.product(e1.float().to(device), e2.float().to(device), alpha.float().to(device))
    for r, g in zip(ref, got, strict=True):
        assert g.device.type == device and g.dtype == torch.float32
        # float32 queries: the exact peak loses ~e * 1e-7 relative to rounding of the angle
        torch.testing.assert_close(g.cpu().double(), r, rtol=2e-3, atol=1e-30)
    out = tables.product(e1.numpy(), e2.numpy(), alpha.numpy())
    assert all(isinstance(x, np.ndarray) for x in out)


def test_product_lobes_axis_lies_between_the_axes(tables):
    g = torch.Generator().manual_seed(8)
    a1 = torch.nn.functional.normalize(torch.randn(50, 3, dtype=F64, generator=g), dim=-1)
    a2 = torch.nn.functional.normalize(torch.randn(50, 3, dtype=F64, generator=g), dim=-1)
    e1, e2 = torch.full((50,), 20.0, dtype=F64), torch.full((50,), 5.0, dtype=F64)
    axis, exponent, scale = tables.product_lobes(a1, e1, a2, e2)
    alpha = torch.arccos((a1 * a2).sum(-1).clamp(-1, 1))
    beta, scale_ref, exp_ref = tables.product(e1, e2, alpha)
    torch.testing.assert_close(torch.linalg.vector_norm(axis, dim=-1), torch.ones(50, dtype=F64))
    torch.testing.assert_close(
        torch.arccos((axis * a1).sum(-1).clamp(-1, 1)), beta, atol=1e-6, rtol=0
    )
    torch.testing.assert_close(
        torch.arccos((axis * a2).sum(-1).clamp(-1, 1)), alpha - beta, atol=1e-6, rtol=0
    )
    torch.testing.assert_close(exponent, exp_ref)
    torch.testing.assert_close(scale, scale_ref)


def test_bad_input_raises():
    t = C.build_tables(SMALL)
    with pytest.raises(InputError, match="e1"):
        t.product(torch.tensor([-1.0]), 1.0, 0.5)
    with pytest.raises(InputError, match="e2"):
        C.fit_product(1.0, torch.tensor([float("nan")]), 0.5)
    with pytest.raises(InputError, match="angle"):
        C.product_integral(torch.tensor([1.0]), 1.0, 4.0)
    with pytest.raises(InputError, match="axis2"):
        t.product_lobes(torch.tensor([0.0, 1.0, 0.0]), 1.0, torch.tensor([1.0, 0.0]), 1.0)
    with pytest.raises(InputError, match="per_decade"):
        C.TableParams(per_decade=0)


# --------------------------------------------------------------------------------------------
# spherical caps


def ref_cap_exponent(theta: float) -> float:
    """argmin_e ∫ (f_cap - max(h.w,0)^e)^2 dw, none of the module's closed form: the root of
    the derivative ``dD/de = 4 pi [∫_c^1 -(1 - m^e) m^e log m dm + ∫_0^c m^(2e) log m dm]``
    (``m = h.w``, ``c = cos theta``) by scipy's adaptive quadrature and Brent's root finder,
    bracketed by a scan in log e. (Minimising the distance itself is limited by its flatness.)"""
    c = math.cos(theta)

    def slope(log_e):
        e = math.exp(log_e)

        def inside(m):
            p = math.exp(e * math.log(m))
            return math.expm1(e * math.log(m)) * p * math.log(m)  # -(1 - m^e) m^e log m

        def outside(m):
            return math.exp(2 * e * math.log(m)) * math.log(m) if m > 0 else 0.0

        a, _ = integrate.quad(inside, c, 1, epsabs=0, epsrel=1e-10, limit=200)
        if e < 2:  # m^(2e) log m, singular at 0: QUADPACK's algebraic-log weight (QAWS)
            b, _ = integrate.quad(
                lambda m: 1.0, 0, c, weight="alg-loga", wvar=(2 * e, 0), epsabs=0, epsrel=1e-10
            )
        else:
            pts = [q for q in (c - 30 / (2 * e), c - 3 / (2 * e)) if 0 < q < c]
            b, _ = integrate.quad(outside, 0, c, points=pts, epsabs=0, epsrel=1e-10, limit=200)
        return a + b

    # the optimum has e (1 - c) in (0, 1): scan log e up to 4 / (1 - c)
    scan = np.linspace(-8, math.log(4 / (1 - c)), 97)
    signs = np.sign([slope(x) for x in scan])
    k = int(np.argmax((signs[:-1] < 0) & (signs[1:] > 0)))
    return math.exp(optimize.brentq(slope, scan[k], scan[k + 1], xtol=1e-13, rtol=1e-13))


@pytest.mark.parametrize("theta", [0.002, 0.05, 0.3, 0.9, 1.3, 1.52])
def test_cap_exponent_minimises_the_l2_distance(theta, tables):
    # the reference's quadrature (1e-10) moves the root by ~1e-9 relative: 1e-8
    ref = ref_cap_exponent(theta)
    assert float(C.fit_cap_exponent(torch.tensor(theta, dtype=F64))) == pytest.approx(ref, rel=1e-8)
    # the 1000-entry table, linear in kappa = e (1 - cos) (spacing 1.6e-3 rad): measured 1.2e-5
    # relative in e below 1.5 rad; towards pi/2, e ~ c (1 - log c)/2 (c = cos theta) is not
    # smooth and the error grows (2e-5 at 1.52), but the lobe integral 2 pi/(e + 1) stays
    # within 3.1e-4 of the exact fit's over [0, pi/2] (dense check below)
    got = float(tables.cap_exponent(torch.tensor(theta, dtype=F64)))
    assert got == pytest.approx(ref, rel=3e-5)


def test_cap_table_matches_exact_fits_densely(tables):
    theta = torch.linspace(1e-4, math.pi / 2, 4001, dtype=F64)
    exact, table = C.fit_cap_exponent(theta), tables.cap_exponent(theta)
    below = theta < 1.5
    assert float((table / exact - 1)[below].abs().max()) < 2e-5  # measured 1.2e-5
    assert float(((exact + 1) / (table + 1) - 1).abs().max()) < 5e-4  # measured 3.1e-4


def test_cap_lobe_integral_is_the_solid_angle(tables):
    # With the paper's definition (scale 1, eq. 34) the lobe's integral 2 pi/(e+1) is the cap's
    # solid angle 2 pi (1 - cos) only up to the L2 fit: the ratio tends to 1/kappa_0 = 1.0403 for
    # small caps, where (1 + kappa_0) exp(-kappa_0) = 3/4 (derived from the closed-form
    # distance), falls to 0.9309 at 1.32 rad and returns to 1 at pi/2 (e = 0, a hemisphere).
    theta = torch.linspace(1e-4, math.pi / 2, 2001, dtype=F64)
    ratio = C.integral(tables.cap_exponent(theta)) / (2 * math.pi * (1 - torch.cos(theta)))
    assert float(ratio.max()) < 1.0405 and float(ratio.min()) > 0.9305
    kappa0 = optimize.brentq(lambda k: (1 + k) * math.exp(-k) - 0.75, 0.1, 3)
    assert float(ratio[0]) == pytest.approx(1 / kappa0, rel=1e-4)  # O(theta^2) from the limit
    assert float(ratio[-1]) == pytest.approx(1.0, abs=1e-6)
    e = tables.cap_exponent(torch.tensor([0.0, math.pi / 2, 2.0], dtype=F64))
    assert math.isinf(float(e[0])) and float(e[1]) == 0 and float(e[2]) == 0


# --------------------------------------------------------------------------------------------
# cache


def test_default_tables_size_and_shapes(tables):
    p = tables.params
    assert p.n_exponent == 97 and p.n_angle == 166  # 16 per decade from 0 to 1e5; see module
    assert tables.shapes["product_stored"] == [97 * 98 // 2, 166, 3]
    assert tables.nbytes < 10e6  # the budget: the paper's three tables take < 10 MB
    assert tables.cap_table.shape == (1000,)


def test_cache_round_trip(tmp_path, monkeypatch):
    path = tmp_path / "t.npz"
    built = C.get_tables(path=path, params=SMALL)
    assert path.is_file() and path.stat().st_size < 10 * 2**20
    assert not list(tmp_path.glob(".*tmp"))  # the temporary name was renamed away
    loaded = C.load_tables(path)
    assert loaded.params == SMALL
    torch.testing.assert_close(loaded.product_table, built.product_table, rtol=0, atol=0)
    torch.testing.assert_close(loaded.cap_table, built.cap_table, rtol=0, atol=0)
    # a second process reads the file instead of building
    _tables._MEMO.clear()

    def no_build(*a, **k):
        raise AssertionError("rebuilt a valid cache")

    monkeypatch.setattr(_tables, "build_tables", no_build)
    again = C.get_tables(path=path, params=SMALL)
    torch.testing.assert_close(again.product_table, built.product_table, rtol=0, atol=0)
    # LOBELIGHT_CACHE moves the default location
    monkeypatch.setenv("LOBELIGHT_CACHE", str(tmp_path / "elsewhere"))
    assert C.default_path() == tmp_path / "elsewhere" / "cosine-tables.npz"


def _rewrite(path, **changes):
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    arrays.update(changes)
    with open(path, "wb") as f:
        np.savez(f, **arrays)


def test_version_or_parameter_mismatch_rebuilds(tmp_path):
    path = tmp_path / "t.npz"
    C.save_tables(C.build_tables(SMALL), path)
    _rewrite(path, format_version=np.array(C.FORMAT_VERSION - 1, dtype=np.int64))
    with pytest.raises(InputError, match="format version"):
        C.load_tables(path)
    t = C.get_tables(path=path, params=SMALL)  # rebuilt and rewritten
    with np.load(path, allow_pickle=False) as z:
        assert int(z["format_version"]) == C.FORMAT_VERSION
    assert t.params == SMALL
    # other parameters than asked for: rebuilt with the asked ones
    other = C.TableParams(**{**SMALL.to_dict(), "cap_nodes": 60})
    _tables._MEMO.clear()
    assert C.get_tables(path=path, params=other).cap_table.shape == (60,)
    assert C.load_tables(path).params == other


def test_build_reports_progress_and_is_unchanged_by_it():
    """``progress(stage, done, total)`` after each chunk of fits, up to every fit; the tables
    are the same bits with and without it."""
    calls = []
    t = C.build_tables(SMALL, chunk=512, progress=lambda *a: calls.append(a))
    total = t.info["product_fits"]
    assert len(calls) == -(-total // 512) and {c[0] for c in calls} == {"lobe tables"}
    assert [c[1] for c in calls] == sorted(c[1] for c in calls) and calls[-1][1:] == (total,) * 2
    assert torch.equal(t.product_table, C.build_tables(SMALL, chunk=512).product_table)


@pytest.mark.parametrize("damage", ["garbage", "truncated", "missing", "shape", "header"])
def test_corrupt_file_raises_naming_it(tmp_path, damage):
    path = tmp_path / "tables.npz"
    C.save_tables(C.build_tables(SMALL), path)
    if damage == "garbage":
        path.write_bytes(b"not a table file at all")
    elif damage == "truncated":
        data = path.read_bytes()
        path.write_bytes(data[: len(data) // 2])
    elif damage == "missing":
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files if k != "cap"}
        with open(path, "wb") as f:
            np.savez(f, **arrays)
    elif damage == "shape":
        _rewrite(path, product=np.zeros((3, 3, 3), dtype=np.float32))
    else:
        _rewrite(path, params=np.array("{not json"))
    for call in (lambda: C.load_tables(path), lambda: C.get_tables(path=path, params=SMALL)):
        with pytest.raises(InputError) as err:
            call()
        assert str(path) in str(err.value)


def test_failed_write_leaves_the_old_file(tmp_path, monkeypatch):
    path = tmp_path / "t.npz"
    t = C.build_tables(SMALL)
    C.save_tables(t, path)
    before = path.read_bytes()

    def broken(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez", broken)
    with pytest.raises(OSError):
        C.save_tables(t, path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.npz"]
    assert isinstance(zipfile.ZipFile(path).namelist(), list)


def test_bench_tables_reports(monkeypatch):
    # Smoke test of the benchmark's report on the tiny grid (timings are for `lobelight bench`).
    real = _tables.build_tables
    monkeypatch.setattr(_tables, "build_tables", lambda **k: real(SMALL, **k))
    out = bench_tables()
    for key in ("seconds", "shapes", "bytes", "file_bytes", "machine", "goal_seconds"):
        assert key in out
    assert out["unconverged_fits"] == 0 and out["bytes"] > 0
