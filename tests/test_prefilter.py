"""Gaussian-prefiltered lighting against brute-force integration over the full map.

Reference: ``sum_t exp(lam (mu.w_t - 1)) L_t Omega_t`` over every texel of a cube map four times
finer than the chain's base (exact texel solid angles, float64), i.e. direct quadrature of the
lighting with no prefiltering. Lobe axes are drawn uniformly and also around the brightest texel
(the sun), where interpolation errors are largest. The error measure is the relative L2 error
over a set of lobe axes at one sharpness, ``||I_chain - I_ref|| / ||I_ref||``.
"""

from __future__ import annotations

import math

import pytest
import torch

from conftest import REAL_ENVMAPS
from lobelight.envmap import builtin, load, prefilter
from lobelight.errors import InputError
from lobelight.geometry import cubemap
from lobelight.lobes.sg import integral as sg_integral

BASE = 64  # chain base resolution in tests: lam_max = (64 / 5)^2 = 164 (CPU time, see below)
LAMS = [0.5, 1.0, 2.0, 5.0, 12.0, 30.0, 70.0, 150.0]
# Measured at BASE = 64 over the built-in sky and all eight real maps (docs/results.md): worst
# 1.8 % for lam <= 70 and 2.7 % at lam = 150, within 10 % of the chain's lam_max, where the
# Gaussian spans 2.6 texels and bilinear lookup is at its limit. The 2 % goal is asserted where
# it is met; 3 % at the top still fails a wrong level ladder, a missing solid-angle weight, a
# mis-oriented face or a cascade drift (errors of 5-100 %).
TOL = 0.02
TOL_TOP = 0.03


def _brute(cube: torch.Tensor, mu: torch.Tensor, lam: float) -> torch.Tensor:
    res = cube.shape[1]
    d = cubemap.texel_directions(res, dtype=torch.float64).reshape(-1, 3)
    lo = (cube.double() * cubemap.texel_solid_angles(res, dtype=torch.float64)[..., None]).reshape(
        -1, 3
    )
    return torch.exp(lam * (mu.double() @ d.T - 1)) @ lo


def _axes(cube: torch.Tensor, lam: float, n: int = 48) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(7)
    uni = torch.nn.functional.normalize(torch.randn(n, 3, generator=g, dtype=torch.float64), dim=-1)
    res = cube.shape[1]
    lum = cube.sum(-1).reshape(-1)
    sun = cubemap.texel_directions(res, dtype=torch.float64).reshape(-1, 3)[lum.argmax()]
    near = torch.nn.functional.normalize(
        sun + torch.randn(n, 3, generator=g, dtype=torch.float64) / math.sqrt(lam), dim=-1
    )
    return {"uniform": uni, "sun": near}


def _check_env(env) -> float:
    fine = env.to_cubemap(4 * BASE)
    pf = prefilter(fine, base_res=BASE)
    worst = 0.0
    for lam in LAMS:
        for kind, mu in _axes(fine, lam).items():
            ref = _brute(fine, mu, lam)
            got = pf.integrate(mu.float(), torch.full((mu.shape[0],), lam)).double()
            err = float((got - ref).norm() / ref.norm())
            worst = max(worst, err)
            tol = TOL if lam <= 100 else TOL_TOP
            assert err <= tol, (
                f"{env.name}: lam={lam} {kind} axes: relative L2 error {err:.4f} > {tol}"
            )
    return worst


def test_constant_environment_integrates_exactly():
    # Every level is a normalised average, so a constant map must give c * Z(lam) for any lam;
    # 1e-5 is float32 rounding of the stored levels.
    cube = torch.full((6, 32, 32, 3), 2.5)
    pf = prefilter(cube, base_res=32)
    mu = torch.nn.functional.normalize(torch.randn(100, 3), dim=-1)
    for lam in [0.01, 0.5, 3.0, 40.0, pf.lam_max, 10 * pf.lam_max]:
        got = pf.integrate(mu, torch.full((100,), lam))
        ref = 2.5 * sg_integral(torch.tensor(lam, dtype=torch.float64)).float()
        torch.testing.assert_close(got, ref.expand_as(got), rtol=1e-5, atol=0)


def test_builtin_matches_brute_force():
    _check_env(builtin())


@pytest.mark.parametrize("path", REAL_ENVMAPS, ids=lambda p: p.name)
def test_real_maps_match_brute_force(path):
    _check_env(load(path))


def test_level_ladder_and_gl_layout():
    pf = prefilter(torch.rand(6, 32, 32, 3), base_res=32, phases=4)
    assert pf.lam_max == pytest.approx((32 / 5) ** 2)
    ratios = pf.lambdas[:-1] / pf.lambdas[1:]
    torch.testing.assert_close(ratios, torch.full_like(ratios, math.sqrt(2)))
    chains = pf.gl_chains()
    assert len(chains) == 4 and all(len(c) == 6 for c in chains)  # mips 32, 16, 8, 4, 2, 1
    assert [c.shape for c in chains[0]] == [(6, r, r, 3) for r in (32, 16, 8, 4, 2, 1)]


def test_lookup_at_a_level_returns_that_level():
    # At lam = lam_k and texel centres the lookup must return the stored texels (t = 0 or 1,
    # bilinear weights 0/1); 1e-5 covers float32 rounding of the face coordinates.
    pf = prefilter(torch.rand(6, 16, 16, 3), base_res=16)
    k = 5
    res = pf.levels[k].shape[1]
    d = cubemap.texel_directions(res)
    got = pf.lookup(d, torch.full(d.shape[:-1], float(pf.lambdas[k])))
    torch.testing.assert_close(got, pf.levels[k], rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [({"base_res": 48}, "base_res"), ({"phases": 0}, "phases"), ({"blend": "x"}, "blend")],
)
def test_bad_parameters(kwargs, name):
    with pytest.raises(InputError, match=name):
        prefilter(torch.rand(6, 16, 16, 3), **{"base_res": 16, **kwargs})


# Sharp lobes need the full 512 base (lam_max = 10486). Reference: the brute-force sum over a
# 1024^2 cube map (the same map the chain is built from, box-downsampled). Measured: near the
# sun at most 0.8 %; over 48 uniform axes up to 6.2 % (rooitou at lam = 1000), where one axis
# lands 3-4 sigma from a sun 1e5 times brighter than the sky and the relative error of
# bilinear interpolation in a Gaussian's tail dominates (over 2000 axes the same map is 0.5 %).
SHARP_LAMS = [1000.0, 10000.0]
SHARP_TOL = {"sun": 0.01, "uniform": 0.08}


def _check_sharp(env) -> None:
    fine = env.to_cubemap(1024)
    pf = prefilter(fine, base_res=512)
    d = cubemap.texel_directions(1024).reshape(-1, 3)
    lo = (fine * cubemap.texel_solid_angles(1024)[..., None]).reshape(-1, 3)
    for lam in SHARP_LAMS:
        for kind, mu in _axes(fine, lam).items():
            mu = mu.float()
            # float32 is enough here: dots are exact to 6e-8, i.e. lam * 6e-8 < 1e-3 in the exponent
            ref = torch.cat(
                [torch.exp(lam * (mu[i : i + 8] @ d.T - 1)) @ lo for i in range(0, 48, 8)]
            )
            got = pf.integrate(mu, torch.full((mu.shape[0],), lam))
            err = float((got - ref).norm() / ref.norm())
            assert err <= SHARP_TOL[kind], f"{env.name}: lam={lam} {kind}: {err:.4f}"


# Each builds a 1024^2 cube map and a 512-base chain (the default) and sums 6.3 M texels per
# axis: about 20 s each on a quiet 2-core machine.
def test_builtin_sharp_lobes_at_base_512():
    _check_sharp(builtin())


@pytest.mark.parametrize("path", REAL_ENVMAPS, ids=lambda p: p.name)
def test_real_maps_sharp_lobes_at_base_512(path):
    _check_sharp(load(path))
