"""Image scores every study uses: PSNR on linear radiance and on displayed images, relative L2,
and the PSNR a Monte Carlo reference's own noise allows.

All compare ``img`` with ``ref``, linear radiance of one shape (``(H, W, 3)`` images, or
``(P, 3)`` pixels), over ``mask`` (a bool array of the leading shape, or None for every pixel),
in float64:

``psnr``            ``10 log10(peak^2 / MSE)`` with ``peak`` the reference's largest value over
                    the mask (a sun's reflection makes it large and the figure generous)
``psnr_display``    the same of the displayed images, peak 1: both scaled by ``2^exposure``,
                    clipped to [0, 1] and sRGB-encoded (:func:`display`)
``relative_l2``     ``|img - ref| / |ref|`` over the mask
``noise_psnr``      the linear PSNR of a perfect image against a reference with per-pixel
                    standard errors; ``noise_psnr_display`` its displayed counterpart (the
                    noise taken through the display curve's slope)

and, for fine detail (blotches, noise) of ``(H, W, 3)`` images:

``highpass_energy``   ``sum (L - G * L)^2`` over the pixels of ``mask`` whose whole filter
                      window lies in ``mask``: ``L`` the displayed luminance (Rec. 709 weights
                      of :func:`display`'s values), ``G`` a normalised Gaussian of
                      ``sigma`` pixels truncated at ``ceil(3 sigma)``
``highpass_ratio``    ``img``'s high-pass energy / ``ref``'s, one window mask for both (1 for
                      the same image; above 1 where ``img`` holds more fine detail)
``noise_highpass_energy``  the high-pass energy a reference's own Monte Carlo noise is
                      expected to add to it (from its per-pixel standard errors)
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from .._tol import DIVISOR_F32

__all__ = [
    "HIGHPASS_SIGMA",
    "LUMA",
    "display",
    "highpass_energy",
    "highpass_ratio",
    "highpass_window_mask",
    "noise_highpass_energy",
    "noise_psnr",
    "noise_psnr_display",
    "psnr",
    "psnr_display",
    "psnr_from_mse",
    "relative_l2",
    "srgb_encode",
]

#: Rec. 709 luminance weights of linear RGB.
LUMA = (0.2126, 0.7152, 0.0722)
#: The high-pass filter's Gaussian, in pixels: detail finer than a couple of pixels.
HIGHPASS_SIGMA = 1.0
#: Below this displayed value the sRGB curve's slope is taken at it (the curve's power law
#: has an infinite slope at 0; these values are in the curve's linear segment anyway).
_SLOPE_FLOOR = 1e-6


def srgb_encode(x: torch.Tensor) -> torch.Tensor:
    """The sRGB transfer function of values in [0, 1]: linear below 0.0031308, the 1/2.4 power
    law above."""
    return torch.where(x <= 0.0031308, 12.92 * x, 1.055 * x.pow(1 / 2.4) - 0.055)


def display(x: torch.Tensor, scale: float) -> torch.Tensor:
    """The displayed image of linear radiance ``x``: ``srgb(clip(scale x, 0, 1))``, float64, of
    ``x``'s shape."""
    return srgb_encode((x.double() * scale).clamp(0, 1))


def psnr_from_mse(mse: float, peak: float = 1.0) -> float:
    """``10 log10(peak^2 / mse)`` in dB; infinite for a zero error."""
    return math.inf if mse == 0 else 10 * math.log10(peak * peak / mse)


def _masked(x: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
    return x if mask is None else x[mask]


def psnr(img: torch.Tensor, ref: torch.Tensor, mask: torch.Tensor | None) -> float:
    """PSNR in dB on linear radiance over ``mask``, with the reference's peak there."""
    a, b = _masked(img, mask).double(), _masked(ref, mask).double()
    mse = float(((a - b) ** 2).mean())
    return psnr_from_mse(mse, float(b.max()))


def psnr_display(
    img: torch.Tensor, ref: torch.Tensor, mask: torch.Tensor | None, exposure: float
) -> float:
    """PSNR in dB over ``mask`` of the displayed images (:func:`display` at ``2^exposure``),
    peak 1."""
    k = 2.0**exposure
    diff = display(_masked(img, mask), k) - display(_masked(ref, mask), k)
    return psnr_from_mse(float((diff**2).mean()))


def relative_l2(img: torch.Tensor, ref: torch.Tensor, mask: torch.Tensor | None = None) -> float:
    """``|img - ref| / |ref|`` on linear radiance over ``mask`` (0 / 0 stays finite)."""
    a, b = _masked(img, mask).double(), _masked(ref, mask).double()
    return float((a - b).norm() / b.norm().clamp_min(DIVISOR_F32))


def noise_psnr(ref: torch.Tensor, stderr: torch.Tensor, mask: torch.Tensor | None) -> float:
    """The linear PSNR of a perfect image against a reference with per-pixel standard errors
    ``stderr`` (``ref``'s shape): ``peak^2 / mean(stderr^2)`` over ``mask``, in dB."""
    var = float((_masked(stderr, mask).double() ** 2).mean())
    return psnr_from_mse(var, float(_masked(ref, mask).double().max()))


def noise_psnr_display(
    ref: torch.Tensor, stderr: torch.Tensor, mask: torch.Tensor | None, exposure: float
) -> float:
    """The displayed PSNR over ``mask`` that the reference's own noise allows a perfect image:
    ``10 log10(1 / mean((s'(k ref) k stderr)^2))``, ``s`` the sRGB curve, ``k = 2^exposure``
    (the noise taken through the display's slope; clipped pixels carry none)."""
    k = 2.0**exposure
    x = (_masked(ref, mask).double() * k).clamp_min(_SLOPE_FLOOR)  # (P, 3)
    slope = torch.where(x <= 0.0031308, 12.92, 1.055 / 2.4 * x.pow(1 / 2.4 - 1))
    slope = torch.where(x >= 1, torch.zeros_like(slope), slope)
    mse = float(((slope * k * _masked(stderr, mask).double()) ** 2).mean())
    return psnr_from_mse(mse)


def _gaussian_1d(sigma: float, dtype=torch.float64) -> torch.Tensor:
    """``(2 r + 1,)`` normalised Gaussian weights, ``r = ceil(3 sigma)``."""
    if not sigma > 0:
        raise ValueError(f"sigma must be > 0, got {sigma}")
    r = math.ceil(3 * sigma)
    x = torch.arange(-r, r + 1, dtype=dtype)
    g = torch.exp(-0.5 * (x / sigma) ** 2)
    return g / g.sum()


def _separable(x: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
    """``(H - 2 r, W - 2 r)``: ``x`` ``(H, W)`` convolved with the outer product of ``g``
    ``(2 r + 1,)`` with itself, over the windows that lie inside the image."""
    k = g.to(x)
    y = F.conv2d(x[None, None], k.view(1, 1, -1, 1))  # (1, 1, H - 2r, W)
    return F.conv2d(y, k.view(1, 1, 1, -1))[0, 0]  # (H - 2r, W - 2r)


def highpass_window_mask(mask: torch.Tensor, sigma: float = HIGHPASS_SIGMA) -> torch.Tensor:
    """``(H, W)`` bool: the pixels of ``mask`` ``(H, W)`` whose whole high-pass window
    (``2 ceil(3 sigma) + 1`` pixels square) lies in ``mask`` (the image's border rows and
    columns excluded)."""
    r = math.ceil(3 * sigma)
    out = torch.zeros(mask.shape, dtype=torch.bool, device=mask.device)
    if min(mask.shape) < 2 * r + 1:
        return out  # no window fits in the image
    box = torch.ones(2 * r + 1, dtype=torch.float64)
    full = _separable(mask.double(), box) > (2 * r + 1) ** 2 - 0.5  # (H - 2r, W - 2r)
    out[r : mask.shape[0] - r, r : mask.shape[1] - r] = full
    return out


def _highpass_sq(lum: torch.Tensor, window: torch.Tensor, sigma: float) -> torch.Tensor:
    """``(P,)`` squared high-pass of luminance ``lum`` ``(H, W)`` at the pixels of
    ``window``."""
    if not bool(window.any()):
        return lum.new_zeros(0)
    r = math.ceil(3 * sigma)
    h = lum[r:-r, r:-r] - _separable(lum, _gaussian_1d(sigma))  # (H - 2r, W - 2r)
    return h[window[r:-r, r:-r]] ** 2


def _displayed_luminance(x: torch.Tensor, exposure: float) -> torch.Tensor:
    """``(H, W)`` float64: the luminance of :func:`display`'s values of ``x`` ``(H, W, 3)``."""
    w = torch.tensor(LUMA, dtype=torch.float64, device=x.device)
    return display(x, 2.0**exposure) @ w


def highpass_energy(
    img: torch.Tensor, mask: torch.Tensor, exposure: float, *, sigma: float = HIGHPASS_SIGMA
) -> float:
    """The high-pass energy of ``img`` ``(H, W, 3)`` displayed at ``2^exposure``, summed over
    :func:`highpass_window_mask` of ``mask`` ``(H, W)`` bool (0 when no pixel qualifies)."""
    window = highpass_window_mask(mask, sigma)
    return float(_highpass_sq(_displayed_luminance(img, exposure), window, sigma).sum())


def highpass_ratio(
    img: torch.Tensor,
    ref: torch.Tensor,
    mask: torch.Tensor,
    exposure: float,
    *,
    sigma: float = HIGHPASS_SIGMA,
) -> float:
    """:func:`highpass_energy` of ``img`` / that of ``ref`` (both ``(H, W, 3)``, one window
    mask); inf where the reference has none and ``img`` some, 1 where neither has any."""
    num = highpass_energy(img, mask, exposure, sigma=sigma)
    den = highpass_energy(ref, mask, exposure, sigma=sigma)
    if den > 0:
        return num / den
    return 1.0 if num == 0 else math.inf


def noise_highpass_energy(
    ref: torch.Tensor,
    stderr: torch.Tensor,
    mask: torch.Tensor,
    exposure: float,
    *,
    sigma: float = HIGHPASS_SIGMA,
    correlated: bool = True,
) -> float:
    """The expected :func:`highpass_energy` that independent per-pixel noise of standard error
    ``stderr`` ``(H, W, 3)`` adds to ``ref``: with ``s`` the noise of the displayed luminance
    (each channel's through the display curve's slope at ``ref``, as
    :func:`noise_psnr_display`), ``E[h_p^2] = s_p^2 (1 - 2 g_0) + sum_q g_q^2 s_(p-q)^2``
    summed over the window mask, ``g`` the filter's 2-D weights and ``g_0`` its centre's.

    ``correlated``: the channels' noise taken as fully correlated (``s`` the weighted sum of
    the channels' standard errors: an upper estimate, as one path carries all three colours),
    else as independent (the root of the weighted squares: a lower estimate)."""
    window = highpass_window_mask(mask, sigma)
    if not bool(window.any()):
        return 0.0
    k = 2.0**exposure
    x = (ref.double() * k).clamp_min(_SLOPE_FLOOR)  # (H, W, 3)
    slope = torch.where(x <= 0.0031308, 12.92, 1.055 / 2.4 * x.pow(1 / 2.4 - 1))
    slope = torch.where(x >= 1, torch.zeros_like(slope), slope)
    w = torch.tensor(LUMA, dtype=torch.float64, device=ref.device)
    per_channel = slope * k * stderr.double() * w  # (H, W, 3)
    if correlated:
        var_px = per_channel.sum(-1) ** 2  # (H, W) displayed luminance noise variance
    else:
        var_px = (per_channel**2).sum(-1)
    g = _gaussian_1d(sigma)
    r = g.shape[0] // 2
    var = var_px[r:-r, r:-r] * (1 - 2 * float(g[r] ** 2)) + _separable(var_px, g**2)
    return float(var[window[r:-r, r:-r]].sum())
