"""The prefilter's fast paths against the plain forms they replace.

Each check pairs an operator's batched or restructured implementation with the direct
computation of the same quantity: the halo's merged sub-sample weights against the plain
average of the sub-samples, the batched separable passes against a loop over taps, the
windowed sum's single padded group (the GPU form) against its per-window-size groups (the CPU
form), the fast downsample, seamless padding and SH basis against their references. All are
float32 rounding apart (1e-6 relative) unless stated.
"""

from __future__ import annotations

import math

import pytest
import torch

from lobelight.envmap import _convolve as C
from lobelight.envmap import _prefilter as P
from lobelight.envmap import builtin
from lobelight.geometry import cubemap
from lobelight.lobes import sh


def _spiky(res: int, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    cube = torch.rand(6, res, res, 3, generator=g)
    cube[4, res // 3, res // 2] = 1e3  # a bright texel, where a wrong weight shows
    cube[0, res - 1, res - 1] = 1e3  # and one in a cube corner
    return cube


def _rel(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a - b).abs().max() / b.abs().max())


def test_extend_equals_the_mean_of_the_sub_samples():
    res, pad = 32, 13
    level = _spiky(res)
    rows, cols, src = C._halo_sources(res, C._halo_pad(pad))
    n = res + 2 * C._halo_pad(pad)
    ref = level.new_empty(6, n, n, 3)
    ref[:, rows, cols] = level.reshape(-1, 3)[src].mean(2)  # (6, B, 3)
    off = C._halo_pad(pad) - pad
    ref = ref[:, off : n - off, off : n - off]
    got = C.extend(level, pad)
    border = torch.ones(res + 2 * pad, res + 2 * pad, dtype=torch.bool)
    border[pad:-pad, pad:-pad] = False
    assert _rel(got[:, border], ref[:, border]) < 1e-6
    assert torch.equal(got[:, pad:-pad, pad:-pad], level)


def _passes_by_taps(x: torch.Tensor, passes) -> torch.Tensor:
    """The plan's passes as a loop over taps on whole windows (tile coordinates)."""
    row = 0
    for p in passes:
        (r0, r1), (c0, c1) = p.rows, p.cols
        n, h = p.n, p.taps.shape[1] // 2
        taps = torch.zeros(r1 - r0, n, 2 * h + 1, dtype=x.dtype)
        taps.view(-1, 2 * h + 1)[c0 : c0 + p.run] = p.taps
        out = torch.zeros(r1 - r0, n, x.shape[-1], dtype=x.dtype)
        for i, t in enumerate(range(-h, h + 1)):
            dr, dc = t * p.step[0], t * p.step[1]
            src = x[r0 - row + dr : r1 - row + dr, c0 + dc : c1 + dc]
            out[:, c0:c1] += taps[:, c0:c1, i : i + 1] * src
        x, row = out, r0
    return x


@pytest.mark.parametrize(("res", "lam"), [(64, 160.0), (64, 400.0), (32, 160.0)])
def test_batched_passes_equal_a_loop_over_taps(res, lam):
    pad, passes, _ = C._anisotropic_plan(res, lam, torch.device("cpu"), torch.float64)
    n = res // 2 + 2 * pad
    x = torch.rand(n, n, 5, dtype=torch.float64)
    got = C._run_passes(x, passes)[:, pad : pad + res // 2]
    ref = _passes_by_taps(x, passes)[:, pad : pad + res // 2]
    torch.testing.assert_close(got, ref, rtol=1e-12, atol=1e-12)


def test_anisotropic_increment_keeps_constants_and_follows_the_exact_sum():
    res, lam = 128, (128 / 5) ** 2
    const = torch.full((6, res, res, 3), 2.0)
    torch.testing.assert_close(C.anisotropic_increment(const, lam), const, rtol=1e-5, atol=0)
    # the separable passes' own error at this width (lobe 0.04 rad), near two texels 2000 times
    # brighter than the rest, is 5.6 % (relative L2); tiles or output one texel off give 16-21 %
    cube = _spiky(res)
    got = C.anisotropic_increment(cube, lam)
    ref = C.windowed_increment(cube, lam)
    assert float((got - ref).norm() / ref.norm()) < 0.075
    # float64 in, float64 out, the same values
    got64 = C.anisotropic_increment(cube.double(), lam)
    assert got64.dtype == torch.float64
    assert _rel(got64.float(), got) < 1e-5


def test_kept_tile_indices_equal_rebuilt_ones(monkeypatch):
    # the GPU keeps the gather indices in the plan, the CPU rebuilds them per call
    cube, lam = _spiky(64), 400.0
    rebuilt = C.anisotropic_increment(cube, lam)
    C._anisotropic_plan.cache_clear()
    monkeypatch.setattr(C, "_keep_indices", lambda device: True)
    try:
        kept = C.anisotropic_increment(cube, lam)
        assert C._anisotropic_plan(64, lam, torch.device("cpu"), torch.float32)[2] is not None
    finally:
        C._anisotropic_plan.cache_clear()
    assert torch.equal(kept, rebuilt)


@pytest.mark.parametrize(("res", "lam"), [(64, 195.4), (32, 120.0), (8, 400.0)])
def test_one_padded_window_group_equals_per_size_groups(res, lam, monkeypatch):
    cube = _spiky(res)
    per_size = C.windowed_increment(cube, lam)
    C._windowed_plan.cache_clear()
    monkeypatch.setattr(C, "_one_window_group", lambda device: True)
    try:
        one = C.windowed_increment(cube, lam)
    finally:
        C._windowed_plan.cache_clear()
    assert _rel(one, per_size) < 1e-6
    assert _rel(per_size, C.dense_increment(cube, lam)) < 1e-3


@pytest.mark.parametrize(("res", "pad"), [(32, 13), (64, 40)])
def test_gathered_halo_equals_the_sparse_product(res, pad, monkeypatch):
    # the GPU (and meta) gather each border texel's sources and weights, the CPU multiplies by
    # a sparse matrix: the same weights, summed in another order
    level = _spiky(res)
    sparse = C.extend(level, pad)
    C._halo_plan.cache_clear()
    monkeypatch.setattr(C, "_sparse_halo", lambda device: False)
    try:
        gathered = C.extend(level, pad)
        _, (idx, w) = C._halo_plan(res, C._halo_pad(pad), torch.device("cpu"), torch.float32)
    finally:
        C._halo_plan.cache_clear()
    assert _rel(gathered, sparse) < 1e-6
    # the padding entries weigh nothing, and every border texel's weights sum to one
    torch.testing.assert_close(w.sum(1), torch.ones(idx.shape[0], 1))
    assert idx.dtype == torch.int32 and idx.shape[1] <= C.HALO_SUBSAMPLES**2


def test_downsample_equals_the_cubemap_one():
    cube = _spiky(64)
    assert _rel(P._downsample(cube), cubemap.downsample(cube)) < 1e-6
    assert P._downsample(cube).is_contiguous()


@pytest.mark.parametrize(("res", "pad"), [(1, 1), (2, 1), (8, 1), (8, 3)])
def test_pad_seamless_corners_average_three_texels(res, pad):
    cube = _spiky(res)
    got = cubemap.pad_seamless(cube, pad)
    lo, hi = pad - 1, res + pad
    for ci, cj, di, dj in ((lo, lo, 1, 1), (lo, hi, 1, -1), (hi, lo, -1, 1), (hi, hi, -1, -1)):
        three = got[:, ci + di, cj + dj] + got[:, ci, cj + dj] + got[:, ci + di, cj]
        torch.testing.assert_close(got[:, ci, cj], three / 3)
    assert torch.equal(got[:, pad : pad + res, pad : pad + res], cube)


def test_sh_basis_rows_equal_the_sh_module():
    d = cubemap.texel_directions(8, dtype=torch.float64).reshape(-1, 3)
    got = C._sh_basis_rows(d, 12).T
    torch.testing.assert_close(got, sh.basis(d, 12), rtol=0, atol=1e-12)


def test_inverse_langevin_inverts_the_mean_cosine():
    for lam in (1e-4, 0.3, 5.0, 700.0, 2e5):
        a = float(P._langevin(torch.tensor(lam, dtype=torch.float64)))
        assert P._mean_cosine(lam) == pytest.approx(a, rel=1e-14)
        assert P._inverse_langevin(a) == pytest.approx(lam, rel=1e-9)
    assert P._inverse_langevin(0.0) == 0.0
    assert math.isinf(P._inverse_langevin(1.0))


def test_a_cold_build_equals_a_warm_one():
    cube = builtin().to_cubemap(64)
    P.clear_memory_caches()
    cold = P.prefilter(cube, base_res=64, cache=False)
    warm = P.prefilter(cube, base_res=64, cache=False)
    for a, b in zip(cold.levels, warm.levels, strict=True):
        assert torch.equal(a, b) and a.is_contiguous() and a.dtype == torch.float32
