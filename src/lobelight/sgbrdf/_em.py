"""Expectation-maximisation for mixtures of von Mises-Fisher distributions on the sphere.

The model (the EM paper, eqs. 1-5) is ``p(x) = sum_k alpha_k g(x; mu_k, kappa_k)`` with the vMF
density ``g = C(kappa) exp(kappa (mu.x - 1))``, ``C(kappa) = kappa / (2 pi (1 - exp(-2 kappa)))``
(conventions.md: the SG of sharpness ``kappa`` normalised by its integral). Data are directions with
non-negative weights: drawn samples have weight 1; weighted samples (quadrature points or
importance samples with values ``f / pdf``) make EM fit the density proportional to ``f``, i.e.
minimise ``KL(f || p)``.

Batches
    Every function works on ``P`` independent problems at once (e.g. views x materials):
    directions ``(P, S, 3)``, weights ``(P, S)``, parameters ``mu (P, N, 3)``, ``kappa (P, N)``,
    ``alpha (P, N)``. Leading batch dimensions of any rank are flattened to ``P`` and restored.
    A problem stops updating once its own log-likelihood has converged, so its result does not
    depend on which other problems share the batch.

Numerics
    The E-step works with log-densities and log-sum-exp: nothing overflows for ``kappa`` up to
    ``kappa_max`` (1e5 by default); its dot products ``mu.x`` are taken in float64, since
    ``kappa (mu.x - 1)`` from float32 dot products is off by ``6e-8 kappa``. The M-step
    accumulates in float64: the concentration comes from ``1 - r`` (``r`` the mean resultant
    length), which is ``1/kappa`` (1e-5 for the sharpest lobes) and would lose all its digits
    as ``1 - r`` in float32. A component that receives no weight at all keeps its mean and
    concentration (with ``alpha = 0``).

Initialisation (the paper's)
    Spherical coordinates of the samples (in a frame whose equator passes through the weighted
    mean direction, so the coordinates are continuous over the data), samples sorted along the
    principal axis of their weighted (latitude, longitude) covariance, split into ``N`` sets of
    equal weight (= equal size for drawn samples), each set's vMF estimated by moments.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch

from .._checks import check_int
from .._tol import DIVISOR_F32, DIVISOR_F64
from ..errors import InputError
from ..geometry.sphere import frame
from ..lobes.sg import mean_cosine

__all__ = [
    "VMFMixture",
    "em_fit",
    "init_paper",
    "kappa_from_gap",
    "log_vmf_normalization",
    "sample_mixture",
    "vmf_log_pdf",
]

_LOG_2PI = math.log(2 * math.pi)
#: Bounds on fitted concentrations: below ``KAPPA_MIN`` a lobe is a constant over the sphere,
#: above ``KAPPA_MAX`` narrower than anything a float32 direction or a prefiltered map resolves.
KAPPA_MIN = 1e-3
KAPPA_MAX = 1e5


@dataclass
class VMFMixture:
    """A batch of fitted vMF mixtures.

    Attributes
    ----------
    mu : (..., N, 3) unit means
    kappa : (..., N) concentrations (= SG sharpness)
    alpha : (..., N) mixture weights, summing to 1
    loglik : (...) mean log-likelihood per unit sample weight at these parameters (float64)
    iterations : (...) int64, EM iterations each problem ran
    """

    mu: torch.Tensor
    kappa: torch.Tensor
    alpha: torch.Tensor
    loglik: torch.Tensor
    iterations: torch.Tensor

    def log_pdf(self, dirs: torch.Tensor) -> torch.Tensor:
        """Log density of each mixture at ``dirs (..., S, 3)`` -> ``(..., S)``."""
        logp = vmf_log_pdf(dirs.unsqueeze(-2), self.mu.unsqueeze(-3), self.kappa.unsqueeze(-2))
        return torch.logsumexp(logp + self.alpha.clamp_min(DIVISOR_F32).log().unsqueeze(-2), -1)

    def pdf(self, dirs: torch.Tensor) -> torch.Tensor:
        """Density of each mixture at ``dirs (..., S, 3)`` -> ``(..., S)``."""
        return self.log_pdf(dirs).exp()


# --------------------------------------------------------------------------------------------
# densities and concentrations


def log_vmf_normalization(kappa: torch.Tensor) -> torch.Tensor:
    """``log C(kappa) = log(kappa / (2 pi (1 - exp(-2 kappa))))``, ``-log(4 pi)`` at 0. (...)."""
    small = kappa < 1e-8
    safe = torch.where(small, torch.ones_like(kappa), kappa)
    out = torch.log(safe) - torch.log(-torch.expm1(-2 * safe)) - _LOG_2PI
    return torch.where(small, torch.full_like(kappa, -math.log(4 * math.pi)), out)


def vmf_log_pdf(dirs: torch.Tensor, mu: torch.Tensor, kappa: torch.Tensor) -> torch.Tensor:
    """Log vMF density ``log C(kappa) - kappa |x - mu|^2 / 2`` (the chord form: exact near the
    peak of sharp lobes). ``dirs, mu (..., 3)``, ``kappa (...)`` broadcast -> ``(...)``."""
    d = dirs - mu
    return log_vmf_normalization(kappa) - 0.5 * kappa * (d * d).sum(-1)


def _gap_of(k: torch.Tensor) -> torch.Tensor:
    """``1 - (coth k - 1/k) = 1/k - 2/(e^(2k) - 1)`` in float64, ``k`` in ``[1e-3, 25]`` (the
    cancellation costs ``1e-16 / k`` absolute, at most 1e-13)."""
    return 1 / k - 2 / torch.expm1(2 * k)


def kappa_from_gap(gap: torch.Tensor, *, solver: str = "exact") -> torch.Tensor:
    """Concentration whose vMF has ``1 - E[mu.x] = gap`` (``gap = 1 - r``, ``r`` the mean
    resultant length).

    ``solver="approx"`` is the standard closed form of Banerjee et al. 2005 for p = 3,
    ``r (3 - r^2) / (1 - r^2)`` (within 5 % everywhere and 0.2 % for ``kappa > 25``, where it
    tends to the exact ``1 / gap``). ``solver="exact"`` inverts ``coth(k) - 1/k`` to float64
    rounding: ``1 / gap`` for ``gap < 1/25`` (there ``gap(k) = 1/k - 2/(e^(2k) - 1)`` is ``1/k``
    to 1e-21 relative), otherwise four Newton steps from Banerjee's estimate (quadratic
    convergence from within 5 %: 5e-2, 3e-3, 1e-5, 1e-10, 1e-16); within 1e-9 relative of
    :func:`lobelight.lobes.sg.lam_from_mean_cosine` everywhere (the gap's own float64 rounding, near
    ``kappa = 1e-3``), at a fraction of its cost per EM step.

    Parameters
    ----------
    gap : (...) in ``[0, 1]`` (it is ``1/kappa`` for sharp lobes, so pass float64)

    Returns
    -------
    (...) float64, unclamped (``inf`` at ``gap = 0``, 0 at ``gap = 1``)
    """
    gap = gap.double()
    if solver not in ("exact", "approx"):
        raise InputError("kappa_solver", f"must be 'exact' or 'approx', got {solver!r}")
    if solver == "approx":
        r = 1 - gap
        return r * (3 - r * r) / (gap * (2 - gap))
    k = 1 / gap  # exact for gap < 1/25 (inf at 0)
    wide = (gap >= 0.04).nonzero(as_tuple=True)
    if wide[0].numel():  # Newton only where the lobe is wide (few entries, or none)
        g = gap[wide]
        r = 1 - g
        kw = (r * (3 - r * r) / (g * (2 - g))).clamp(1e-3, 25.0)
        for _ in range(4):
            sinh = torch.sinh(kw)
            deriv = 1 / (sinh * sinh) - 1 / (kw * kw)  # d gap / dk < 0
            kw = (kw - (_gap_of(kw) - g) / deriv).clamp(1e-3, 26.0)
        k[wide] = torch.where(g >= 1, torch.zeros_like(kw), kw)
    return k


# --------------------------------------------------------------------------------------------
# input checks


def _check_data(
    dirs: Any, weights: Any, n_lobes: Any
) -> tuple[torch.Tensor, torch.Tensor, tuple[int, ...], int]:
    """Validate and flatten: ``dirs (P, S, 3)``, ``weights (P, S)``, batch shape, ``N``."""
    n = check_int(n_lobes, "n_lobes", minimum=1)
    if not isinstance(dirs, torch.Tensor):
        try:
            dirs = torch.as_tensor(dirs)
        except (TypeError, ValueError, RuntimeError):
            raise InputError("dirs", "must be a (..., S, 3) array of directions") from None
    if not dirs.is_floating_point():
        dirs = dirs.to(torch.float32)
    if dirs.ndim < 2 or dirs.shape[-1] != 3:
        raise InputError(
            "dirs", f"must be a (..., S, 3) array of directions, got shape {tuple(dirs.shape)}"
        )
    batch, s = tuple(dirs.shape[:-2]), dirs.shape[-2]
    if s < n:
        raise InputError("dirs", f"has {s} samples per problem, fewer than n_lobes={n}")
    if not bool(torch.isfinite(dirs).all()):
        raise InputError("dirs", "must be finite (found NaN or Inf)")
    norms = torch.linalg.vector_norm(dirs, dim=-1)
    if bool((norms < 1e-6).any()):
        raise InputError("dirs", "contains zero-length directions")
    dirs = dirs / norms.unsqueeze(-1)
    if weights is None:
        w = torch.ones(dirs.shape[:-1], dtype=dirs.dtype, device=dirs.device)
    else:
        w = torch.as_tensor(weights, device=dirs.device)
        w = w.to(dirs.dtype)
        if tuple(w.shape) != tuple(dirs.shape[:-1]):
            raise InputError(
                "weights",
                f"must have shape {tuple(dirs.shape[:-1])} (one per direction), "
                f"got {tuple(w.shape)}",
            )
        if not bool(torch.isfinite(w).all()):
            raise InputError("weights", "must be finite (found NaN or Inf)")
        if w.numel() and float(w.min()) < 0:
            raise InputError("weights", f"must be non-negative, found {float(w.min()):g}")
    dirs, w = dirs.reshape(-1, s, 3), w.reshape(-1, s)  # (P, S, 3), (P, S)
    if w.shape[0] and bool((w.sum(-1) <= 0).any()):
        bad = int((w.sum(-1) <= 0).nonzero()[0, 0])
        raise InputError("weights", f"problem {bad} has zero total weight")
    return dirs, w, batch, n


# --------------------------------------------------------------------------------------------
# M-step statistics


def _estimate(
    x64: torch.Tensor,
    wr: torch.Tensor,
    *,
    solver: str,
    kappa_min: float,
    kappa_max: float,
    prior: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None = None,
    prior_strength: float = 0.0,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Weighted moment estimates of ``N`` vMFs from soft assignments.

    Parameters
    ----------
    x64 : (P, S, 3) float64 unit directions
    wr : (P, N, S) sample weight x responsibility (any float dtype)
    prior : optional reference ``(mu0 (P, N, 3), mc0 (P, N), alpha0 (P, N))`` (float64; ``mc0``
        the reference's mean cosines) whose components act as pseudo-data of mass
        ``prior_strength * alpha0 * total mass`` each: a conjugate-style MAP prior pulling
        component ``k`` towards reference component ``k``

    Returns
    -------
    mu (P, N, 3) float64, kappa (P, N) float64, alpha (P, N) float64, mass (P, N) float64
    """
    wr = wr.double()
    mass = wr.sum(-1)  # (P, N)
    res = torch.bmm(wr, x64)  # (P, N, 3) resultant vectors
    total = mass.sum(-1, keepdim=True)  # (P, 1)
    if prior is not None and prior_strength > 0:
        mu0, mc0, a0 = prior
        pm = prior_strength * a0 * total  # (P, N) pseudo mass
        res = res + (pm * mc0).unsqueeze(-1) * mu0  # E[x] of a vMF is mean_cosine * mu
    else:
        pm = torch.zeros_like(mass)
    norm = torch.linalg.vector_norm(res, dim=-1, keepdim=True)  # (P, N, 1)
    mu = res / norm.clamp_min(DIVISOR_F64)
    # 1 - r with r = |res| / mass; in float64 the cancellation costs ~1e-16 / gap relative.
    gap_data = mass - (res * mu).sum(-1)  # sum w r (1 - x.mu) incl. pseudo-data's expectation
    if prior is not None and prior_strength > 0:
        gap_data = gap_data + pm  # pseudo-data: E[1 - x.mu] = 1 - mc0 mu0.mu, mc0 part in res
    mass_all = mass + pm
    gap = (gap_data / mass_all.clamp_min(DIVISOR_F64)).clamp(0.0, 1.0)
    kappa = kappa_from_gap(gap, solver=solver).clamp(kappa_min, kappa_max)
    alpha = mass_all / mass_all.sum(-1, keepdim=True).clamp_min(DIVISOR_F64)
    return mu, kappa, alpha, mass


# --------------------------------------------------------------------------------------------
# initialisation


def init_paper(
    dirs: Any,
    weights: Any = None,
    /,
    *,
    n_lobes: int = 8,
    kappa_solver: str = "exact",
    kappa_min: float = KAPPA_MIN,
    kappa_max: float = KAPPA_MAX,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The EM paper's initial guess: sort along the axis of highest variance, split, estimate.

    1. spherical coordinates (latitude, longitude) of the samples, in the frame whose polar
       axis is the tangent of :func:`lobelight.geometry.sphere.frame` at the weighted mean direction
       ``c`` (so ``c`` is at latitude 0, longitude 0 and the longitude wraps only at ``-c``);
    2. the samples sorted along the principal axis of the weighted 2 x 2 covariance of those
       coordinates (the axis of highest variance);
    3. the sorted samples split into ``N`` consecutive sets of equal weight (equally sized for
       drawn samples, as in the paper), each set's vMF estimated by moments (mean direction,
       concentration from the mean resultant length) and its weight share as ``alpha``.

    A set that carries no weight is estimated from its directions alone, with a negligible
    ``alpha``; a set with no samples at all (one sample can outweigh ``1/N`` of the total)
    starts as the moment estimate of all the data, with ``alpha = 0``.

    Parameters
    ----------
    dirs : (..., S, 3) directions;  weights : optional (..., S) non-negative

    Returns
    -------
    mu (..., N, 3), kappa (..., N), alpha (..., N) in the dtype of ``dirs``
    """
    x, w, batch, n = _check_data(dirs, weights, n_lobes)
    mu, kappa, alpha = _init_paper(x, w, n, kappa_solver, kappa_min, kappa_max)
    return (
        mu.reshape(*batch, n, 3),
        kappa.reshape(*batch, n),
        alpha.reshape(*batch, n),
    )


def _init_paper(x, w, n, solver, kappa_min, kappa_max):
    s = x.shape[1]
    x64 = torch.nn.functional.normalize(x.double(), dim=-1)  # (P, S, 3)
    w64 = w.double()
    wn = w64 / w64.sum(-1, keepdim=True)  # (P, S) normalised weights
    m = (wn.unsqueeze(-1) * x64).sum(1)  # (P, 3)
    zhat = torch.tensor([0.0, 0.0, 1.0], dtype=x64.dtype, device=x.device)
    c = torch.where(
        torch.linalg.vector_norm(m, dim=-1, keepdim=True) > 1e-9,
        torch.nn.functional.normalize(m, dim=-1),
        zhat,
    )
    t, b, _ = frame(c)  # polar axis t; equator through c
    xt = (x64 * t.unsqueeze(1)).sum(-1)  # (P, S)
    xb = (x64 * b.unsqueeze(1)).sum(-1)
    xc = (x64 * c.unsqueeze(1)).sum(-1)
    lat = torch.asin(xt.clamp(-1, 1))
    lon = torch.atan2(xb, xc)
    coords = torch.stack([lat, lon], -1)  # (P, S, 2)
    mean = (wn.unsqueeze(-1) * coords).sum(1, keepdim=True)  # (P, 1, 2)
    d = coords - mean
    cov = torch.einsum("ps,psi,psj->pij", wn, d, d)  # (P, 2, 2)
    _, vecs = torch.linalg.eigh(cov)  # ascending eigenvalues
    axis = vecs[..., :, 1]  # (P, 2) highest variance
    proj = (coords * axis.unsqueeze(1)).sum(-1)  # (P, S)
    order = torch.argsort(proj, dim=-1)  # (P, S)
    w_sorted = wn.gather(1, order)
    # equal-weight sets: a sample's set is given by the weight before its midpoint
    cum = torch.cumsum(w_sorted, -1) - 0.5 * w_sorted  # (P, S) in [0, 1]
    label_sorted = (cum * n).floor().clamp(0, n - 1).long()
    label = torch.empty_like(label_sorted).scatter_(1, order, label_sorted)  # (P, S)
    onehot = torch.nn.functional.one_hot(label, n).double()  # (P, S, N)
    # A tiny uniform floor keeps weightless sets defined (they estimate from directions alone).
    wr = ((wn + 1e-9 / s).unsqueeze(-1) * onehot).transpose(1, 2)  # (P, N, S)
    mu, kappa, _, mass = _estimate(x64, wr, solver=solver, kappa_min=kappa_min, kappa_max=kappa_max)
    # A set with no samples at all (one sample can carry more than 1/N of the weight) starts
    # as the whole data's moment estimate, with alpha 0.
    empty = (onehot.sum(1) == 0).unsqueeze(-1)  # (P, N, 1)
    gap_all = (1 - torch.linalg.vector_norm(m, dim=-1)).clamp(0.0, 1.0)  # (P,)
    k_all = kappa_from_gap(gap_all, solver=solver).clamp(kappa_min, kappa_max)
    mu = torch.where(empty, c.unsqueeze(1), mu)
    kappa = torch.where(empty[..., 0], k_all.unsqueeze(-1), kappa)
    alpha = mass / mass.sum(-1, keepdim=True)
    return mu.to(x.dtype), kappa.to(x.dtype), alpha.to(x.dtype)


# --------------------------------------------------------------------------------------------
# EM


def em_fit(
    dirs: Any,
    weights: Any = None,
    /,
    *,
    n_lobes: int = 8,
    init: tuple[Any, Any, Any] | None = None,
    max_iter: int = 200,
    tol: float = 1e-6,
    kappa_solver: str = "exact",
    kappa_min: float = KAPPA_MIN,
    kappa_max: float = KAPPA_MAX,
    prior: tuple[Any, Any, Any] | None = None,
    prior_strength: float = 0.0,
) -> VMFMixture:
    """Fit a mixture of ``n_lobes`` vMF distributions to weighted directions by EM.

    E-step: responsibilities ``r_sk ∝ alpha_k g(x_s; mu_k, kappa_k)`` from log-densities with
    log-sum-exp (the largest term factored out). M-step, with sample weights ``w_s``:
    ``alpha_k ∝ sum_s w_s r_sk``, ``mu_k`` the normalised weighted resultant
    ``sum_s w_s r_sk x_s``, ``kappa_k`` from its mean resultant length (:func:`kappa_from_gap`).
    With a ``prior`` each reference component adds pseudo-data (see :func:`_estimate`), which
    makes the update a MAP step.

    Convergence: a problem stops when an iteration raises its mean log-likelihood (per unit
    weight) by less than ``tol`` (in nats), or after ``max_iter`` iterations. Without a prior
    EM never lowers the likelihood; with one the change is tested in absolute value.

    Parameters
    ----------
    dirs : (..., S, 3) sample directions (normalised here)
    weights : optional (..., S) non-negative sample weights (default 1: drawn samples)
    n_lobes : number of components ``N >= 1``
    init : optional ``(mu (..., N, 3), kappa (..., N), alpha (..., N))``; default
        :func:`init_paper`
    max_iter : EM iterations at most (0 returns the initial guess with its likelihood)
    tol : log-likelihood change that counts as converged
    kappa_solver : "exact" or "approx" (:func:`kappa_from_gap`)
    kappa_min, kappa_max : bounds on the fitted concentrations
    prior : optional reference mixture ``(mu0, kappa0, alpha0)`` shaped like ``init``
    prior_strength : pseudo-data mass of the prior as a fraction of the data's (0: plain EM)

    Returns
    -------
    VMFMixture with ``(..., N, ...)`` parameters in the dtype and on the device of ``dirs``

    Raises
    ------
    InputError
        naming ``dirs``, ``weights``, ``n_lobes``, ``init``, ``prior``, ``max_iter``, ``tol``,
        ``kappa_solver`` or ``prior_strength`` when it is malformed
    """
    x, w, batch, n = _check_data(dirs, weights, n_lobes)
    max_iter = check_int(max_iter, "max_iter", minimum=0)
    if not (isinstance(tol, (int, float)) and tol >= 0):
        raise InputError("tol", f"must be a number >= 0, got {tol!r}")
    if kappa_solver not in ("exact", "approx"):
        raise InputError("kappa_solver", f"must be 'exact' or 'approx', got {kappa_solver!r}")
    if not (isinstance(prior_strength, (int, float)) and prior_strength >= 0):
        raise InputError("prior_strength", f"must be a number >= 0, got {prior_strength!r}")
    p = x.shape[0]
    if init is None:
        mu, kappa, alpha = _init_paper(x, w, n, kappa_solver, kappa_min, kappa_max)
    else:
        mu, kappa, alpha = _check_params(init, "init", batch, n, x)
    pri = None
    if prior is not None:
        mu0, k0, a0 = _check_params(prior, "prior", batch, n, x)
        pri = (mu0.double(), mean_cosine(k0.double()), a0.double())
    x64 = torch.nn.functional.normalize(x.double(), dim=-1)
    iters = torch.zeros(p, dtype=torch.int64, device=x.device)
    ll = torch.full((p,), -math.inf, dtype=torch.float64, device=x.device)
    # Work on the still-active problems only: ``idx`` are their indices, ``*_a`` their data and
    # parameters; a problem that stops writes its parameters back and leaves the batch.
    # Lobes lead the samples in the E-step, (Pa, N, S): the reductions over N then run along
    # contiguous rows of S, which vectorise better than a trailing N = 8 axis.
    idx = torch.arange(p, device=x.device)
    xta, wa, x64a = x64.transpose(1, 2).contiguous(), w, x64  # (Pa, 3, S), (Pa, S), (Pa, S, 3)
    wsum_a = w.double().sum(-1)  # (Pa,)
    pri_a = pri
    mu_a, kappa_a, alpha_a = mu, kappa, alpha
    ll_prev = torch.full((p,), -math.inf, dtype=torch.float64, device=x.device)
    out_mu, out_kappa, out_alpha = mu.clone(), kappa.clone(), alpha.clone()
    for it in range(max_iter + 1):
        # E-step: log(alpha g) = log alpha + log C + kappa (mu.x - 1); the dot products in
        # float64 (in float32, mu.x - 1 carries 6e-8 absolute error: 6e-3 nats at kappa = 1e5,
        # enough to stall the convergence test), the rest in the data's dtype
        const = alpha_a.clamp_min(DIVISOR_F32).log() + log_vmf_normalization(kappa_a)  # (Pa, N)
        dots = torch.bmm(mu_a.double(), xta)  # (Pa, N, S)
        logp = torch.addcmul(
            const.unsqueeze(-1), kappa_a.unsqueeze(-1), (dots - 1).to(x.dtype)
        )  # (Pa, N, S)
        peak = logp.amax(1, keepdim=True)  # (Pa, 1, S)
        e = torch.exp(logp - peak)
        tot = e.sum(1, keepdim=True)  # (Pa, 1, S)
        lse = (peak + tot.log()).squeeze(1)  # (Pa, S) log density
        ll_a = (wa.double() * lse.double()).sum(-1) / wsum_a  # (Pa,)
        ll[idx] = ll_a
        if it == max_iter:
            go = torch.zeros_like(ll_a, dtype=torch.bool)
        elif it == 0:
            go = torch.ones_like(ll_a, dtype=torch.bool)
        else:
            change = ll_a - ll_prev
            if pri is not None and prior_strength > 0:
                change = change.abs()
            go = change > tol
        if not bool(go.all()):
            done = ~go
            out_mu[idx[done]] = mu_a[done]
            out_kappa[idx[done]] = kappa_a[done]
            out_alpha[idx[done]] = alpha_a[done]
            if not bool(go.any()):
                break
            keep = go.nonzero().squeeze(-1)
            idx, xta, wa, x64a = idx[keep], xta[keep], wa[keep], x64a[keep]
            wsum_a, e, tot, ll_a = wsum_a[keep], e[keep], tot[keep], ll_a[keep]
            mu_a, kappa_a = mu_a[keep], kappa_a[keep]
            if pri_a is not None:
                pri_a = tuple(t[keep] for t in pri_a)
        # M-step (float64 accumulation); responsibilities e / tot
        mu_n, kappa_n, alpha_n, mass_n = _estimate(
            x64a,
            e * (wa.unsqueeze(1) / tot),  # (Pa, N, S)
            solver=kappa_solver,
            kappa_min=kappa_min,
            kappa_max=kappa_max,
            prior=pri_a,
            prior_strength=prior_strength,
        )
        alive = mass_n > 0  # (Pa, N) an empty component keeps its mean and sharpness
        mu_a = torch.where(alive.unsqueeze(-1), mu_n.to(x.dtype), mu_a)
        kappa_a = torch.where(alive, kappa_n.to(x.dtype), kappa_a)
        alpha_a = alpha_n.to(x.dtype)
        ll_prev = ll_a
        iters[idx] += 1
    mu, kappa, alpha = out_mu, out_kappa, out_alpha
    return VMFMixture(
        mu=mu.reshape(*batch, n, 3),
        kappa=kappa.reshape(*batch, n),
        alpha=alpha.reshape(*batch, n),
        loglik=ll.reshape(batch),
        iterations=iters.reshape(batch),
    )


def _check_params(params: Any, name: str, batch: tuple[int, ...], n: int, like: torch.Tensor):
    """``(mu, kappa, alpha)`` of shapes ``batch + (N, 3)``, ``batch + (N,)`` -> flattened."""
    try:
        mu, kappa, alpha = params
    except (TypeError, ValueError):
        raise InputError(name, "must be a tuple (mu, kappa, alpha)") from None
    out = []
    for part, t, shape in (
        ("mu", mu, (*batch, n, 3)),
        ("kappa", kappa, (*batch, n)),
        ("alpha", alpha, (*batch, n)),
    ):
        t = torch.as_tensor(t, device=like.device).to(like.dtype)
        if tuple(t.shape) != shape:
            raise InputError(f"{name}.{part}", f"must have shape {shape}, got {tuple(t.shape)}")
        if not bool(torch.isfinite(t).all()):
            raise InputError(f"{name}.{part}", "must be finite")
        out.append(t)
    mu, kappa, alpha = out
    if bool((kappa <= 0).any()):
        raise InputError(f"{name}.kappa", "must be > 0")
    if bool((alpha < 0).any()):
        raise InputError(f"{name}.alpha", "must be non-negative")
    mu = torch.nn.functional.normalize(mu, dim=-1)
    alpha = alpha / alpha.sum(-1, keepdim=True).clamp_min(DIVISOR_F32)
    return mu.reshape(-1, n, 3), kappa.reshape(-1, n), alpha.reshape(-1, n)


# --------------------------------------------------------------------------------------------
# sampling


def sample_mixture(mu: Any, kappa: Any, alpha: Any, u: Any) -> torch.Tensor:
    """Draw directions from vMF mixtures with given uniform numbers.

    ``u[..., 2]`` picks the component by ``alpha``; ``u[..., 0:2]`` draw the direction from
    it exactly (Wood 1994 for p = 3): ``1 - cos(theta) = -log(e^(-2 kappa) + u0 (1 -
    e^(-2 kappa))) / kappa``, computed so that sharp lobes keep their width in float32.

    Parameters
    ----------
    mu : (..., N, 3);  kappa : (..., N);  alpha : (..., N) non-negative (normalised here)
    u : (..., S, 3) uniform numbers in [0, 1)

    Returns
    -------
    (..., S, 3) unit directions
    """
    mu, kappa, alpha, u = (torch.as_tensor(t) for t in (mu, kappa, alpha, u))
    u = u.to(device=mu.device, dtype=mu.dtype)
    if u.ndim < 2 or u.shape[-1] != 3:
        raise InputError("u", f"must be a (..., S, 3) array, got {tuple(u.shape)}")
    a = alpha.to(mu.dtype)
    cdf = torch.cumsum(a / a.sum(-1, keepdim=True), -1)  # (..., N)
    n = cdf.shape[-1]
    k = (u[..., 2:3] >= cdf.unsqueeze(-2)).sum(-1).clamp(max=n - 1)  # (..., S)
    mk = torch.gather(mu, -2, k.unsqueeze(-1).expand(*k.shape, 3))  # (..., S, 3)
    kk = torch.gather(kappa.to(mu.dtype), -1, k)  # (..., S)
    u0 = (1 - u[..., 0]).clamp_min(torch.finfo(mu.dtype).tiny)  # (0, 1]
    e = torch.exp(-2 * kk)
    s = (-torch.log(e + u0 * (1 - e)) / kk).clamp(0.0, 2.0)  # 1 - cos
    sin = torch.sqrt(s * (2 - s))
    phi = 2 * math.pi * u[..., 1]
    t, b, _ = frame(mk)
    return (
        (sin * phi.cos()).unsqueeze(-1) * t
        + (sin * phi.sin()).unsqueeze(-1) * b
        + (1 - s).unsqueeze(-1) * mk
    )
