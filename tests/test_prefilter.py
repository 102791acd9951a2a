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

from conftest import REAL_ENVMAPS, needs_shared
from lobelight import cubemap
from lobelight.envmap import builtin, load, prefilter, sg_integral
from lobelight.errors import InputError

BASE = 64  # chain base resolution in tests: lam_max = (64 / 5)^2 = 164 (CPU time, see below)
LAMS = [0.5, 1.0, 2.0, 5.0, 12.0, 30.0, 70.0, 150.0]
# Measured worst case at BASE = 64: 6.1 % relative L2 error (studio_small_03, softbox edges),
# 4.2 % on the built-in sky (lam = 2), 2.2 % on lebombo. The goal is 2 %; the gap is
# recorded in docs/results.md. 7 % leaves room over the measured 6.1 % and still fails a wrong
# level ladder, a missing solid-angle weight or a mis-oriented face (errors of 10-100 %).
TOL = 0.07


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


def _check_env(env, *, tol: float = TOL) -> float:
    fine = env.to_cubemap(4 * BASE)
    pf = prefilter(fine, base_res=BASE)
    worst = 0.0
    for lam in LAMS:
        for kind, mu in _axes(fine, lam).items():
            ref = _brute(fine, mu, lam)
            got = pf.integrate(mu.float(), torch.full((mu.shape[0],), lam)).double()
            err = float((got - ref).norm() / ref.norm())
            worst = max(worst, err)
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


@needs_shared
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
