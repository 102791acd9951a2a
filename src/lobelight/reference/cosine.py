"""Independent Monte Carlo reference for direct lighting from spherical lights.

Nothing here uses lobes or tables: the BRDF is evaluated by :meth:`lobelight.brdf.BRDF.eval`,
directions are drawn uniformly in each light's cone of directions (stratified: a jittered
``s x s`` grid in ``(cos theta, phi)``, which is uniform in solid angle), and every shadow ray
is tested analytically against the occluder spheres and planes, up to the light's surface::

    L_o(x, wo) = sum_lights Omega/S sum_s Le f_r(w_s, wo) max(n . w_s, 0) V(x, w_s)

A sphere that contains ``x`` is ignored (as by the lobe renderer's clipping), and so is the
point's own sphere given by ``exclude``. Work is chunked over points (bounded memory).
"""

from __future__ import annotations

import math
from typing import Any

import torch

from .. import brdf as _brdf
from .._tol import DIVISOR_F64
from ..cosine import SphereLight
from ..errors import InputError
from ..geometry.sphere import frame

__all__ = ["direct_mc"]


def _sphere_hit(o, w, spheres, t_max):
    """Whether rays ``o + t w``, ``0 < t < t_max``, hit any sphere from outside.

    o : (P, 1, 3);  w : (P, S, 3);  spheres : (N, 4);  t_max : (P, S)  ->  (P, S) bool
    """
    c = spheres[:, :3]  # (N, 3)
    oc = c.unsqueeze(0) - o[:, 0].unsqueeze(1)  # (P, N, 3)
    cc = (oc * oc).sum(-1) - spheres[:, 3] ** 2  # (P, N) > 0: origin outside
    b = torch.einsum("psk,pnk->psn", w, oc)  # (P, S, N)
    disc = b * b - cc.unsqueeze(1)
    t0 = b - torch.sqrt(disc.clamp_min(0))
    hit = (disc > 0) & (cc.unsqueeze(1) > 0) & (t0 > 0) & (t0 < t_max.unsqueeze(-1))
    return hit


def direct_mc(
    points: Any,
    normals: Any,
    wo: Any,
    brdf: _brdf.BRDF,
    lights: SphereLight | list[SphereLight],
    *,
    spheres: Any = None,
    planes: Any = None,
    exclude: Any = None,
    samples: int = 1024,
    seed: int = 0,
    chunk: int | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Monte Carlo direct radiance with its standard error (per channel).

    Parameters
    ----------
    points, normals, wo : (P, 3)
    brdf : any :class:`lobelight.brdf.BRDF` (per-point parameters (P,) / (P, 3))
    lights : :class:`SphereLight` or list
    spheres : optional (N, 4) occluders;  planes : optional (M, 4) occluding planes
        ``(nx, ny, nz, d)`` = the set ``n . y = d``
    exclude : optional (P,) sphere index ignored per point (-1: none)
    samples : per point and light, rounded down to a square ``s^2`` (stratification)
    seed : the generator's seed (deterministic)

    Returns
    -------
    radiance : (P, 3) float64;  stderr : (P, 3) float64 (of the jittered estimate, estimated
    from the spread between the two halves of the strata; conservative for stratified sampling)
    """
    x = torch.as_tensor(points, dtype=torch.float64)
    dev = x.device
    n = torch.as_tensor(normals, dtype=torch.float64, device=dev)
    v = torch.as_tensor(wo, dtype=torch.float64, device=dev)
    if x.ndim != 2 or x.shape[-1] != 3 or n.shape != x.shape or v.shape != x.shape:
        raise InputError("points", "points, normals and wo must all be (P, 3)")
    lights = [lights] if isinstance(lights, SphereLight) else list(lights)
    s = math.isqrt(int(samples))
    if s < 2:
        raise InputError("samples", f"need at least 4, got {samples}")
    S = s * s
    sph = None
    if spheres is not None:
        sph = torch.as_tensor(spheres, dtype=torch.float64, device=dev).reshape(-1, 4)
        if sph.shape[0] == 0:
            sph = None
    pl = None if planes is None else torch.as_tensor(planes, dtype=torch.float64, device=dev)
    P = x.shape[0]
    N = 1 if sph is None else sph.shape[0]
    chunk = chunk or max(1, (1 << 23) // (S * N))
    g = torch.Generator(device="cpu").manual_seed(seed)
    model = brdf.to(dev, torch.float64)
    total = torch.zeros(P, 3, dtype=torch.float64, device=dev)
    var = torch.zeros(P, 3, dtype=torch.float64, device=dev)
    iu = torch.arange(s, dtype=torch.float64).repeat_interleave(s)
    iv = torch.arange(s, dtype=torch.float64).repeat(s)
    for lt in lights:
        c = torch.tensor(lt.centre, dtype=torch.float64, device=dev)
        le = torch.tensor(lt.radiance, dtype=torch.float64, device=dev)
        for a in range(0, P, chunk):
            sl = slice(a, a + chunk)
            xp, npt, vp = x[sl], n[sl], v[sl]
            p = xp.shape[0]
            d = c - xp
            dist = torch.linalg.vector_norm(d, dim=-1)
            h = d / dist.unsqueeze(-1)
            sin_t = (lt.radius / dist).clamp(max=1.0)
            one_minus = 1 - torch.sqrt(1 - sin_t**2)  # 1 - cos(theta_max)
            jit = torch.rand(p, S, 2, generator=g, dtype=torch.float64).to(dev)
            u1 = (iu.to(dev) + jit[..., 0]) / s
            u2 = (iv.to(dev) + jit[..., 1]) / s
            cos_t = 1 - u1 * one_minus.unsqueeze(-1)  # (p, S)
            sin_s = torch.sqrt((1 - cos_t**2).clamp_min(0))
            phi = 2 * math.pi * u2
            t, b, _ = frame(h)
            w = (
                (sin_s * torch.cos(phi)).unsqueeze(-1) * t.unsqueeze(1)
                + (sin_s * torch.sin(phi)).unsqueeze(-1) * b.unsqueeze(1)
                + cos_t.unsqueeze(-1) * h.unsqueeze(1)
            )  # (p, S, 3)
            # distance to the light's surface along w (first intersection)
            bl = (w * d.unsqueeze(1)).sum(-1)
            cl = (dist**2 - lt.radius**2).unsqueeze(-1)
            t_light = bl - torch.sqrt((bl * bl - cl).clamp_min(0))
            vis = torch.ones(p, S, dtype=torch.bool, device=dev)
            if sph is not None:
                hit = _sphere_hit(xp.unsqueeze(1), w, sph, t_light)  # (p, S, N)
                if exclude is not None:
                    ex = torch.as_tensor(exclude, device=dev).long().reshape(-1)[sl]
                    own = torch.arange(sph.shape[0], device=dev).unsqueeze(0) == ex.unsqueeze(1)
                    hit = hit & ~own.unsqueeze(1)
                vis &= ~hit.any(-1)
            if pl is not None:
                nd = torch.einsum("psk,mk->psm", w, pl[:, :3])  # (p, S, M)
                dist_pl = pl[:, 3].unsqueeze(0) - xp @ pl[:, :3].T  # (p, M)
                tp = dist_pl.unsqueeze(1) / torch.where(nd == 0, DIVISOR_F64, nd)
                vis &= ~((tp > 1e-9 * dist.reshape(-1, 1, 1)) & (tp < t_light.unsqueeze(-1))).any(
                    -1
                )
            mp = (
                model.take(torch.arange(a, a + p, device=dev))
                if model.per_element_params
                else model
            )
            # per-point parameters broadcast over the leading sample axis: (S, p, 3) layout
            wt = w.transpose(0, 1)
            f = mp.eval(wt, vp.expand_as(wt), npt.expand_as(wt)).transpose(0, 1)  # (p, S, 3)
            cosn = (w * npt.unsqueeze(1)).sum(-1).clamp_min(0)
            omega = 2 * math.pi * one_minus
            est = f * (cosn * vis).unsqueeze(-1) * le * omega.reshape(-1, 1, 1)  # (p, S, 3)
            total[sl] += est.mean(1)
            halves = est.reshape(p, 2, S // 2, 3).mean(2) if S % 2 == 0 else est[:, :2]
            var[sl] += ((halves[:, 0] - halves[:, 1]) / 2) ** 2
    return total, var.sqrt()
