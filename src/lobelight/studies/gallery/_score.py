"""The gallery's scores: displayed PSNR at the reference's exposure, relative L2, energy ratio.

All scores compare ``img`` with ``ref``, both ``(H, W, 3)`` linear radiance, over ``mask``
``(H, W)`` bool, the pixels fully covered by the object (one mask for both images, stored with
the reference):

``exposure``            stops that map the reference's 99th-percentile luminance over the mask
                        (Rec. 709 weights) to 1: :func:`display_exposure`
``psnr_display``        dB over the mask: both images scaled by ``2^exposure``, clipped to
                        [0, 1], sRGB-encoded, ``10 log10(1 / MSE)`` over pixels and channels
                        (:func:`lobelight.studies.score.psnr_display`)
``psnr_display_full``   the same over every pixel, object and background
``rel_l2``              ``|img - ref| / |ref|`` on linear radiance over the mask
                        (:func:`lobelight.studies.score.relative_l2`)
``energy_ratio``        sum of ``img``'s luminance over the mask / the same of ``ref``
``highpass_ratio``      fine detail: the energy of the displayed luminance less its Gaussian
                        blur (sigma 1 pixel) over the mask's pixels whose filter window lies in
                        the mask, ``img``'s / ``ref``'s
                        (:func:`lobelight.studies.score.highpass_ratio`)
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ...errors import InputError
from ..score import HIGHPASS_SIGMA, LUMA, highpass_ratio, psnr_display, relative_l2

__all__ = [
    "LEGEND",
    "PERCENTILE",
    "display_exposure",
    "energy_ratio",
    "luminance",
    "score",
]

#: The reference's luminance percentile over the mask that the display exposure maps to 1.
PERCENTILE = 99.0

#: What each score means (also in ``gallery.json``).
LEGEND = {
    "exposure": f"stops mapping the reference's {PERCENTILE:g}th-percentile object luminance to 1",
    "psnr_display": "dB over fully covered object pixels: both images at that exposure, "
    "clipped to [0, 1], sRGB-encoded, peak 1",
    "psnr_display_full": "dB, the same over the whole image (object and background)",
    "rel_l2": "|ours - reference| / |reference|, linear radiance over object pixels",
    "energy_ratio": "sum of ours / sum of the reference, luminance over object pixels",
    "highpass_ratio": "ours / reference: energy of the displayed luminance less its Gaussian "
    f"blur (sigma {HIGHPASS_SIGMA:g} pixel) over object pixels whose filter window is on the "
    "object; above 1: more fine detail (blotches, noise) than the reference",
    "reference_noise_highpass": "[low, high]: the share of the reference's high-pass energy its "
    "own Monte Carlo noise is expected to make (from its standard errors; its colour channels' "
    "noise independent, fully correlated): the reference's detail is the rest",
    "highpass_ratio_detail": "[low, high]: highpass_ratio against the reference's detail alone "
    "(its energy less its noise's, at each end of reference_noise_highpass); wide where the "
    "reference is mostly noise at the pixel scale",
    "base_res": "face resolution of the prefiltered chain's sharpest level our frame used",
    "frame_seconds": "seconds of one of our frames at the scene's size and samples per pixel "
    "(median of warm frames; not the bake, not the renderer's set-up)",
    "equal_quality": "Mitsuba at our psnr_display: samples per pixel and seconds (crossing of "
    "its spp sweep, interpolated in log2 spp), speedup = its seconds / frame_seconds, bound "
    "'=' (interpolated), '~' (extrapolated past the sweep with MSE = a / spp + the reference's "
    "noise, up to the reference's spp), '>=' (not reached: lower bounds) or '<=' (reached at "
    "the first level)",
    "mitsuba_sweep": "Mitsuba renders of the scene at 1, 2, 4, ... spp, the reference's variant, "
    "depth and size, seeds apart from the reference's: each render's seconds and psnr_display "
    "against the reference over our mask",
    "reference_noise_psnr_display": "dB, the psnr_display the reference's own noise allows a "
    "perfect image (its standard error through the display's slope): scores near it are "
    "limited by the reference",
}


def _check(img: torch.Tensor, ref: torch.Tensor, mask: torch.Tensor) -> None:
    if img.ndim != 3 or img.shape[-1] != 3 or img.shape != ref.shape:
        shapes = f"{tuple(img.shape)} and {tuple(ref.shape)}"
        raise InputError("image", f"expected two (H, W, 3) images, got {shapes}")
    if mask.shape != img.shape[:2] or mask.dtype != torch.bool:
        got = f"{tuple(mask.shape)} {mask.dtype}"
        raise InputError("mask", f"expected an (H, W) bool mask, got {got}")
    if not bool(mask.any()):
        raise InputError("mask", "holds no pixel: nothing to score")


def luminance(img: torch.Tensor) -> torch.Tensor:
    """``(...)`` float64 Rec. 709 luminance of ``(..., 3)`` linear RGB."""
    w = torch.tensor(LUMA, dtype=torch.float64, device=img.device)
    return img.double() @ w


def display_exposure(ref: torch.Tensor, mask: torch.Tensor) -> float:
    """Stops that map the :data:`PERCENTILE` th percentile (linear interpolation between
    ranks, as ``numpy.percentile``) of ``ref``'s luminance over ``mask`` to 1."""
    lum = luminance(ref[mask]).cpu().numpy()  # (P,)
    p = float(np.percentile(lum, PERCENTILE))
    if not p > 0:
        raise InputError("reference", "its object pixels are black: no exposure to display")
    return -math.log2(p)


def energy_ratio(img: torch.Tensor, ref: torch.Tensor, mask: torch.Tensor) -> float:
    """Sum of ``img``'s luminance over ``mask`` / the same of ``ref``."""
    den = float(luminance(ref[mask]).sum())
    return float(luminance(img[mask]).sum()) / den if den > 0 else math.inf


def score(img: torch.Tensor, ref: torch.Tensor, mask: torch.Tensor) -> dict[str, float]:
    """The scores of the module docstring, with the exposure they use."""
    img, ref, mask = img.cpu(), ref.cpu(), mask.cpu()
    _check(img, ref, mask)
    e = display_exposure(ref, mask)
    everything = torch.ones_like(mask)
    return {
        "psnr_display": psnr_display(img, ref, mask, e),
        "psnr_display_full": psnr_display(img, ref, everything, e),
        "rel_l2": relative_l2(img, ref, mask),
        "energy_ratio": energy_ratio(img, ref, mask),
        "highpass_ratio": highpass_ratio(img, ref, mask, e),
        "exposure": e,
    }
