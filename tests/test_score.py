"""The high-pass scores of lobelight.studies.score against closed forms and Monte Carlo.

Images are grey (luminance = value: the Rec. 709 weights sum to 1) and kept in the sRGB curve's
linear segment (displayed value = 12.92 x below 0.0031308 at exposure 0), so that the displayed
luminance is known in closed form.
"""

from __future__ import annotations

import math

import pytest
import torch

from lobelight.studies.score import (
    HIGHPASS_SIGMA,
    highpass_energy,
    highpass_ratio,
    highpass_window_mask,
    noise_highpass_energy,
)

#: The sRGB curve's slope in its linear segment.
SLOPE = 12.92
#: Largest linear value that stays in that segment at exposure 0.
LINEAR_MAX = 0.0031308


def _grey(x: torch.Tensor) -> torch.Tensor:
    """``(H, W, 3)`` grey image of ``(H, W)`` values."""
    return x[..., None].expand(*x.shape, 3).double()


def _weights(sigma: float = HIGHPASS_SIGMA):
    """The filter's 2-D weights written out independently: ``(centre weight, sum of squares)``."""
    r = math.ceil(3 * sigma)
    x = torch.arange(-r, r + 1, dtype=torch.float64)
    g = torch.exp(-0.5 * (x / sigma) ** 2)
    g2 = torch.outer(g, g)
    g2 = g2 / g2.sum()
    return float(g2[r, r]), float((g2**2).sum())


def _smooth(h: int = 64, w: int = 80) -> torch.Tensor:
    """A smooth grey image (a wide bump over a ramp) in the linear segment."""
    yy, xx = torch.meshgrid(
        torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64), indexing="ij"
    )
    bump = torch.exp(-((yy - h / 2) ** 2 + (xx - w / 2) ** 2) / (2 * 15.0**2))
    return _grey(LINEAR_MAX * (0.2 + 0.3 * xx / w + 0.4 * bump))


def test_window_mask_keeps_pixels_whose_whole_window_is_in_the_mask():
    mask = torch.zeros(20, 30, dtype=torch.bool)
    mask[2:18, 5:25] = True
    r = math.ceil(3 * HIGHPASS_SIGMA)
    expect = torch.zeros_like(mask)
    expect[2 + r : 18 - r, 5 + r : 25 - r] = True
    assert torch.equal(highpass_window_mask(mask), expect)
    # the image's border counts as outside
    assert not highpass_window_mask(torch.ones(20, 30, dtype=torch.bool))[:r].any()


def test_a_linear_ramp_has_no_highpass_energy():
    # a symmetric normalised filter reproduces a linear function: its high-pass is zero
    yy, xx = torch.meshgrid(
        torch.arange(40, dtype=torch.float64), torch.arange(50, dtype=torch.float64), indexing="ij"
    )
    ramp = _grey(LINEAR_MAX * (0.1 + 0.01 * xx + 0.005 * yy))
    mask = torch.ones(40, 50, dtype=torch.bool)
    # float64 rounding only: displayed values ~0.03 carry errors ~1e-17 each, squared ~1e-34,
    # over ~1.5K pixels; 1e-28 leaves room and is 1e-24 of one pixel's squared value
    assert highpass_energy(ramp, mask, 0.0) < 1e-28


def test_white_noise_energy_matches_the_closed_form():
    g = torch.Generator().manual_seed(1)
    h, w = 300, 300
    x = LINEAR_MAX * torch.rand(h, w, generator=g, dtype=torch.float64)
    mask = torch.ones(h, w, dtype=torch.bool)
    n = int(highpass_window_mask(mask).sum())
    g0, sum_sq = _weights()
    var = (SLOPE * LINEAR_MAX) ** 2 / 12  # a uniform variable's variance, displayed
    expect = n * var * (1 - 2 * g0 + sum_sq)
    # the sum of ~86K squared, locally correlated terms: relative std ~ sqrt(2 * 9 / 86K)
    # = 1.4 % (a window of ~9 correlated neighbours); 5 % is 3.5 standard deviations
    assert highpass_energy(_grey(x), mask, 0.0) == pytest.approx(expect, rel=0.05)


def test_a_smooth_image_scores_one_against_itself_and_a_noisy_one_more():
    ref = _smooth()
    mask = torch.ones(ref.shape[:2], dtype=torch.bool)
    mask[:5] = False
    assert highpass_ratio(ref, ref, mask, 0.0) == 1.0
    g = torch.Generator().manual_seed(2)
    noise = 0.05 * LINEAR_MAX * torch.randn(ref.shape[:2], generator=g, dtype=torch.float64)
    noisy = ref + _grey(noise)
    assert highpass_ratio(noisy, ref, mask, 0.0) > 10.0  # noise dwarfs a smooth image's detail
    # and the other way round: the smooth image holds less detail than the noisy one
    assert highpass_ratio(ref, noisy, mask, 0.0) < 0.1
    # blurring the noisy image lowers its ratio: the score sees fine detail only
    blurred = torch.nn.functional.avg_pool2d(
        noisy[..., 0][None, None], 3, stride=1, padding=1, count_include_pad=False
    )[0, 0]
    assert highpass_ratio(_grey(blurred), ref, mask, 0.0) < highpass_ratio(noisy, ref, mask, 0.0)


def test_noise_energy_matches_monte_carlo():
    ref = _smooth()
    mask = torch.ones(ref.shape[:2], dtype=torch.bool)
    g = torch.Generator().manual_seed(3)
    # a per-pixel standard error that varies over the image, 3 % to 8 % of the value
    stderr = (
        ref * (0.03 + 0.05 * torch.rand(ref.shape[:2], generator=g, dtype=torch.float64))[..., None]
    )
    expect = noise_highpass_energy(ref, stderr, mask, 0.0)
    base = highpass_energy(ref, mask, 0.0)
    draws = []
    for _ in range(20):
        z = torch.randn(ref.shape[:2], generator=g, dtype=torch.float64)[..., None]
        draws.append(highpass_energy(ref + stderr * z, mask, 0.0) - base)
    got = sum(draws) / len(draws)
    # 20 draws of a sum over ~4.4K pixels: relative std of the mean ~ sqrt(2 * 9 / 4.4K / 20)
    # = 1.4 % plus the cross term with the smooth image (zero mean, small); 6 % is > 4 sigma
    assert got == pytest.approx(expect, rel=0.06)
    assert expect > 0
    # the channels' noise drawn independently: the lower estimate, by the same margin
    lower = noise_highpass_energy(ref, stderr, mask, 0.0, correlated=False)
    draws = []
    for _ in range(20):
        z = torch.randn(ref.shape, generator=g, dtype=torch.float64)  # (H, W, 3)
        draws.append(highpass_energy(ref + stderr * z, mask, 0.0) - base)
    assert sum(draws) / len(draws) == pytest.approx(lower, rel=0.06)
    # grey noise of equal channels: sum(w)^2 = 1 against sum(w^2) = 0.562 of the Rec. 709 weights
    assert lower / expect == pytest.approx(sum(w * w for w in (0.2126, 0.7152, 0.0722)), rel=1e-9)


def test_clipped_pixels_carry_no_noise_and_no_detail():
    ref = _grey(torch.full((30, 30), 10.0, dtype=torch.float64))  # displayed as 1, clipped
    mask = torch.ones(30, 30, dtype=torch.bool)
    assert noise_highpass_energy(ref, 0.5 * ref, mask, 0.0) == 0.0
    # a constant's blur is the constant up to float64 rounding (~1e-16 per pixel, squared)
    assert highpass_energy(ref, mask, 0.0) < 1e-26
    assert highpass_ratio(ref, ref, mask, 0.0) == 1.0
