"""The Gaussian fit (Green et al. 2006, eq. 6) on transport made from known Gaussians."""

from __future__ import annotations

import math

import pytest
import torch

from lobelight import fit, scene, transport
from lobelight.fit import FitData, Gaussians, Weights, _lm
from lobelight.fit._objective import conserve_factor
from lobelight.geometry import cubemap, sphere
from lobelight.lobes import sg

VIEWS = sphere.geodesic_views()
NBR = sphere.geodesic_neighbor_table()


def _synthetic(
    lams_sharp, *, broad: float | None = None, jitter: float = 0.0, seed: int = 0, res: int = 8
):
    """Transport of B vertices made of a lobe at each view's mirror direction (sharpness per
    vertex) and optionally a broad lobe tilted toward the normal, sampled like the real fit."""
    g = torch.Generator().manual_seed(seed)
    b = len(lams_sharp)
    n = torch.nn.functional.normalize(
        torch.randn(b, 3, generator=g) + torch.tensor([0, 3.0, 0]), dim=-1
    )
    refl = 2 * (VIEWS[None] * n[:, None]).sum(-1, keepdim=True) * n[:, None] - VIEWS[None]
    below = (VIEWS[None] * n[:, None]).sum(-1) <= 0
    lam1 = torch.tensor(lams_sharp)[:, None].expand(b, VIEWS.shape[0])
    if jitter:  # per-view wobble of the lobes: what noisy or ambiguous data does to a fit
        kick = jitter * torch.randn(refl.shape, generator=g)
        refl = torch.nn.functional.normalize(refl + kick, dim=-1)
        lam1 = lam1 * torch.exp(jitter * 4 * torch.randn(lam1.shape, generator=g))
    ld, lw = sphere.local_grid(refl, lam1 / 4, n_theta=12)
    gd = cubemap.texel_directions(res).reshape(-1, 3)  # the global set outside the cap
    gom = cubemap.texel_solid_angles(res).reshape(-1)
    inside = (refl[:, :, None] * gd).sum(-1) > torch.cos(sphere.lobe_cap_angle(lam1 / 4))[..., None]
    gw = torch.where(inside, 0.0, gom.expand(b, VIEWS.shape[0], -1))
    dirs = torch.cat([ld.float(), gd.expand(b, VIEWS.shape[0], -1, 3)], 2)
    wts = torch.cat([lw.float(), gw], 2)
    w1 = torch.tensor([1.0, 0.7, 0.4])
    vals = sg.evaluate(dirs, refl[:, :, None], lam1[..., None])[..., None] * w1
    truth = {"mu": refl, "lam": lam1, "w": w1, "below": below}
    if broad is not None:
        mu2 = torch.nn.functional.normalize(refl + 0.6 * n[:, None], dim=-1)
        w2 = torch.tensor([0.2, 0.3, 0.4])
        vals = vals + sg.evaluate(dirs, mu2[:, :, None], torch.tensor(broad))[..., None] * w2
        truth.update(mu2=mu2, w2=w2, lam2=broad)
    vals = torch.where(below[..., None, None], 0.0, vals)
    return FitData(dirs, wts, vals, below), truth


def _angles(a, b):
    return torch.acos((a * b).sum(-1).clamp(-1, 1))


@pytest.mark.parametrize("lam", [2.0, 1e4])
def test_one_gaussian_recovered_from_a_perturbed_start(lam):
    data, t = _synthetic([lam, lam])
    ok = ~t["below"]
    g0 = fit.initial_guess(data, 1)
    gen = torch.Generator().manual_seed(1)
    sigma = g0.lam.rsqrt()[..., None]
    start = torch.nn.functional.normalize(
        g0.mu + 0.5 * sigma * torch.randn(g0.mu.shape, generator=gen), dim=-1
    )
    g, terms = fit.fit_batch(data, 1, NBR, init=Gaussians(g0.w, start, g0.lam * 1.5), iters=40)
    ang = _angles(g.mu[:, :, 0], t["mu"])[ok]
    # means within 5 % of the lobe width (the M term's pull on a curved field of means is a
    # fraction of that), sharpness within 5 %, weights within 5 %
    assert float((ang * math.sqrt(lam)).max()) < 0.05
    assert float((g.lam[..., 0][ok] / lam - 1).abs().max()) < 0.05
    assert float((g.w[:, :, 0][ok] / t["w"] - 1).abs().max()) < 0.05
    assert float(terms["D"].max()) < 1e-3
    assert bool((g.w[t["below"]] == 0).all())


def test_two_gaussians_sharp_over_broad():
    # the broad lobe lives on the global set: 16^2 texels (0.12 rad) resolve its 0.35 rad width
    data, t = _synthetic([300.0, 3000.0], broad=8.0, res=16)
    ok = ~t["below"]
    _, terms1 = fit.fit_batch(data, 1, NBR)
    two, terms2 = fit.fit_batch(data, 2, NBR)
    # one Gaussian cannot represent both; two do, to quadrature precision
    assert float(terms1["D"].min()) > 1e-2
    assert float(terms2["D"].max()) < 1e-3
    k = two.lam.argmax(-1, keepdim=True)
    sharp_mu = torch.gather(two.mu, 2, k[..., None].expand(-1, -1, 1, 3))[:, :, 0]
    broad_mu = torch.gather(two.mu, 2, (1 - k)[..., None].expand(-1, -1, 1, 3))[:, :, 0]
    sharp_lam = two.lam.amax(-1)
    assert float(_angles(sharp_mu, t["mu"])[ok].max()) < 0.01  # ~ a fifth of a sharp width
    assert float(_angles(broad_mu, t["mu2"])[ok].max()) < 0.05  # broad lobe: width 0.35 rad
    assert float((sharp_lam[ok] / t["lam"][ok] - 1).abs().max()) < 0.05


def test_mean_and_sigma_terms_smooth_parameters_across_views():
    # lobes that wobble from view to view: alpha-only fitting follows every wobble, M and V
    # trade a little data error for parameters that vary smoothly (and so interpolate well)
    # The smoothing terms are checked with the plain L2 weights: with the light conserved
    # (the default) a view's weight follows its sharpness (w Z(lam) is held), so smoothing
    # sigma also moves the weight against the data and V drops less (0.57x here); that case
    # is checked below with its own bound.
    data, _ = _synthetic([60.0, 60.0], jitter=0.05, seed=3)
    plain = Weights(beta=0.0, gamma=0.0, delta=0.0)
    _, tp = fit.fit_batch(data, 1, NBR, weights=plain, conserve=False)
    _, ts = fit.fit_batch(data, 1, NBR, weights=Weights(beta=0.5, gamma=0.5), conserve=False)
    _, cp = fit.fit_batch(data, 1, NBR, weights=plain)
    _, cs = fit.fit_batch(data, 1, NBR, weights=Weights(beta=0.5, gamma=0.5))
    assert bool((cs["V"] < 0.75 * cp["V"]).all()), (cs["V"], cp["V"])
    assert bool((cs["M"] <= cp["M"]).all()), (cs["M"], cp["M"])
    # roughness = the M and V terms themselves: how far each view's mean (sigma) is from its
    # neighbours' average, i.e. the discrete Laplacian of the field, not its gradient (the
    # mirror direction legitimately turns ~0.7 rad between neighbouring views). Measured here:
    # V drops 2.5x at beta = gamma = 0.5; M moves little, because a 0.05 rad wobble of a lobe
    # 0.13 rad wide is firmly supported by the data (moving it costs ~30x more in D than M
    # gains) -- M's job is the views without data and the correspondence of several lobes.
    assert bool((ts["V"] < 0.5 * tp["V"]).all()), (ts["V"], tp["V"])
    assert bool((ts["M"] <= tp["M"]).all()), (ts["M"], tp["M"])
    # the price in data error stays small (relative L2 error squared)
    assert float(ts["D"].max()) < 1e-3
    assert float(tp["D"].max()) < float(ts["D"].min())


def test_lm_agrees_with_autograd_adam():
    # the same objective minimised by an independent method lands on the same Gaussians
    data, _ = _synthetic([40.0], jitter=0.03, seed=5)
    lm, t_lm = fit.fit_batch(data, 1, NBR, method="lm", iters=30)
    ad, t_ad = fit.fit_batch(data, 1, NBR, method="adam", iters=300)
    w = Weights()

    def total(t):
        return t["D"] + w.beta * t["M"] + w.gamma * t["V"]

    total_lm, total_ad = total(t_lm), total(t_ad)
    # the data term agrees; the alignment terms over the views without data converge slowly in
    # LM (block-Jacobi: a fill propagates one view per iteration), measured 1.29x Adam's value
    # after 30 iterations, 1.13x after 120
    assert float(t_lm["D"]) <= 1.05 * float(t_ad["D"]) + 1e-6
    assert float(total_lm) <= float(total_ad) * 1.35
    ok = ~data.below
    assert float(_angles(lm.mu[:, :, 0], ad.mu[:, :, 0])[ok].max()) < 0.02


def test_gather_resolves_a_sharp_phong_lobe():
    # on a convex sphere the transport of a Phong lobe is known: its quadrature over the
    # gathered samples is the directional albedo, and the fitted Gaussian's integral matches
    sc = scene.builtin("sphere", subdivisions=2, model="phong", roughness=0.03)
    tr = transport.Transport(sc)
    vidx = torch.tensor([3, 40])
    data = fit.gather(tr, vidx, VIEWS)
    integral = (data.weights[..., None] * data.values).sum(2)  # (B, J, 3)
    n = sc.mesh.normals[vidx]
    ok = (VIEWS[None] * n[:, None]).sum(-1) > 0.3  # away from grazing
    spec = sc.materials.specular
    g = torch.Generator().manual_seed(0)
    u = torch.rand(4000, 1, 2, generator=g)
    for bi in range(2):
        views = VIEWS[ok[bi]]
        _, wgt, _ = spec.sample(
            views.expand(4000, -1, 3),
            n[bi].expand(4000, views.shape[0], 3),
            u.expand(-1, views.shape[0], 2),
        )
        ref = wgt.mean(0)
        se = wgt.std(0) / math.sqrt(4000)
        got = integral[bi][ok[bi]]
        assert bool(((got - ref).abs() <= 0.01 * ref + 3 * se).all())
    _, terms = fit.fit_batch(data, 1, NBR)
    # a Phong lobe is close to, but not exactly, a Gaussian (its cosine factor and horizon
    # cut): the relative L2 error of one Gaussian is a few per cent
    assert float(terms["D"].max()) < 0.02


def test_neighbour_mean_is_each_views_average_of_its_neighbours():
    # the one matrix product over all vertices against the average written out view by view
    from lobelight.fit._objective import _neighbour_mean

    g = torch.Generator().manual_seed(1)
    x = torch.randn(5, NBR.shape[0], 2, 3, generator=g, dtype=torch.float64)
    got = _neighbour_mean(x, NBR)
    for v in range(NBR.shape[0]):
        ids = NBR[v][NBR[v] >= 0]
        want = x[:, ids].mean(1)
        assert torch.allclose(got[:, v], want, atol=1e-12), v
    assert _neighbour_mean(x[:0], NBR).shape == (0, NBR.shape[0], 2, 3)


def test_graded_cap_points_lie_on_their_rings_for_a_mirror_sharp_lobe():
    # the cap's points at 1 - cos = s of their ring from the axis, equally spaced around it,
    # unit length; at the smallest peak scale (1e-6) the first ring is 1e-7 from the axis, so
    # its radius (4.5e-4 rad) is found to a few 1e-4 relative only if the points are formed
    # from the ring's radius and height, not from a float32 1 - s
    from lobelight.fit._data import graded_cap

    g = torch.Generator().manual_seed(2)
    axis = torch.nn.functional.normalize(torch.randn(3, 4, 3, generator=g), dim=-1)
    scale = torch.tensor([1e-6, 1e-4, 1e-2, 0.5]).expand(3, 4)
    s_max = torch.tensor([1e-3, 0.1, 0.5, 2.0]).expand(3, 4)
    n_theta, n_phi = 12, 24
    dirs, w = graded_cap(axis, scale, s_max, n_theta=n_theta, n_phi=n_phi)
    assert dirs.shape == (3, 4, n_theta * n_phi, 3) and w.shape == (3, 4, n_theta * n_phi)
    d = dirs.double().reshape(3, 4, n_theta, n_phi, 3)
    assert float((d.norm(dim=-1) - 1).abs().max()) < 1e-6
    # angle from the axis per point, against the ring's (all of a ring's points alike)
    a = axis.double()[:, :, None, None]
    angle = torch.atan2(torch.linalg.cross(a.expand_as(d), d).norm(dim=-1), (a * d).sum(-1))
    ring = angle.mean(-1, keepdim=True)
    assert float(((angle - ring).abs() / ring).max()) < 1e-3
    # the first ring of the sharpest cap: s = scale (exp(u_0) - 1) from Gauss-Legendre's first
    # node, so 1 - cos(angle) = s
    x, _ = sphere.gauss_legendre(n_theta)
    top = math.log1p(1e-3 / 1e-6)
    s0 = 1e-6 * math.expm1(0.5 * (float(x[0]) + 1) * top)
    assert abs(float(ring[0, 0, 0, 0]) - math.acos(1 - s0)) < 1e-3 * math.acos(1 - s0)
    # the weights sum to the cap's solid angle 2 pi s_max
    assert torch.allclose(w.double().sum(-1), 2 * math.pi * s_max.double(), rtol=1e-5)


def test_gather_again_from_the_kept_visibility_gives_the_same_samples():
    # the relaxation gathers a chunk again from the lobe estimate and the samples' visibility
    # the flood fill kept (as bits): the same directions, weights and values, with no ray
    from lobelight.fit._chunk import pack_bits, unpack_bits
    from lobelight.fit._data import CAP_SAMPLES, GLOBAL_SAMPLES

    sc = scene.builtin("knot")  # it shadows itself and its ground
    tr = transport.Transport(sc)
    vidx = torch.arange(0, sc.mesh.n_vertices, 29)
    lobe = fit.lobe_estimate(tr, vidx, VIEWS)
    first = fit.gather(tr, vidx, VIEWS, lobe=lobe)
    cap, glob = first.visibility
    assert cap.shape == (*first.dirs.shape[:2], CAP_SAMPLES)
    assert glob.shape == (vidx.numel(), GLOBAL_SAMPLES)
    assert 0.05 < float(glob.float().mean()) < 0.6  # some rays blocked, the others not
    kept = tuple(unpack_bits(pack_bits(x), x.shape[-1]) for x in (cap, glob))
    calls = []
    real = tr.visibility
    tr.visibility = lambda *a, **k: calls.append(1) or real(*a, **k)
    again = fit.gather(tr, vidx, VIEWS, lobe=lobe, visibility=kept)
    assert not calls
    for a, b in ((first.dirs, again.dirs), (first.weights, again.weights)):
        assert torch.equal(a, b)
    assert torch.equal(first.values, again.values)


def test_bits_pack_eight_to_a_byte_and_unpack_to_the_same():
    from lobelight.fit._chunk import pack_bits, unpack_bits

    g = torch.Generator().manual_seed(3)
    x = torch.rand(4, 3, 21, generator=g) < 0.5
    p = pack_bits(x)
    assert p.dtype == torch.uint8 and p.shape == (4, 3, 3)
    assert int(p[0, 0, 0]) == sum(int(x[0, 0, i]) << i for i in range(8))
    assert torch.equal(unpack_bits(p, 21), x)


def test_weights_of_coincident_lobes_are_finite():
    # regression: two Gaussians that coincide (same mean and sharpness, e.g. N = 2 on a single
    # lobe) made the float32 normal equations exactly singular and stopped a knot fit
    from lobelight.fit._objective import solve_weights

    g = torch.Generator().manual_seed(0)
    d = torch.nn.functional.normalize(torch.randn(1, 1, 50, 3, generator=g), dim=-1)
    data = FitData(
        d,
        torch.ones(1, 1, 50),
        torch.rand(1, 1, 50, 3, generator=g),
        torch.zeros(1, 1, dtype=torch.bool),
    )
    mu = torch.tensor([0, 1.0, 0]).expand(1, 1, 2, 3).contiguous()
    w = solve_weights(data, mu, torch.full((1, 1, 2), 5.0))
    assert bool(torch.isfinite(w).all())
    # the ridge splits the weight evenly between the two copies
    torch.testing.assert_close(w[0, 0, 0], w[0, 0, 1])


def test_flip_count_counts_swapped_arrangements_of_live_gaussians():
    # two Gaussians 0.3 rad apart; the neighbour has them swapped in views 0-4 of 10
    j = 10
    a = torch.tensor([[0.0, 0.0, 1.0], [0.3, 0.0, 1.0]])
    a = torch.nn.functional.normalize(a, dim=-1).expand(1, j, 2, 3).clone()
    b = a.clone()
    b[:, :5] = a[:, :5].flip(-2)
    active = torch.ones(1, j, dtype=torch.bool)
    assert fit.flip_count(a, b, active).tolist() == [5]
    assert fit.flip_count(a, a, active).tolist() == [0]
    assert fit.flip_count(a, b, active & (torch.arange(j) >= 3)).tolist() == [2]
    # a Gaussian of zero weight has no arrangement: with it dead in some views those views do
    # not count (without the masks they would, by chance, about half the time)
    live = torch.ones(1, j, 2, dtype=torch.bool)
    dead = live.clone()
    dead[:, :2, 1] = False
    assert fit.flip_count(a, b, active, live, dead).tolist() == [3]


def test_compact_data_gives_the_same_fit_as_the_whole_sample_set():
    # a sample of weight 0 adds nothing to any integral: dropping them (FitData.compact) leaves
    # the energy, the solved weights and the fit itself as they are, up to float32 summation
    # order (rtol 1e-5 for sums of a few hundred terms; the fitted lobes 1e-3, the LM's accept
    # tests seeing the same costs to rounding)
    data, _ = _synthetic([40.0, 400.0], broad=4.0)
    g = torch.Generator().manual_seed(1)
    drop = torch.rand(data.weights.shape, generator=g) < 0.4
    data = FitData(data.dirs, torch.where(drop, 0.0, data.weights), data.values, data.below)
    small = data.compact()
    assert small.weights.shape[-1] < data.weights.shape[-1]
    assert int((small.weights > 0).sum()) == int((data.weights > 0).sum())
    torch.testing.assert_close(small.energy(), data.energy(), rtol=1e-5, atol=1e-12)
    g0 = fit.initial_guess(data, 1, nbr_views=NBR)
    w_all = fit._objective.solve_weights(data, g0.mu, g0.lam)
    w_small = fit._objective.solve_weights(small, g0.mu, g0.lam)
    torch.testing.assert_close(w_small, w_all, rtol=1e-4, atol=1e-8)
    a, ta = fit.fit_batch(data, 1, NBR, iters=5)
    b, tb = fit.fit_batch(small, 1, NBR, iters=5)
    torch.testing.assert_close(tb["D"], ta["D"], rtol=1e-3, atol=1e-7)
    torch.testing.assert_close(b.mu, a.mu, rtol=0, atol=1e-3)


def test_gaussians_at_the_samples_match_the_half_chord_evaluation():
    # the fit's fused float64 exponent against lobelight.lobes.sg.evaluate's half-chord form,
    # both exact to float32 rounding of G: relative 2e-5 where the exponent reaches -100
    # (float32's 6e-8 of the argument, times 100, plus the half-chord's own rounding), for
    # lobes from 0.5 to the fit's 3e4, samples near the mean and far from it
    g = torch.Generator().manual_seed(3)
    mu = torch.nn.functional.normalize(torch.randn(2, 4, 2, 3, generator=g), dim=-1)
    lam = torch.tensor([0.5, 30.0, 3e3, 3e4]).reshape(1, 4, 1).expand(2, 4, 2).contiguous()
    near = mu[:, :, :1] + torch.randn(2, 4, 50, 3, generator=g) * lam[..., :1, None] ** -0.5
    dirs = torch.nn.functional.normalize(torch.cat([near, torch.randn(2, 4, 50, 3)], 2), dim=-1)
    got = fit._objective.gaussians_at(dirs, mu, lam)  # (B, J, N, S)
    ref = sg.evaluate(dirs[:, :, None], mu[:, :, :, None], lam[..., None])
    torch.testing.assert_close(got, ref, rtol=2e-5, atol=1e-30)


def _vp_residual(dirs, wts, vals, mu, lam, theta, light):
    """The variable-projection residual ``sqrt(W) (G w*(theta) - T)`` of one view (flattened),
    with ``w*`` the least-squares weights for the lobes moved by ``theta`` (N, 3) as the LM moves
    them; under ``sum_k Z(lam_k) w_kc = light_c`` where ``light`` is given (a KKT solve)."""
    t, s, _ = sphere.frame(mu)
    sigma = lam.rsqrt()[:, None]
    m = torch.nn.functional.normalize(mu + sigma * (theta[:, :1] * t + theta[:, 1:2] * s), dim=-1)
    lm = lam * torch.exp(theta[:, 2])
    g = torch.exp(lm[:, None] * (m @ dirs.T - 1))  # (N, S)
    a = (g * wts) @ g.T
    rhs = (g * wts) @ vals  # (N, 3)
    if light is None:
        w = torch.linalg.solve(a, rhs)
    else:
        n = a.shape[0]
        z = sg.integral(lm)
        kkt = torch.zeros(n + 1, n + 1, dtype=a.dtype)
        kkt[:n, :n], kkt[:n, n], kkt[n, :n] = a, z, z
        w = torch.linalg.solve(kkt, torch.cat([rhs, light[None]], 0))[:n]
    return (wts.sqrt()[:, None] * (g.T @ w - vals)).reshape(-1)


@pytest.mark.parametrize("conserve", [False, True])
def test_lm_gauss_newton_matrix_is_the_variable_projections(conserve):
    # The LM's Gauss-Newton matrix for two overlapping lobes (a sharp core on a broad skirt),
    # against J^T J of the variable-projection residual differentiated by autograd through an
    # independent solve of the weights (a KKT system under the light's constraint). With data
    # the lobes represent exactly, the residual is 0 at the truth and Kaufman's matrix is
    # exact there: the two agree to float64 rounding (bound 1e-8 of the largest entry).
    # Holding the weights instead (the rows' products alone) is off by over a tenth of it
    # here, so the check tells the two apart.
    dirs, wts = sphere.fibonacci(4000, dtype=torch.float64)
    mu = torch.tensor([[0.1, 0.2, 1.0], [0.0, 0.35, 1.0]], dtype=torch.float64)
    mu, lam = torch.nn.functional.normalize(mu, dim=-1), torch.tensor([60.0, 6.0]).double()
    w = torch.tensor([[1.0, 0.8, 0.6], [0.3, 0.35, 0.4]], dtype=torch.float64)
    g = torch.exp(lam[:, None] * (mu @ dirs.T - 1))  # (N, S)
    vals = g.T @ w  # (S, 3): two Gaussians exactly
    light = (sg.integral(lam)[:, None] * w).sum(0) if conserve else None
    jac = torch.autograd.functional.jacobian(
        lambda th: _vp_residual(dirs, wts, vals, mu, lam, th, light),
        torch.zeros(2, 3, dtype=torch.float64),
        vectorize=True,
        strategy="forward-mode",
    ).reshape(-1, 6)
    ref = jac.T @ jac  # (6, 6), parameters (lobe, a/b/z)
    # the LM's pieces at the truth: scaled rows per lobe (a, b, z), as in lobelight.fit._lm
    t, s, _ = sphere.frame(mu)
    sw = wts.sqrt()
    gs = g * sw
    rows = torch.stack(
        [
            gs * (lam * lam.rsqrt())[:, None] * (t @ dirs.T),
            gs * (lam * lam.rsqrt())[:, None] * (s @ dirs.T),
            gs * (lam[:, None] * (mu @ dirs.T - 1) + (conserve_factor(lam)[:, None] * conserve)),
        ],
        1,
    ).reshape(6, -1)
    jj, jg = rows @ rows.T, rows @ gs.T
    free = _lm._free_weights((gs @ gs.T)[None], lam[None], w[None], conserve)[0]
    ww = (w @ w.T).repeat_interleave(3, 0).repeat_interleave(3, 1)
    ours = _lm._projected(jj[None], jg[None], free[None])[0] * ww
    held = jj * ww
    scale = ref.abs().max()
    assert float((ours - ref).abs().max() / scale) < 1e-8
    assert float((held - ref).abs().max() / scale) > 0.1
