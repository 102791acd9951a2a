"""Monte Carlo reference for the comparison: direct environment lighting of surface points.

``L_o = int f(i, o) max(n.i, 0) L(i) di`` with no occlusion (a convex object), estimated per
shading point by multiple importance sampling with the balance heuristic: every sample pair is
one direction from the BRDF's importance sampling (:meth:`lobelight.brdf.BRDF.sample`) and one
from the environment's luminance (:class:`lobelight.reference.paths.EnvSampler`), each contributing
``f cos L / (p_brdf + p_env)``. The lighting is the map's own interpolant
(:meth:`lobelight.envmap.EnvMap.radiance`), not any filtered copy of it, so the reference is
independent of the prefiltered chains the methods under test read.

The standard error of each pixel comes from the sample variance of its iid pair estimates
(accumulated in float64), so the reference states its own noise.
"""

from __future__ import annotations

import math
from typing import Any

import torch

from .._backend import as_tensor
from .._tol import DIVISOR_F32
from ..brdf import BRDF
from ..errors import InputError
from ..sgbrdf import normals_and_views
from .paths import EnvSampler

__all__ = ["shade_reference"]

#: Sample pairs processed at once (pixels x pairs), to bound memory (~300 B each).
_CHUNK = 1 << 20


def shade_reference(
    brdf: BRDF,
    env: Any,
    normals: Any,
    views: Any,
    /,
    *,
    tangents: Any = None,
    spp: int = 1024,
    seed: int = 0,
    replicates: int = 4,
    sampler: EnvSampler | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Reference radiance and its standard error per shading point (module docstring).

    Parameters
    ----------
    brdf : a material with scalar parameters
    env : :class:`lobelight.envmap.EnvMap` (its device is the computation's)
    normals, views : (..., 3) unit normals and directions towards the viewer, world frame
    tangents : optional (..., 3) tangents (the material's ``x`` axis)
    spp : samples per point, half from each technique (``spp // 2`` pairs, at least 1)
    seed : seed of the random numbers (the same call gives the same image)
    replicates : independent randomisations the samples are split into; the standard error
        is the spread of their estimates (randomised quasi-Monte Carlo)
    sampler : an :class:`EnvSampler` of ``env`` to reuse (built here when None)

    Returns
    -------
    mean : (..., 3) float32 radiance;  stderr : (..., 3) float32 standard error of ``mean``
    """
    if not isinstance(brdf, BRDF):
        raise InputError("brdf", f"must be a lobelight.brdf.BRDF, got {type(brdf).__name__}")
    if not hasattr(env, "radiance"):
        raise InputError("env", f"must be an EnvMap, got {type(env).__name__}")
    if not isinstance(spp, int) or isinstance(spp, bool) or spp < 2:
        raise InputError("spp", f"must be an integer >= 2, got {spp!r}")
    dev = env.device
    n, o = normals_and_views(normals, views, dev)
    shape = n.shape[:-1]
    n, o = n.reshape(-1, 3), o.reshape(-1, 3)  # (P, 3)
    t = None
    if tangents is not None:
        t = as_tensor(tangents, device=dev).to(torch.float32).expand(*shape, 3).reshape(-1, 3)
    sampler = EnvSampler(env) if sampler is None else sampler
    b = brdf.to(dev)
    if not isinstance(replicates, int) or isinstance(replicates, bool) or replicates < 2:
        raise InputError("replicates", f"must be an integer >= 2, got {replicates!r}")
    pairs = max(1, spp // (2 * replicates))  # pairs per replicate
    npix = n.shape[0]
    gen = torch.Generator(device="cpu").manual_seed(seed)
    reps = torch.zeros(replicates, npix, 3, dtype=torch.float64, device=dev)
    pix_step = max(1, min(npix, _CHUNK // min(pairs, 256)))
    pair_step = max(1, _CHUNK // pix_step)
    for r in range(replicates):  # independent randomisations (estimate the error)
        # one scrambled Sobol sequence per replicate for all pixels, each pixel shifted by its
        # own uniform vector (Cranley-Patterson): every pixel's estimate is unbiased, and the
        # replicates are independent of each other
        sobol = torch.quasirandom.SobolEngine(5, scramble=True, seed=seed * 7919 + r)
        shift = torch.rand(npix, 1, 5, generator=gen).to(dev)  # (P, 1, 5)
        for q0 in range(0, pairs, pair_step):
            m = min(pair_step, pairs - q0)
            pts = sobol.draw(m).to(device=dev, dtype=torch.float32)  # (m, 5)
            for p0 in range(0, npix, pix_step):  # chunks: pixels x pairs, each vectorised
                sl = slice(p0, p0 + pix_step)
                np_, on = n[sl].unsqueeze(1), o[sl].unsqueeze(1)  # (p, 1, 3)
                ns = None if t is None else t[sl].unsqueeze(1)
                u = torch.frac(pts + shift[sl]).clamp_max(1 - 2**-24)  # (p, m, 5)
                reps[r, sl] += _pair_estimates(b, env, sampler, np_, on, ns, u).sum(1)
    reps /= pairs
    mean = reps.mean(0)
    se = reps.std(0) / math.sqrt(replicates)
    return mean.to(torch.float32).reshape(*shape, 3), se.to(torch.float32).reshape(*shape, 3)


def _pair_estimates(b, env, sampler, n, o, t, u) -> torch.Tensor:
    """MIS estimates ``(p, m, 3)`` float64 of sample pairs from uniforms ``u (p, m, 5)``."""
    wi_b, w_b, p_b = b.sample(o, n, u[..., :2], t)  # (p, m, 3), (p, m, 3), (p, m)
    pe_b = sampler.pdf(wi_b)
    c_b = w_b * (p_b / (p_b + pe_b).clamp_min(DIVISOR_F32)).unsqueeze(-1) * env.radiance(wi_b)
    wi_e, p_e = sampler.sample(u[..., 2:])  # (p, m, 3), (p, m)
    f = b.eval(wi_e, o, n, t)  # (p, m, 3), 0 below either horizon
    cos = (wi_e * n).sum(-1).clamp_min(0)
    pb_e = b.pdf(wi_e, o, n, t)
    c_e = f * (cos / (p_e + pb_e).clamp_min(DIVISOR_F32)).unsqueeze(-1) * env.radiance(wi_e)
    return (c_b + c_e).double()
