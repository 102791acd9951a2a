"""SG-BRDF (EM paper): vMF-mixture EM, fitted materials, coherence across views, rendering.

References are independent of the code under test: known mixtures (drawn with exact vMF
sampling, or as weights on a quadrature rule), directional albedo by Monte Carlo with the
BRDF's own sampling routine and fresh random numbers, and environment integrals by brute-force
sums over cube-map texels. Each tolerance is stated and justified at its assertion.
"""

from __future__ import annotations

import math
import re

import pytest
import torch

from conftest import smooth_env
from lobelight import brdf
from lobelight.envmap import EnvMap, prefilter
from lobelight.errors import InputError
from lobelight.geometry import cubemap, sphere
from lobelight.geometry.camera import Camera
from lobelight.lobes.sg import integral, lam_from_mean_cosine, mean_cosine
from lobelight.sgbrdf import (
    em_fit,
    fit,
    fit_error,
    interpolation_error,
    kappa_from_gap,
    match_components,
    mip_chain,
    render_sphere,
    sample_mixture,
    shade,
    view_jump,
    vmf_log_pdf,
)

F64 = torch.float64


pytestmark = pytest.mark.usefixtures("one_torch_thread")


# --------------------------------------------------------------------------------------------
# known mixtures

MU = torch.nn.functional.normalize(
    torch.tensor([[0.2, 0.9, 0.3], [1.0, 0.0, -0.4], [-0.6, -0.3, 0.7]], dtype=F64), dim=-1
)
KAPPA = torch.tensor([5.0, 100.0, 1000.0], dtype=F64)
ALPHA = torch.tensor([0.5, 0.3, 0.2], dtype=F64)


def _matched(r_mu, mu):
    """Permutation of fitted lobes nearest to each true mean (means here are >= 60 deg apart)."""
    return (r_mu.double() @ mu.T).argmax(0)


def _angles_deg(a, b):
    return torch.rad2deg(torch.atan2(torch.linalg.cross(a, b).norm(dim=-1), (a * b).sum(-1)))


def test_em_recovers_mixture_from_drawn_samples():
    s = 20000
    g = torch.Generator().manual_seed(1)
    x = sample_mixture(MU, KAPPA, ALPHA, torch.rand(s, 3, generator=g, dtype=F64))
    r = em_fit(x.float(), n_lobes=3, tol=1e-9, max_iter=500)
    p = _matched(r.mu, MU)
    n_k = ALPHA * s  # samples per component
    # Moment estimates from n_k samples: mean direction to 1/sqrt(kappa n_k) rad per axis,
    # concentration to ~1/sqrt(n_k) relative, weights to sqrt(a (1 - a) / S); 5 sigma each.
    ang = _angles_deg(r.mu.double()[p], MU)
    assert bool((ang <= torch.rad2deg(5 / torch.sqrt(KAPPA * n_k))).all()), ang
    krel = (r.kappa.double()[p] / KAPPA - 1).abs()
    assert bool((krel <= 5 / torch.sqrt(n_k) + 0.02).all()), krel  # + overlap bias allowance
    da = (r.alpha.double()[p] - ALPHA).abs()
    assert bool((da <= 5 * torch.sqrt(ALPHA * (1 - ALPHA) / s)).all()), da


def test_em_recovers_mixture_from_weighted_samples():
    # Weighted samples: the mixture's density on a Fibonacci quadrature rule (200k points,
    # about 4 per standard deviation of the sharpest lobe). No sampling noise is left, so the
    # recovery is as good as the quadrature: measured 0.013 deg, 3.4e-5 relative kappa, 3e-6 in
    # the weights; the tolerances are ~10x that.
    d, w = sphere.fibonacci(200_000, dtype=F64)
    pdf = (ALPHA * vmf_log_pdf(d[:, None], MU, KAPPA).exp()).sum(-1)
    r = em_fit(d.float(), (pdf * w).float(), n_lobes=3, tol=1e-10, max_iter=500)
    p = _matched(r.mu, MU)
    assert float(_angles_deg(r.mu.double()[p], MU).max()) < 0.15
    assert float((r.kappa.double()[p] / KAPPA - 1).abs().max()) < 5e-4
    assert float((r.alpha.double()[p] - ALPHA).abs().max()) < 5e-5


def test_em_sharp_lobes_and_batches():
    # kappa = 2e4 and 5e3 (far narrower than any float32 "1 - r" can hold): weighted samples on
    # local grids around each mean (caps disjoint, 1e-12 of the mass outside), float32 data.
    mu = torch.tensor([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]], dtype=F64)
    kap = torch.tensor([2e4, 5e3], dtype=F64)
    a = torch.tensor([0.4, 0.6], dtype=F64)
    d, w = sphere.local_grid(mu, kap, eps=1e-12, n_theta=32)
    d, w = d.reshape(-1, 3), w.reshape(-1)
    wt = (a * vmf_log_pdf(d[:, None], mu, kap).exp()).sum(-1) * w
    # Batch of two problems: the mixture, and the same data with the lobes' weights swapped.
    wt2 = (a.flip(0) * vmf_log_pdf(d[:, None], mu, kap).exp()).sum(-1) * w
    dirs = d.float().expand(2, -1, 3)
    r = em_fit(dirs, torch.stack([wt, wt2]).float(), n_lobes=2, tol=1e-12)
    for b, alpha in enumerate((a, a.flip(0))):
        p = _matched(r.mu[b], mu)
        # Gauss-Legendre caps integrate these lobes to ~1e-12; float32 directions limit the
        # angle to ~1e-7 rad and kappa to ~1e-4 relative (the gap is summed in float64).
        assert float(_angles_deg(r.mu[b].double()[p], mu).max()) < 1e-3
        assert float((r.kappa[b].double()[p] / kap - 1).abs().max()) < 1e-3
        assert float((r.alpha[b].double()[p] - alpha).abs().max()) < 1e-4
    # Each problem of a batch stops on its own: alone it gives the same result.
    alone = em_fit(dirs[1], wt2.float(), n_lobes=2, tol=1e-12)
    assert torch.equal(alone.kappa, r.kappa[1]) and torch.equal(alone.mu, r.mu[1])
    # Exact vMF sampling at kappa = 1e4: E[1 - mu.x] = 1e-4. 1 - mu.x of a sharp vMF is
    # exponential, so its mean over 20000 draws has a relative standard error of 0.7 %: 3 % is
    # over 4 sigma.
    g = torch.Generator().manual_seed(2)
    x = sample_mixture(
        mu[:1],
        torch.tensor([1e4], dtype=F64),
        torch.ones(1, dtype=F64),
        torch.rand(20000, 3, generator=g, dtype=F64),
    )
    gap = (1 - x @ mu[0]).mean()
    assert abs(float(gap) / float(1 - mean_cosine(torch.tensor(1e4, dtype=F64))) - 1) < 0.03


def test_em_degenerate_weights_keep_unit_means():
    # Regression: 8 lobes for weight on only 3 samples of a kappa = 5e4 lobe left the paper's
    # split with sample-less sets, whose mean came out as a zero vector.
    g = torch.Generator().manual_seed(0)
    x = sample_mixture(
        torch.tensor([[0.0, 0.0, 1.0]]),
        torch.tensor([5e4]),
        torch.ones(1),
        torch.rand(64, 3, generator=g),
    )
    w = torch.zeros(64)
    w[:3] = 1
    r = em_fit(x, w, n_lobes=8)
    assert bool(torch.isfinite(r.mu).all() & torch.isfinite(r.kappa).all())
    assert float((r.mu.norm(dim=-1) - 1).abs().max()) < 1e-5
    assert abs(float(r.alpha.sum()) - 1) < 1e-5


def test_kappa_from_gap_exact_and_approx():
    k = torch.logspace(-2, 5, 300, dtype=F64)
    gap = 1 - mean_cosine(k)
    exact = kappa_from_gap(gap)
    # against lobelight.lobes.sg's independent Newton inverse; the gap itself carries float64
    # rounding of ~1e-16 absolute, 1e-11 relative at kappa = 1e5
    assert float((exact / lam_from_mean_cosine(1 - gap) - 1).abs().max()) < 1e-8
    approx = kappa_from_gap(gap, solver="approx")
    assert float((approx / k - 1).abs().max()) < 0.05  # Banerjee et al.: within 5 %


# --------------------------------------------------------------------------------------------
# fitted materials


@pytest.fixture(scope="module")
def fits():
    """Fitted Ward materials (coherent and independent), shared by the tests below."""
    out = {}
    for a in (0.05, 0.2):
        b = brdf.Ward(1.0, a)
        out[a] = (b, fit(b), fit(b, coherent=False))
    return out


def _albedo_mc(b, views, count=16384, seed=7):
    g = torch.Generator().manual_seed(seed)
    u = torch.rand(views.shape[0], count, 2, generator=g)
    n = torch.tensor([0.0, 0.0, 1.0])
    _, w, _ = b.sample(views[:, None], n, u, torch.tensor([1.0, 0.0, 0.0]))
    return w.mean(1), w.std(1) / math.sqrt(count)


def test_fitted_mixture_integrates_to_albedo(fits):
    cases = [(b, m) for b, m, _ in fits.values()]
    ggx = brdf.GGX(0.1)
    cases.append((ggx, fit(ggx, max_iter=50)))
    for b, m in cases:
        got = (m.weight * integral(m.kappa).unsqueeze(-1)).sum(1)  # (M, 3) mixture integrals
        ref, se = _albedo_mc(b, m.fit_views)
        # Fresh random samples vs the fit's 4096-point lattice: 5 standard errors of the Monte
        # Carlo estimate plus 0.5 % for the lattice's own quadrature error (measured <= 0.3 %)
        tol = 5 * se + 0.005 * ref
        assert bool(((got - ref).abs() <= tol).all()), (b, (got - ref).abs().max())


def test_fit_quality_ward(fits, record_property):
    # Relative L2 error of the mixture against rho cos (MIS over BRDF and mixture samples).
    # Measured (coherent fit, 16 views 0..88 deg): alpha 0.05: median 0.0055, <= 0.006 up to
    # 41 deg, 0.03 at 76, 0.45 at 88 where the horizon cuts the lobe; alpha 0.2: median 0.014,
    # <= 0.017 up to 70 deg, 0.033 at 82, 0.12 at 88. Bounds: 0.05 up to 70 deg, median 0.04.
    for a, (b, m, _) in fits.items():
        err = fit_error(m, b, samples=8192)
        record_property(f"fit_error_ward_{a}", [round(float(e), 4) for e in err])
        print(f"Ward alpha={a}: relative L2 per view", [round(float(e), 3) for e in err])
        th = torch.rad2deg(torch.acos(m.fit_views[:, 2]))
        assert float(err[th <= 70].max()) < 0.05
        assert float(err.median()) < 0.04


def test_coherent_fit_smaller_view_jump(fits, record_property):
    b, coh, ind = fits[0.2]
    jc, ji = view_jump(coh.params, coh.fit_views), view_jump(ind.params, ind.fit_views)
    ec = fit_error(coh, b, samples=8192)
    ei = fit_error(ind, b, samples=8192)
    th = torch.atan2(coh.views[:, 0], coh.views[:, 2])
    mid = 0.5 * (th[1:] + th[:-1])
    q = torch.stack([mid.sin(), torch.zeros_like(mid), mid.cos()], -1)  # views between views
    ic, ii = (
        interpolation_error(coh, b, q, samples=8192),
        interpolation_error(ind, b, q, samples=8192),
    )
    record_property("view_jump_coherent", jc)
    record_property("view_jump_independent", ji)
    print("coherent", jc, float(ec.mean()), float(ic.mean()))
    print("independent", ji, float(ei.mean()), float(ii.mean()))
    # Measured: mean jump 1.40 vs 3.57 deg (2.6x), worst edge 3.7 vs 12.4 deg (3.3x); require 2x.
    assert ji["angle_deg"] >= 2 * jc["angle_deg"]
    assert ji["angle_deg_max"] >= 2 * jc["angle_deg_max"]
    # ... at no cost in fit error (measured 0.024 vs 0.034 mean), and the artefact the paper
    # names is gone: between views the interpolated lobes fit better (0.029 vs 0.053).
    assert float(ec.mean()) <= float(ei.mean())
    assert float(ic.mean()) <= 0.75 * float(ii.mean())
    # match=True re-pairs lobes between views by geometry. The coherent fit's labels are
    # already the best pairing (measured: identical numbers); re-pairing the independent fits
    # after the fact does not catch up (measured 2.64 deg, still 1.9x the coherent 1.40 deg).
    jmc = view_jump(coh.params, coh.fit_views, match=True)
    jmi = view_jump(ind.params, ind.fit_views, match=True)
    assert jmc["angle_deg"] <= 1.01 * jc["angle_deg"]
    assert jmi["angle_deg"] >= 1.5 * jc["angle_deg"]


def test_match_components_pairs_a_shifted_chain_in_order():
    # Eight lobes along a great circle, shifted by 1.5 spacings and shuffled: the 2-Wasserstein
    # cost pairs them in order (an L2 overlap cost cannot, the lobes no longer overlap).
    ang = torch.arange(8, dtype=F64) * 0.05

    def mk(s):
        return torch.stack([torch.sin(ang + s), torch.zeros(8, dtype=F64), torch.cos(ang + s)], -1)

    k, a = torch.full((8,), 4000.0, dtype=F64), torch.full((8,), 0.125, dtype=F64)
    shuffle = torch.tensor([3, 7, 0, 5, 1, 6, 2, 4])
    perm = match_components(mk(0.0), k, a, mk(0.075)[shuffle], k, a)
    assert torch.equal(shuffle[perm], torch.arange(8))


@pytest.fixture(scope="module")
def aniso():
    """Anisotropic Ward (0.05, 0.2) on the geodesic views; iterations capped to keep it quick."""
    b = brdf.Ward(1.0, 0.05, 0.2)
    return b, fit(b, max_iter=60)


def test_anisotropic_fit_geodesic_layout(aniso):
    b, m = aniso
    assert m.layout == "geodesic" and int(m.used.sum()) == 61
    got = (m.weight * integral(m.kappa).unsqueeze(-1)).sum(1)[m.used]
    ref, se = _albedo_mc(b, m.fit_views[m.used], count=8192)
    assert bool(((got - ref).abs() <= 5 * se + 0.005 * ref).all())  # as for isotropic fits
    # near normal incidence 8 isotropic lobes fit a 4:1 lobe to ~6 %; 8 % allows for the
    # capped iterations
    err = fit_error(m, b, samples=4096)
    assert float(err[0]) < 0.08
    # Coherence on the geodesic views. Here the paper's start (split along the lobe's long
    # axis) already orders the lobes alike in neighbouring views, so the mean jump stays
    # (measured 3.68 vs 3.66 deg); the worst edge drops (7.9 vs 10.6 deg), and the fit error
    # is no worse (0.203 vs 0.207; large at grazing views, where the lobe is cut off).
    ind = fit(b, max_iter=60, coherent=False)
    jc, ji = view_jump(m.params, m.fit_views), view_jump(ind.params, ind.fit_views)
    assert jc["angle_deg_max"] <= 0.85 * ji["angle_deg_max"]
    assert jc["angle_deg"] <= 1.05 * ji["angle_deg"]
    assert float(err[m.used].mean()) <= float(fit_error(ind, b, samples=4096)[m.used].mean())


# --------------------------------------------------------------------------------------------
# rendering


def _constant_env() -> EnvMap:
    return EnvMap(torch.full((16, 32, 3), 1.0), layout="latlong", name="constant")


def test_render_constant_environment_gives_albedo(fits):
    b, m, _ = fits[0.2]
    pf = prefilter(_constant_env(), base_res=16)
    img, mask = render_sphere(m, pf, width=24)
    # independent albedo at each pixel's view: orthographic view +Z, normal on the sphere
    x = (torch.arange(24) + 0.5) / 12 - 1
    yy, xx = torch.meshgrid(-x, x, indexing="ij")
    n = torch.stack([xx, yy, torch.sqrt((1 - xx**2 - yy**2).clamp_min(0))], -1)[mask]
    cos_o = n[:, 2]
    keep = cos_o > math.cos(math.radians(80))  # the table ends at 88 deg (clamped beyond)
    o_local = torch.stack([torch.sqrt(1 - cos_o**2), torch.zeros_like(cos_o), cos_o], -1)[keep]
    ref, se = _albedo_mc(b, o_local, count=8192)
    got = img[mask][keep]
    # 5 Monte Carlo standard errors, plus the linear interpolation of the albedo between views
    # 5.9 deg apart (measured <= 0.1 % up to 70 deg, 1 % at 80) and the prefiltered chain's
    # normalisation of a constant map (1e-6)
    tol = 5 * se + 0.012 * ref
    assert bool(((got - ref).abs() <= tol).all()), float((got - ref).abs().max())
    # The eq. (10) mip chain reproduces a constant map exactly as well: the same image.
    img2, _ = render_sphere(m, mip_chain(_constant_env(), base_res=16), width=24)
    assert float((img2 - img).abs().max()) < 1e-5
    # A perspective camera sees the same sphere: its centre pixel looks straight down the normal.
    cam = Camera.look_at((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), fov=30.0)
    img3, mask3 = render_sphere(m, pf, width=15, camera=cam)
    assert bool(mask3[7, 7]) and not bool(mask3[0, 0])
    assert abs(float(img3[7, 7, 0]) - float(m.albedo[0, 0])) < 1e-3


def test_lookups_against_quadrature():
    env = smooth_env()
    pf, mc = prefilter(env, base_res=32), mip_chain(env, base_res=32)
    res = 128  # reference: the same map on a finer cube, summed texel by texel
    dirs = cubemap.texel_directions(res).reshape(-1, 3)
    om = cubemap.texel_solid_angles(res).reshape(-1)
    rad = env.to_cubemap(res).reshape(-1, 3)
    mu = torch.nn.functional.normalize(
        torch.randn(100, 3, generator=torch.Generator().manual_seed(0)), dim=-1
    )
    for lam in (2.0, 10.0, 40.0):
        ref = (torch.exp(lam * (mu @ dirs.T - 1)) * om) @ rad  # (100, 3)
        lt = torch.full((100,), lam)

        def rel(x, ref=ref):
            return float((x - ref).norm(dim=-1).mean() / ref.norm(dim=-1).mean())

        e_pf, e_mip = rel(pf.integrate(mu, lt)), rel(mc.integrate(mu, lt))
        print(f"lam={lam}: prefiltered {e_pf:.4f}, eq. (10) mip {e_mip:.4f}")
        # measured 0.07-0.12 % vs 1.6-9 %: the Gaussian-prefiltered chain is the better lookup
        # (the default); eq. (10) with a = 0.5 is within 10 % on this smooth map
        assert e_pf < 0.005
        assert e_mip < 0.10
        assert e_pf < e_mip


def test_shade_anisotropic_tangent_matters(aniso):
    # An anisotropic material under a map with a gradient: turning the tangent by 90 degrees
    # about the normal changes the shading, and turning it by 180 does not (Ward is symmetric).
    _, m = aniso
    pf = prefilter(smooth_env(), base_res=16)
    n = torch.tensor([[0.0, 1.0, 0.0]])
    o = torch.nn.functional.normalize(torch.tensor([[0.3, 1.0, 0.2]]), dim=-1)
    t0 = shade(m, pf, n, o, tangents=torch.tensor([[1.0, 0.0, 0.0]]))
    t90 = shade(m, pf, n, o, tangents=torch.tensor([[0.0, 0.0, 1.0]]))
    t180 = shade(m, pf, n, o, tangents=torch.tensor([[-1.0, 0.0, 0.0]]))
    assert float((t0 - t90).abs().max()) > 1e-3
    # rotating the frame by 180 deg maps geodesic views to other geodesic views only
    # approximately (the 92 views are not symmetric under it): 3 % covers the interpolation
    assert float(((t0 - t180).abs() / t0).max()) < 0.03


# --------------------------------------------------------------------------------------------
# bad input


def _raises(name: str):
    """The error names ``name`` first (InputError's message is ``"name: problem"``)."""
    return pytest.raises(InputError, match=rf"^{re.escape(name)}:")


def test_bad_input_names_it():
    d = torch.nn.functional.normalize(torch.randn(2, 50, 3), dim=-1)
    w = torch.rand(2, 50)
    with _raises("weights"):
        em_fit(d, -w)
    with _raises("weights"):
        em_fit(d, w[:, :40])
    with _raises("weights"):
        em_fit(d, torch.zeros(2, 50))
    with _raises("dirs"):
        em_fit(d[..., :2], w)
    with _raises("dirs"):
        em_fit(d[:, :3], w[:, :3], n_lobes=8)
    with _raises("n_lobes"):
        em_fit(d, w, n_lobes=0)
    with _raises("init.mu"):
        em_fit(d, w, n_lobes=2, init=(torch.zeros(2, 3, 3), torch.ones(2, 2), torch.ones(2, 2)))
    with _raises("kappa_solver"):
        em_fit(d, w, kappa_solver="newton")
    ward = brdf.Ward(1.0, 0.1)
    with _raises("n_lobes"):
        fit(ward, n_lobes=0)
    with _raises("brdf"):
        fit("ward")
    with _raises("layout"):
        fit(brdf.Ward(1.0, 0.05, 0.2), layout="elevation")
    with _raises("brdf.alpha_x"):
        fit(brdf.Ward(1.0, torch.tensor([0.1, 0.2])))
    with _raises("params"):
        view_jump(torch.zeros(16, 8, 6), torch.zeros(16, 3))
    m = fit(ward, n_lobes=1, n_views=2, samples=64, max_iter=5)
    pf = prefilter(_constant_env(), base_res=8)
    with _raises("normals"):
        shade(m, pf, torch.zeros(4, 2), torch.zeros(4, 3))
    with _raises("base_res"):
        mip_chain(_constant_env(), base_res=24)
