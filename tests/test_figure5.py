"""Figure 5 of Green et al. 2006 (lobelight.studies.figure5): Gaussians vs Haar vs SH.

The tests run at 64^2 per face and K <= 3 (the figure: 256^2, K <= 10) to stay fast. 64^2 is
justified for functions (a) and (b): their 7-coefficient Haar and SH errors at 64^2 are within
0.025 (absolute) of the 256^2 and 512^2 values (docs/figure5.md). Function (c)'s narrow width
(0.014 rad) is only ~half a texel at 64^2; its 64^2 table leads to the same conclusions as the
256^2 one in docs/figure5.md.
"""

from __future__ import annotations

import itertools
import json
import math

import pytest
import torch

from lobelight.geometry import cubemap
from lobelight.lobes import sg, sh
from lobelight.studies.figure5 import (
    FLOATS_PER_GAUSSIAN,
    FUNCTIONS,
    figure5,
    fit_gaussians,
    haar_errors,
    sh_errors,
    sh_order_errors,
    transport_functions,
)

RES = 64
KMAX = 3
COUNTS = [FLOATS_PER_GAUSSIAN * k for k in range(1, KMAX + 1)]


@pytest.fixture(scope="module")
def cubes():
    return transport_functions(RES)


@pytest.fixture(scope="module")
def fits(cubes):
    return {name: fit_gaussians(c, KMAX, seed=0) for name, c in cubes.items()}


def test_functions_are_physical_transport(cubes):
    omega = cubemap.texel_solid_angles(RES, dtype=torch.float64)
    dirs = cubemap.texel_directions(RES, dtype=torch.float64)
    for name, c in cubes.items():
        assert c.shape == (6, RES, RES)
        assert bool(torch.isfinite(c).all()) and float(c.min()) >= 0
        # nothing below the ground's horizon (normal +Y): BRDF x cosine is one-sided
        assert float(c[dirs[..., 1] <= 0].abs().max()) == 0, name
        # a bounded-albedo BRDF times the cosine integrates to at most ks = 0.8
        assert float((omega * c).sum()) < 0.8, name
    # (b) is cut by the box: an edge where neighbouring texels go from lit to 0 inside the lobe
    b = cubes["b_visibility"]
    lit = b > 0.05 * b.max()
    assert bool((lit[:, :, 1:] != lit[:, :, :-1]).any())
    zero_in_lobe = (b == 0) & (dirs[..., 1] > 0) & (dirs[..., 0] > 0.3)
    assert int(zero_in_lobe.sum()) > 50


@pytest.mark.parametrize("name", list(FUNCTIONS))
def test_one_gaussian_beats_seven_sh_coefficients(cubes, fits, name):
    g1 = fits[name][0]["error"]
    assert g1 < sh_errors(cubes[name], [FLOATS_PER_GAUSSIAN])[0]


@pytest.mark.parametrize(
    "name",
    [
        "a_glossy",
        "b_visibility",
        pytest.param(
            "c_anisotropic",
            marks=pytest.mark.xfail(
                strict=True,
                reason=(
                    "the paper's claim does not hold for a Ward (0.01, 0.2) lobe: it is ~8.5x "
                    "longer than wide, and the best single isotropic Gaussian for an 8.5:1 "
                    "Gaussian streak has relative L2 error sqrt(1 - 4r^2/((1+r)(r^2+r))) = "
                    "0.82 at r = 8.5 (measured 0.79) while 7 Haar coefficients reach 0.63-0.69; "
                    "see docs/figure5.md"
                ),
            ),
        ),
    ],
)
def test_one_gaussian_beats_seven_haar_coefficients(cubes, fits, name):
    # the figure's claim, the Gaussian half (the SH half is above): one Gaussian's 7 floats fit
    # the function better than the 7 largest Haar coefficients
    g1 = fits[name][0]["error"]
    assert g1 < haar_errors(cubes[name], [FLOATS_PER_GAUSSIAN])[0]


def test_isotropic_bound_explains_the_anisotropic_lobe(fits):
    # one isotropic Gaussian against an anisotropic Gaussian of aspect r: the best normalised
    # correlation is 4 r s^2 / ((1 + s^2)(r^2 + s^2)) at s^2 = r; at r = 8.5 the error is 0.82.
    # The Ward streak is not exactly Gaussian (it is also cut by the cosine), so allow 0.1.
    r = 8.5
    bound = math.sqrt(1 - 4 * r * r / ((1 + r) * (r * r + r)))
    assert abs(fits["c_anisotropic"][0]["error"] - bound) < 0.1


@pytest.mark.parametrize("name", list(FUNCTIONS))
def test_gaussian_errors_never_grow_with_k(fits, name):
    errs = [f["error"] for f in fits[name]]
    assert len(errs) == KMAX
    assert all(b <= a for a, b in itertools.pairwise(errs)), errs
    assert all(0 <= e <= 1 for e in errs)


def test_haar_with_all_coefficients_is_exact(cubes):
    for c in cubes.values():
        full = 6 * RES * RES
        for weighting in ("solid_angle", "texel"):
            # float64 round trip: ~1e-16 relative per level
            assert haar_errors(c, [full], weighting=weighting)[0] < 1e-12
            # and keeping nothing leaves all of it
            assert haar_errors(c, [0], weighting=weighting)[0] == pytest.approx(1.0)


def test_haar_ranking_by_solid_angle_or_texel_hardly_matters(cubes):
    # ranking by energy in the norm the error is measured in (the default) is not exactly
    # optimal either: cube-map Haar is not orthonormal under solid-angle weights, and at 28
    # coefficients on (c) the plain texel ranking is measured 0.009 better. Either way the
    # baseline is the same to within 0.02.
    for c in cubes.values():
        sa = haar_errors(c, COUNTS)
        tx = haar_errors(c, COUNTS, weighting="texel")
        assert all(abs(a - b) < 0.02 for a, b in zip(sa, tx, strict=True)), (sa, tx)


def test_sh_error_decreases_with_order(cubes):
    for name, c in cubes.items():
        errs = sh_order_errors(c, range(1, 9))
        assert all(b < a for a, b in itertools.pairwise(errs)), (name, errs)
        # partial bands in between are least squares too: never worse with more coefficients
        part = sh_errors(c, range(1, 50))
        assert all(b <= a + 1e-12 for a, b in itertools.pairwise(part))


def test_sh_errors_match_the_closed_form_of_a_gaussian():
    # independent reference: an SG's band energies are z_l^2 (zonal coefficients, rotation
    # invariant) and its energy is int G^2 = int G(2 lam); the full-order LS error is then
    # sqrt(1 - sum_{l<n} z_l^2 / int G(2 lam)). Texel quadrature at 64^2 of a lam = 20 lobe
    # (0.22 rad, 9 texels) is good to ~1e-4.
    lam = 20.0
    mu = torch.nn.functional.normalize(torch.tensor([0.3, 0.8, -0.5], dtype=torch.float64), dim=0)
    dirs = cubemap.texel_directions(RES, dtype=torch.float64)
    cube = sg.evaluate(dirs, mu, lam)
    z = sh.sg_zonal(torch.tensor(lam, dtype=torch.float64), 8)
    energy = float(sg.integral(torch.tensor(2 * lam, dtype=torch.float64)))
    ref = [math.sqrt(max(0.0, 1 - float((z[:n] ** 2).sum()) / energy)) for n in range(1, 9)]
    got = sh_order_errors(cube, range(1, 9))
    assert got == pytest.approx(ref, abs=2e-3)


def test_a_function_that_is_one_gaussian_is_fitted_exactly():
    lam, amp = 150.0, 0.7
    mu = torch.nn.functional.normalize(torch.tensor([-0.4, 0.7, 0.2], dtype=torch.float64), dim=0)
    dirs = cubemap.texel_directions(RES, dtype=torch.float64)
    cube = amp * sg.evaluate(dirs, mu, lam)
    (one,) = fit_gaussians(cube, 1)
    # the fit's quadrature is the same texel grid (64^2 cells at R = 64): only the LM's float32
    # tolerance is left
    assert one["error"] < 1e-3
    assert one["lam"][0] == pytest.approx(lam, rel=0.01)
    assert one["w"][0] == pytest.approx(amp, rel=0.01)
    ang = math.acos(min(1.0, float(torch.tensor(one["mu"][0], dtype=torch.float64) @ mu)))
    assert ang * math.sqrt(lam) < 0.01  # a hundredth of the lobe's width


def test_figure5_writes_json_and_png(tmp_path):
    r = figure5(tmp_path / "fig", max_gaussians=2, res=32, names=["a_glossy"])
    files = sorted(p.name for p in (tmp_path / "fig").iterdir())
    assert files == ["figure5.json", "figure5.png"]  # no temporary names left behind
    on_disk = json.loads((tmp_path / "fig" / "figure5.json").read_text())
    assert on_disk == json.loads(json.dumps(r))
    f = r["functions"]["a_glossy"]
    assert f["coefficients"] == [7, 14]
    for key in ("gaussians", "haar", "haar_texel", "sh"):
        assert len(f[key]) == 2
    assert f["sh_full_order"]["order"] == [2, 3]
    assert (tmp_path / "fig" / "figure5.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
