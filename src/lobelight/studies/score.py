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
"""

from __future__ import annotations

import math

import torch

from .._tol import DIVISOR_F32

__all__ = [
    "LUMA",
    "display",
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
