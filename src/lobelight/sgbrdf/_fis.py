"""Filtered importance sampling (Colbert & Křivánek 2007, GPU Gems 3 ch. 20): a baseline.

Per shading point, ``N`` (40) directions are drawn by the BRDF's own importance sampling from
one deterministic Hammersley set shared by every pixel (so the image has no noise, only the
structured error of a fixed quadrature, as on the GPU). Each direction reads the environment's
box-filtered mip chain (:class:`lobelight.sgbrdf.MipChain`, what GPUs build in hardware) at the
level whose texel covers the sample's share of the sphere::

    Omega_s = 1 / (N pdf(w_i)),   Omega_p = solid angle of a base texel at w_i,
    lod     = max(1/2 log2(Omega_s / Omega_p) + 1, 0)            (their eq. 13, + 1 bias)

and the estimate is ``1/N sum_i f(w_i, o) cos(w_i) / pdf(w_i) L_lod(w_i)`` (the BRDF's sampling
weight, so any BRDF of :mod:`lobelight.brdf` works, not only ones whose pdf is proportional to
``f cos``). The filtering trades the noise of ``N`` samples for blur: with ``N -> inf`` the
levels go to 0 and the estimate converges to the true integral against the base level
(``tests/test_sgbrdf_compare.py``).
"""

from __future__ import annotations

from typing import Any

import torch

from .._backend import as_tensor
from .._checks import check_int
from .._tol import DIVISOR_F32
from ..brdf import BRDF
from ..errors import InputError
from ._render import MipChain, normals_and_views

__all__ = ["FIS_SAMPLES", "hammersley", "shade_fis"]

#: Samples per pixel of the baseline (the EM paper's comparison: "about 40 samples").
FIS_SAMPLES = 40
#: Sample directions processed at once (pixels x samples), to bound memory (~100 B each).
_CHUNK = 1 << 21


def hammersley(n: int, /, *, dtype: torch.dtype = torch.float64, device: Any = None):
    """The ``n``-point Hammersley set in the unit square, ``(n, 2)``: ``(i / n, phi_2(i))``
    with ``phi_2`` the base-2 radical inverse (bit reversal of ``i``)."""
    n = check_int(n, "samples")
    i = torch.arange(n, dtype=torch.int64, device=device)
    rev = torch.zeros(n, dtype=torch.float64, device=device)
    bits = max(1, (n - 1).bit_length())
    for b in range(bits):  # a loop over the bits of the index, vectorised over points
        rev += ((i >> b) & 1).to(torch.float64) * 0.5 ** (b + 1)
    return torch.stack([i.to(torch.float64) / n, rev], -1).to(dtype)


def shade_fis(
    brdf: BRDF,
    chain: MipChain,
    normals: Any,
    views: Any,
    /,
    *,
    tangents: Any = None,
    samples: int = FIS_SAMPLES,
    lod_bias: float = 1.0,
) -> torch.Tensor:
    """Outgoing radiance by filtered importance sampling (module docstring).

    Parameters
    ----------
    brdf : a material with scalar parameters (:mod:`lobelight.brdf`)
    chain : the environment's box-filtered mip chain (:func:`lobelight.sgbrdf.mip_chain`)
    normals, views : (..., 3) unit normals and directions towards the viewer, world frame
    tangents : optional (..., 3) tangents (the material's ``x`` axis)
    samples : ``N``, Hammersley points per shading point
    lod_bias : the ``+ 1`` of Colbert & Křivánek's level formula (their choice, kept)

    Returns
    -------
    (..., 3) float32 radiance on the chain's device, 0 where the viewer is below the surface
    """
    if not isinstance(brdf, BRDF):
        raise InputError("brdf", f"must be a lobelight.brdf.BRDF, got {type(brdf).__name__}")
    if not isinstance(chain, MipChain):
        raise InputError("chain", f"must be a MipChain (mip_chain), got {type(chain).__name__}")
    dev = chain.device
    n, o = normals_and_views(normals, views, dev)
    t = None
    if tangents is not None:
        t = as_tensor(tangents, device=dev).to(torch.float32).expand_as(n).reshape(-1, 3)
    shape = n.shape[:-1]
    n, o = n.reshape(-1, 3), o.reshape(-1, 3)  # (P, 3)
    u = hammersley(samples, dtype=torch.float32, device=dev).unsqueeze(0)  # (1, N, 2)
    b = brdf.to(dev)
    out = torch.zeros(n.shape[0], 3, device=dev)
    step = max(1, _CHUNK // samples)
    for s in range(0, n.shape[0], step):  # chunks of pixels, each vectorised over samples
        sl = slice(s, s + step)
        ts = None if t is None else t[sl].unsqueeze(1)
        wi, weight, pdf = b.sample(o[sl].unsqueeze(1), n[sl].unsqueeze(1), u, ts)  # (p, N, ...)
        omega_s = 1.0 / (samples * pdf.double().clamp_min(DIVISOR_F32))  # (p, N) the sample's share
        lod = (0.5 * torch.log2(omega_s / chain.texel_solid_angle(wi)) + lod_bias).clamp_min(0)
        light = chain.lookup_level(wi, lod)  # (p, N, 3)
        out[sl] = (weight * light).mean(1)
    return out.reshape(*shape, 3)
