"""Tests of lobelight.lobes.sg against independent references.

Brute-force references are float64 scipy quadratures in the polar angle about one lobe's axis,
with the azimuth done in closed form where a second lobe is off-axis
(``∫ exp(a cos phi) dphi = 2 pi I0(a)``); none of them uses the SG product or integral formulas
under test. The bound is 1e-4 relative over sharpness 0.1 to 1e4; the tolerances below are
tighter where float64 allows it and say why.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import integrate, special

from conftest import F64, random_dirs, triple, unit
from lobelight.errors import InputError
from lobelight.geometry import sphere as S
from lobelight.lobes import sg

LAMS = [0.1, 0.3, 1.0, 3.0, 10.0, 100.0, 1e3, 1e4]

log_lam = st.floats(math.log(0.1), math.log(1e4))


def _breaks(centre: float, width: float) -> list[float]:
    return sorted(
        {min(max(centre + k * width, 0.0), math.pi) for k in (-30, -8, -3, -1, 0, 1, 3, 8, 30)}
    )


def quad_theta(f, centre: float, width: float) -> float:
    """∫_0^π f(θ) dθ, adaptive, with break points around a peak of the given width."""
    val, _ = integrate.quad(
        f, 0, math.pi, points=_breaks(centre, width), limit=500, epsabs=0, epsrel=1e-13
    )
    return val


def ref_integral(lam: float) -> float:
    # 2π ∫ exp(λ(cosθ - 1)) sinθ dθ, with cosθ - 1 = -2 sin²(θ/2) to keep precision at λ = 1e4
    def f(th):
        return math.exp(-2 * lam * math.sin(th / 2) ** 2) * math.sin(th)

    return 2 * math.pi * quad_theta(f, 0.0, 1 / math.sqrt(lam))


def ref_inner(lam1: float, lam2: float, beta: float) -> float:
    """∫ G(ω; μ1, λ1) G(ω; μ2, λ2) dω with μ2 at angle β from μ1, by polar quadrature about μ1.

    μ2·ω = cosθ cosβ + sinθ sinβ cosφ; the φ-integral of exp(λ2 sinθ sinβ cosφ) is 2π I0, and
    exp(λ2(cosθ cosβ - 1)) I0(a) = exp(λ2(cos(θ - β) - 1)) i0e(a) never overflows.
    """

    def f(th):
        a = lam2 * math.sin(th) * math.sin(beta)
        e = -2 * lam1 * math.sin(th / 2) ** 2 - 2 * lam2 * math.sin((th - beta) / 2) ** 2
        return math.exp(e) * special.i0e(a) * math.sin(th)

    peak = lam2 * beta / (lam1 + lam2)
    return 2 * math.pi * quad_theta(f, peak, 1 / math.sqrt(lam1 + lam2))


# ---------------------------------------------------------------------------------------------
# evaluate


def test_evaluate_definition_and_peak():
    d = random_dirs(1000)
    mu = random_dirs(1000, seed=1)
    lam = torch.exp(torch.empty(1000, dtype=F64).uniform_(math.log(1e-3), math.log(1e5)))
    g = sg.evaluate(d, mu, lam)
    # float64: the chord form equals exp(λ(μ·ω - 1)) for unit vectors up to rounding of
    # |μ - ω|² vs the dot product: relative error λ * 1e-16 <= 1e-11 at λ = 1e5
    ref = torch.exp(lam * ((d * mu).sum(-1) - 1))
    assert torch.allclose(g, ref, rtol=1e-10, atol=1e-300)
    assert torch.equal(sg.evaluate(mu, mu, lam), torch.ones(1000, dtype=F64))
    assert ((g >= 0) & (g <= 1)).all()


def test_evaluate_float32_sharp_lobe_precision():
    """λ = 1e5 in float32: the chord form stays accurate where the dot-product form cancels."""
    lam = 1e5
    mu = random_dirs(1, torch.float32)[0]
    t = S.frame(mu)[0]
    ang = torch.linspace(0, 8e-3, 50)  # out to ~2.5 lobe widths
    d = torch.nn.functional.normalize(mu + ang.unsqueeze(-1) * t, dim=-1)
    g32 = sg.evaluate(d, mu, lam)
    # reference: the angle between the same float32 inputs (in float64, by atan2), through the
    # definition with exactly unit vectors. (The definition applied to the float32 vectors as
    # they are is off by λ (|μ|² - 1) ~ 1e5 * 1e-7 = 1e-2 at the peak: their norms are not 1.)
    theta = _angle(d.double(), mu.double())
    ref = torch.exp(lam * (torch.cos(theta) - 1))
    # Remaining error: float32 rounding in |ω - μ|² and exp, measured 2.5e-7 (the dot-product
    # form exp(λ(μ·ω - 1)) in float32 is off by 1.2% here); 1e-5 leaves margin.
    assert torch.allclose(g32.double(), ref, rtol=1e-5, atol=1e-12)


def test_evaluate_weights_and_broadcasting():
    d = random_dirs(12).reshape(4, 3, 3)
    mu = random_dirs(3, seed=2)  # (3, 3) broadcast against (4, 3, 3)
    lam = torch.tensor([1.0, 10.0, 100.0], dtype=F64)
    w = torch.tensor([[1.0, 2.0, 3.0]], dtype=F64)
    g = sg.evaluate(d, mu, lam)
    assert g.shape == (4, 3)
    gw = sg.evaluate(d, mu, lam, w)
    assert gw.shape == (4, 3, 3)
    assert torch.allclose(gw, g.unsqueeze(-1) * w)
    assert torch.equal(sg.evaluate(d, mu, lam, weight=w), gw)
    with pytest.raises(InputError, match="dirs"):
        sg.evaluate(torch.zeros(4, 2), mu, 1.0)


# ---------------------------------------------------------------------------------------------
# integral, product, inner product


@pytest.mark.parametrize("lam", [1e-3, *LAMS, 1e5])
def test_integral_against_quadrature(lam):
    ref = ref_integral(lam)
    # float64: closed form vs adaptive quadrature at epsrel 1e-13
    assert abs(sg.integral(torch.tensor(lam, dtype=F64)).item() / ref - 1) < 1e-11
    # float32: a handful of float32 roundings (expm1, division): measured <= 2e-7
    assert abs(sg.integral(torch.tensor(lam)).item() / ref - 1) < 1e-6


def test_integral_limits_weights_and_gradient():
    lam = torch.tensor([0.0, 1e-12, 1e-3], dtype=F64, requires_grad=True)
    val = sg.integral(lam)
    assert torch.allclose(val[:2], torch.full((2,), 4 * math.pi, dtype=F64))
    # small λ: 2π(1 - e^{-2λ})/λ = 4π(1 - λ + 2λ²/3 - λ³/3 + 2λ⁴/15 ...); the next term is 2e-12
    x = 1e-3
    assert abs(val[2].item() - 4 * math.pi * (1 - x + 2 * x**2 / 3 - x**3 / 3)) < 1e-11
    val.sum().backward()
    assert torch.isfinite(lam.grad).all()  # the λ = 0 branch is gradient-safe
    w = torch.tensor([[1.0, 0.5, 0.25]], dtype=F64)
    assert torch.allclose(
        sg.integral(torch.tensor([2.0], dtype=F64), w), w * sg.integral(2.0).double()
    )
    assert sg.integral(torch.tensor(1e5)).item() == pytest.approx(2 * math.pi / 1e5, rel=1e-6)


def _pair_angle(lam1: float, lam2: float) -> float:
    # the product scale is exp(-λh β²/2) with λh = λ1λ2/(λ1+λ2) for small β: pick β so that the
    # overlap is e^-4 (a relevant, non-underflowing value), capped below π
    lam_h = lam1 * lam2 / (lam1 + lam2)
    return min(2.5, math.sqrt(8 / lam_h))


@pytest.mark.parametrize("lam1", LAMS)
@pytest.mark.parametrize("lam2", [0.1, 1.0, 30.0, 1e3, 1e4])
def test_inner_product_against_quadrature(lam1, lam2):
    for beta in (0.0, _pair_angle(lam1, lam2) / 2, _pair_angle(lam1, lam2)):
        mu1 = torch.tensor([0.0, 1.0, 0.0], dtype=F64)
        mu2 = torch.tensor([math.sin(beta), math.cos(beta), 0.0], dtype=F64)
        ref = ref_inner(lam1, lam2, beta)
        got = sg.inner_product(mu1, lam1, mu2, lam2).item()
        # float64 closed form vs quadrature at epsrel 1e-13: measured <= 1e-14
        assert abs(got / ref - 1) < 1e-10
        # the product's own parameters integrate to the same value
        _, lam, scale = sg.product(mu1, lam1, mu2, lam2)
        assert abs((scale * sg.integral(lam)).item() / ref - 1) < 1e-10
        # float32 with random orientation: the module's 1e-4. Error sources: float32 means
        # (rounding ~6e-8 in β, amplified by λh β ~ sqrt(8 λh) <= 300 in the exponent);
        # measured <= 1.7e-6 over this grid
        R = S.random_rotation(1, generator=torch.Generator().manual_seed(int(lam1 + lam2)))[0]
        got32 = sg.inner_product(R @ mu1.float(), lam1, R @ mu2.float(), lam2).item()
        assert abs(got32 / ref - 1) < 1e-4


def test_product_pointwise():
    """G1 G2 = scale G(μ, λ) at directions spread over the product lobe."""
    g = torch.Generator().manual_seed(4)
    n = 400
    mu1 = random_dirs(n, seed=5)
    lam1 = torch.exp(torch.empty(n, dtype=F64).uniform_(math.log(0.1), math.log(1e4), generator=g))
    lam2 = torch.exp(torch.empty(n, dtype=F64).uniform_(math.log(0.1), math.log(1e4), generator=g))
    # second mean within a few widths of the first so the product does not underflow
    lam_h = lam1 * lam2 / (lam1 + lam2)
    off = torch.randn(n, 3, generator=g, dtype=F64) * (2 / lam_h.sqrt()).clamp(max=1).unsqueeze(-1)
    mu2 = torch.nn.functional.normalize(mu1 + off, dim=-1)
    mu, lam, scale = sg.product(mu1, lam1, mu2, lam2)
    assert torch.allclose(torch.linalg.vector_norm(mu, dim=-1), torch.ones(n, dtype=F64))
    assert ((scale > 0) & (scale <= 1)).all()
    for k in range(4):
        spread = torch.randn(n, 3, generator=g, dtype=F64) * (k / (lam + 1).sqrt()).unsqueeze(-1)
        w = torch.nn.functional.normalize(mu + spread, dim=-1)
        lhs = sg.evaluate(w, mu1, lam1) * sg.evaluate(w, mu2, lam2)
        rhs = scale * sg.evaluate(w, mu, lam)
        # float64: exponents up to ~1e4 carry ~1e-12 absolute rounding
        assert torch.allclose(lhs, rhs, rtol=1e-9, atol=1e-300)


@settings(max_examples=200, deadline=None)
@given(triple, triple, log_lam, log_lam, triple)
def test_product_of_two_sgs_is_an_sg(t1, t2, l1, l2, tw):
    """Property: for any two lobes and any direction, G1 G2 = scale G(μ, λ) (compared in log
    space, so that values that underflow are compared too)."""
    mu1, mu2, w = unit(t1), unit(t2), unit(tw)
    lam1, lam2 = math.exp(l1), math.exp(l2)
    mu, lam, log_scale = sg.product(mu1, lam1, mu2, lam2, log_scale=True)
    assert abs(torch.linalg.vector_norm(mu).item() - 1) < 1e-14
    assert 0 <= lam.item() <= lam1 + lam2 + 1e-9
    assert log_scale <= 0
    log_lhs = lam1 * (mu1 @ w - 1) + lam2 * (mu2 @ w - 1)
    log_rhs = log_scale + lam * (mu @ w - 1)
    # exponents of size up to 4e4, float64: absolute rounding ~1e-11
    assert abs(log_lhs - log_rhs) < 1e-9 * (1 + lam1 + lam2)


def test_product_degenerate_and_stable():
    mu1 = torch.tensor([0.0, 0.0, 1.0], dtype=F64)
    # opposite lobes of equal sharpness multiply to a constant: λ = 0, scale = e^{-2λ1}
    mu, lam, scale = sg.product(mu1, 3.0, -mu1, 3.0)
    assert lam.item() == 0 and torch.equal(mu, mu1)
    assert scale.item() == pytest.approx(math.exp(-6.0), rel=1e-14)
    assert sg.inner_product(mu1, 3.0, -mu1, 3.0).item() == pytest.approx(
        4 * math.pi * math.exp(-6), rel=1e-14
    )
    # very sharp, nearly coincident float32 lobes: no cancellation in the scale
    mu2 = torch.nn.functional.normalize(torch.tensor([1e-3, 0.0, 1.0]), dim=-1)
    _, _, s32 = sg.product(mu1.float(), 1e5, mu2, 1e5)
    # reference: ∫-free closed form in float64 from the angle, scale = exp(λm - 2λ) with
    # λm = 2λ cos(β/2), written as -2λ (1 - cos(β/2)) = -4λ sin²(β/4) to avoid cancellation
    beta = math.atan(1e-3)
    ref = math.exp(-4e5 * math.sin(beta / 4) ** 2)
    # float32: β ~ 1e-3 carries ~6e-8 absolute rounding; exponent ~ 0.025 -> ~3e-6 relative
    assert s32.item() == pytest.approx(ref, rel=1e-5)
    # all sharpness extremes stay finite
    lam = torch.tensor([1e-3, 1e5])
    for a in lam:
        for b in lam:
            out = sg.inner_product(mu1.float(), a, mu2, b)
            assert torch.isfinite(out) and out > 0


def test_gradients_finite_difference():
    """Fits will differentiate through these: float64 gradcheck (analytic vs finite differences)."""
    d = random_dirs(4, seed=6).requires_grad_()
    mu = random_dirs(4, seed=7).requires_grad_()
    lam = torch.tensor([0.3, 2.0, 40.0, 900.0], dtype=F64, requires_grad=True)
    w = torch.rand(4, 3, dtype=F64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a, b, c, e: sg.evaluate(a, b, c, e), (d, mu, lam, w))
    mu2 = torch.nn.functional.normalize(mu.detach() + 0.05 * d.detach(), dim=-1).requires_grad_()
    lam2 = torch.tensor([1.0, 5.0, 30.0, 500.0], dtype=F64, requires_grad=True)
    assert torch.autograd.gradcheck(sg.inner_product, (mu, lam, mu2, lam2))
    assert torch.autograd.gradcheck(lambda a, b, c, e: sg.product(a, b, c, e), (mu, lam, mu2, lam2))
    assert torch.autograd.gradcheck(sg.integral, (lam,))
    assert torch.autograd.gradcheck(sg.mean_cosine, (lam,))


# ---------------------------------------------------------------------------------------------
# σ, vMF, mean cosine


def test_sigma_sharpness():
    sigma = torch.tensor([1e-3, 0.01, 0.1, 1.0], dtype=F64)
    lam = sg.sigma_to_sharpness(sigma)
    assert torch.allclose(lam, 1 / sigma**2)
    assert torch.allclose(sg.sharpness_to_sigma(lam), sigma)
    # small-angle meaning of σ: G at angle σ from the mean is e^{-1/2} (relative error ~σ²/12)
    g = torch.exp(lam * (torch.cos(sigma) - 1))
    assert abs(g[1].item() / math.exp(-0.5) - 1) < 1e-5


@pytest.mark.parametrize("kappa", [1e-3, 0.5, 10.0, 1e3, 1e5])
def test_vmf_pdf_integrates_to_one(kappa):
    mu = random_dirs(2)
    dirs, w = S.local_grid(mu, kappa, eps=1e-14)  # cap holds all but 1e-14 of the mass
    p = sg.vmf_pdf(dirs, mu.unsqueeze(-2), kappa)
    # Gauss-Legendre on the cap is converged to rounding (see test_sphere); 1e-10 for margin
    assert torch.allclose((w * p).sum(-1), torch.ones(2, dtype=F64), rtol=1e-10)
    n = sg.vmf_normalization(torch.tensor(kappa, dtype=F64))
    assert n.item() == pytest.approx(1 / ref_integral(kappa), rel=1e-11)
    assert sg.vmf_normalization(torch.tensor(0.0)).item() == pytest.approx(1 / (4 * math.pi))


@pytest.mark.parametrize("lam", [1e-3, 0.01, 0.3, 0.5, 0.7, 3.0, 30.0, 1e3, 1e4])
def test_mean_cosine_against_quadrature(lam):
    # E[c] = ∫ c e^{λ(c-1)} dc / ∫ e^{λ(c-1)} dc over c = cosθ in [-1, 1]. The numerator folds
    # c and -c together, ∫_0^1 c (e^{λ(c-1)} - e^{-λ(c+1)}) dc, so that it does not cancel for
    # small λ (where it is ~2λ/3 from terms of size 1).
    pts = sorted({max(1 - k / lam, 0.0) for k in (1, 3, 10, 30)})

    def num_f(c):
        return c * math.exp(lam * (c - 1)) * -math.expm1(-2 * lam * c)

    num, _ = integrate.quad(num_f, 0, 1, points=pts, limit=200, epsabs=0, epsrel=1e-13)
    den, _ = integrate.quad(
        lambda c: math.exp(lam * (c - 1)), -1, 1, points=pts, limit=200, epsabs=0, epsrel=1e-13
    )
    ref = num / den
    # float64 on both sides (series below λ = 0.5, closed form above): measured <= 1e-15
    assert sg.mean_cosine(torch.tensor(lam, dtype=F64)).item() == pytest.approx(ref, rel=1e-12)
    # float32: computed in float64 and rounded once
    assert sg.mean_cosine(torch.tensor(lam)).item() == pytest.approx(ref, rel=2e-7)


def test_mean_cosine_limits_and_continuity():
    lam = torch.tensor([0.0, 0.5 - 1e-12, 0.5, 1e10], dtype=F64)
    r = sg.mean_cosine(lam)
    assert r[0] == 0 and r[3] == pytest.approx(1 - 1e-10, abs=1e-16)
    assert abs(r[1] - r[2]) < 1e-12  # series and closed form agree at the switch
    assert torch.isfinite(sg.mean_cosine(torch.tensor([1e5, 1e30]))).all()


def test_lam_from_mean_cosine_round_trip():
    lam = torch.logspace(-3, 5, 400, dtype=F64)
    back = sg.lam_from_mean_cosine(sg.mean_cosine(lam))
    # float64: Newton converges to rounding; the conditioning dλ/λ = dr/(λ A'(λ)) ~ λ eps near
    # r = 1 gives ~1e-11 at λ = 1e5
    assert torch.allclose(back, lam, rtol=1e-9)
    # float32 r: its rounding near 1 (6e-8) limits λ to ~λ * 6e-8 relative, so stop at 1e3
    lam32 = torch.logspace(-3, 3, 100)
    back32 = sg.lam_from_mean_cosine(sg.mean_cosine(lam32))
    assert back32.dtype == torch.float32
    assert torch.allclose(back32, lam32, rtol=2e-4)
    edge = sg.lam_from_mean_cosine(torch.tensor([-0.5, 0.0, 1.0, 1.5], dtype=F64))
    assert edge.tolist() == [0.0, 0.0, math.inf, math.inf]


# ---------------------------------------------------------------------------------------------
# mixtures, rotation, fitting


def test_evaluate_mixture_and_constant_integral():
    n_gaussians = 3
    mus = random_dirs(2 * n_gaussians).reshape(2, n_gaussians, 3)
    lams = torch.tensor([[1.0, 20.0, 300.0], [0.5, 5.0, 50.0]], dtype=F64)
    weights = torch.rand(2, n_gaussians, 3, dtype=F64)
    d = random_dirs(10, seed=3).reshape(10, 1, 3)  # (10, 1, 3) against 2 mixtures
    out = sg.evaluate_mixture(d, mus, lams, weights)
    assert out.shape == (10, 2, 3)
    ref = sum(
        sg.evaluate(d, mus[:, k], lams[:, k]).unsqueeze(-1) * weights[:, k]
        for k in range(n_gaussians)
    )
    assert torch.allclose(out, ref)
    # constant lighting: closed form vs Fibonacci quadrature of the mixture (1e5 points; the
    # sharpest lobe, λ = 300, is ~0.06 rad wide vs 0.011 rad spacing; measured error ~1e-9)
    fd, fw = S.fibonacci(100000, dtype=F64)
    radiance = torch.tensor([1.0, 2.0, 0.5], dtype=F64)
    quad = (
        fw.unsqueeze(-1).unsqueeze(-1) * sg.evaluate_mixture(fd.unsqueeze(-2), mus, lams, weights)
    ).sum(0)
    closed = sg.integrate_mixture_constant(lams, weights, radiance=radiance)
    assert closed.shape == (2, 3)
    assert torch.allclose(closed, quad * radiance, rtol=1e-6)
    with pytest.raises(InputError, match="weights"):
        sg.evaluate_mixture(d, mus, lams, torch.ones(3, dtype=F64))


@settings(max_examples=50, deadline=None)
@given(triple, triple, log_lam)
def test_rotate_is_rotation_invariant(tm, tw, ll):
    mu, w = unit(tm), unit(tw)
    lam = math.exp(ll)
    R = S.random_rotation(1, generator=torch.Generator().manual_seed(int(lam)), dtype=F64)[0]
    # rotating lobe and direction together leaves the value unchanged
    a = sg.evaluate(sg.rotate(w, R), sg.rotate(mu, R), lam)
    assert a.item() == pytest.approx(sg.evaluate(w, mu, lam).item(), rel=1e-9, abs=1e-300)
    with pytest.raises(InputError, match="R"):
        sg.rotate(mu, torch.eye(2, dtype=F64))


def _angle(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    # atan2 of cross and dot: accurate for tiny angles (unlike acos), and independent of norms
    a, b = torch.broadcast_tensors(a, b)
    return torch.atan2(torch.linalg.vector_norm(torch.linalg.cross(a, b), dim=-1), (a * b).sum(-1))


@pytest.mark.parametrize("lam", [2.0, 50.0])
def test_fit_from_samples_fibonacci(lam):
    mu = torch.nn.functional.normalize(torch.tensor([0.2, -0.5, 0.8], dtype=F64), dim=-1)
    d, w = S.fibonacci(100000, dtype=F64)
    vals = 2.5 * sg.evaluate(d, mu, lam)
    m, l, a = sg.fit_from_samples(d, vals, w)
    # the fit's bounds: μ within 1e-3 rad, λ within 1%; the amplitude within 1% too
    assert _angle(m, mu).item() < 1e-3
    assert abs(l.item() / lam - 1) < 0.01
    assert abs(a.item() / 2.5 - 1) < 0.01


def test_fit_from_samples_sharp_lobe_local_grid_float32():
    """λ = 1e4 sampled on a local grid centred off the true mean, float32 throughout."""
    lam = 1e4
    mu = random_dirs(8, torch.float32, seed=9)
    t, _, _ = S.frame(mu)
    guess = torch.nn.functional.normalize(mu + 0.5 / math.sqrt(lam) * t, dim=-1)  # 0.5 σ off
    d, w = S.local_grid(guess, lam, eps=1e-14)  # wide enough to hold the offset lobe
    vals = torch.stack(
        [1.0 * sg.evaluate(d, mu.unsqueeze(-2), lam), 0.3 * sg.evaluate(d, mu.unsqueeze(-2), lam)],
        -1,
    )
    m, l, a = sg.fit_from_samples(d, vals, w)
    assert m.shape == (8, 3) and l.shape == (8,) and a.shape == (8, 2)
    assert (_angle(m.double(), mu.double()) < 1e-3).all()
    assert ((l / lam - 1).abs() < 0.01).all()
    assert torch.allclose(a, torch.tensor([1.0, 0.3]).expand(8, 2), rtol=0.01)


def test_fit_from_samples_empty_is_finite():
    d, w = S.fibonacci(100)
    m, l, a = sg.fit_from_samples(d, torch.zeros(100), w)
    assert torch.isfinite(m).all() and l.item() == 0 and a.item() == 0


# ---------------------------------------------------------------------------------------------
# backends


def test_numpy_in_numpy_out():
    d = random_dirs(5).numpy()
    mu = random_dirs(5, seed=1).numpy()
    lam = np.full(5, 3.0)
    for out in (
        sg.evaluate(d, mu, lam),
        sg.integral(lam),
        sg.inner_product(mu, lam, d, lam),
        sg.vmf_pdf(d, mu, lam),
        sg.mean_cosine(lam),
        sg.lam_from_mean_cosine(np.full(5, 0.5)),
        sg.sigma_to_sharpness(lam),
        sg.rotate(mu, np.eye(3)),
        *sg.product(mu, lam, d, lam),
        *sg.fit_from_samples(d, lam, lam),
    ):
        assert isinstance(out, np.ndarray) and out.dtype == np.float64


def test_tensors_keep_dtype_and_device(device):
    d = random_dirs(5, torch.float32).to(device)
    mu = random_dirs(5, torch.float32, seed=1).to(device)
    lam = torch.full((5,), 3.0, device=device)
    w = torch.ones(5, 2, 3, device=device)
    for out in (
        sg.evaluate(d, mu, lam),
        sg.evaluate(d, mu, 3.0),
        sg.integral(lam),
        sg.inner_product(mu, lam, d, 2.0),
        sg.vmf_pdf(d, mu, lam),
        sg.vmf_normalization(lam),
        sg.mean_cosine(lam),
        sg.lam_from_mean_cosine(lam / 4),
        sg.sharpness_to_sigma(lam),
        sg.rotate(mu, torch.eye(3, device=device)),
        sg.evaluate_mixture(
            d, mu.reshape(5, 1, 3).expand(5, 2, 3), lam.reshape(5, 1).expand(5, 2), w
        ),
        sg.integrate_mixture_constant(lam.reshape(5, 1).expand(5, 2), w),
        *sg.product(mu, lam, d, lam),
        *sg.fit_from_samples(d, lam, lam),
    ):
        assert out.device.type == device and out.dtype == torch.float32
