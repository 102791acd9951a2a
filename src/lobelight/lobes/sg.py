"""Spherical Gaussians: evaluation, integrals, products, vMF densities and simple fits.

Convention (``docs/conventions.md``): ``G(w; mu, lam) = exp(lam (mu.w - 1))`` with unit mean
``mu``, sharpness ``lam > 0`` and peak 1; ``lam = 1/sigma**2`` links it to the papers' standard
deviation. Shapes broadcast over leading dimensions: directions and means are ``(..., 3)``,
sharpness ``(...)``, RGB (or any channel) weights ``(..., C)``; a mixture of ``N`` lobes puts
``N`` before the vector axis: means ``(..., N, 3)``, sharpness ``(..., N)``,
weights ``(..., N, C)``.

Numerics, for ``lam`` from 1e-3 to 1e5 in float32:

* ``1 - mu.w`` is computed as ``|w - mu|**2 / 2`` (equal for unit vectors). Near the peak of a
  sharp lobe ``1 - mu.w`` is ~1e-5, which the dot product would lose to cancellation; the chord
  keeps full relative precision, so ``G`` is accurate at ``lam = 1e5``.
* Every exponent is ``<= 0`` and ``1 - exp(-2 lam)`` is ``-expm1(-2 lam)``, so nothing
  overflows and small sharpness keeps its precision; ``lam -> 0`` limits (``4 pi``, ``1/3``) are
  taken explicitly, with gradient-safe branches.

All functions are torch-first and accept numpy (numpy in, numpy out; see :mod:`lobelight._backend`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from .._backend import as_float, dispatch
from .._checks import check_directions
from .._tol import SHARPNESS_MIN
from ..errors import InputError

__all__ = [
    "LAM_RANGE",
    "Gaussians",
    "evaluate",
    "evaluate_mixture",
    "fit_from_samples",
    "inner_product",
    "integral",
    "integrate_mixture_constant",
    "lam_from_mean_cosine",
    "mean_cosine",
    "product",
    "rotate",
    "sharpness_to_sigma",
    "sigma_to_sharpness",
    "vmf_normalization",
    "vmf_pdf",
]

#: The sharpness range of the Gaussians lobelight fits or estimates: from a hemisphere-wide lobe
#: to well past a Phong exponent of 1e4.
LAM_RANGE = (0.5, 3e4)

_TWO_PI = 2 * math.pi


def _half_chord2(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``|a - b|**2 / 2`` = ``1 - a.b`` for unit vectors, without cancellation near a = b."""
    d = a - b
    return 0.5 * (d * d).sum(-1)


def _one_minus_exp_neg2_over(lam: torch.Tensor) -> torch.Tensor:
    """``(1 - exp(-2 lam)) / lam``, 2 at ``lam = 0``; stable and gradient-safe."""
    small = lam < SHARPNESS_MIN
    safe = torch.where(small, torch.ones_like(lam), lam)
    return torch.where(small, torch.full_like(lam, 2.0), -torch.expm1(-2 * safe) / safe)


# --------------------------------------------------------------------------------------------
# the record of fitted Gaussians


@dataclass(eq=False)
class Gaussians:
    """N Gaussians per view for B vertices: the paper's 7 floats (w RGB, mu, sigma) per Gaussian.

    Attributes
    ----------
    w : (B, J, N, 3) RGB weights (0 for views below the horizon)
    mu : (B, J, N, 3) unit means (global frame)
    lam : (B, J, N) sharpness, ``sigma = 1 / sqrt(lam)``
    """

    w: torch.Tensor
    mu: torch.Tensor
    lam: torch.Tensor

    @property
    def shape(self) -> tuple[int, ...]:
        """``(B, J, N)``."""
        return tuple(self.lam.shape)

    @property
    def device(self) -> torch.device:
        return self.w.device

    def take(self, idx) -> Gaussians:
        return Gaussians(self.w[idx], self.mu[idx], self.lam[idx])

    def detach(self) -> Gaussians:
        return Gaussians(self.w.detach(), self.mu.detach(), self.lam.detach())

    def to(self, device) -> Gaussians:
        return Gaussians(self.w.to(device), self.mu.to(device), self.lam.to(device))

    def contiguous(self) -> Gaussians:
        """The same Gaussians with C-ordered arrays (itself where they are)."""
        return Gaussians(self.w.contiguous(), self.mu.contiguous(), self.lam.contiguous())

    def records(self, a: int, b: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Records ``a`` to ``b`` of the ``B J N`` in row-major ``(b, j, n)`` order: ``w
        (b - a, 3)``, ``mu (b - a, 3)``, ``lam (b - a,)`` (views where the arrays are
        C-ordered, :meth:`contiguous`)."""
        return self.w.reshape(-1, 3)[a:b], self.mu.reshape(-1, 3)[a:b], self.lam.reshape(-1)[a:b]


# --------------------------------------------------------------------------------------------
# evaluation and closed forms


@dispatch
def evaluate(dirs, mu, lam, /, weight=None):
    """``G(dirs; mu, lam)`` (times ``weight``), evaluated as ``exp(-lam |dirs - mu|**2 / 2)``.

    Parameters
    ----------
    dirs : (..., 3) unit directions
    mu : (..., 3) unit means (broadcast with ``dirs``)
    lam : (...) or scalar sharpness
    weight : optional (..., C) channel weights

    Returns
    -------
    (...) values in ``[0, 1]``, or (..., C) with ``weight``
    """
    dirs = as_float(dirs)
    check_directions(dirs, "dirs")
    mu = as_float(mu, like=dirs)
    check_directions(mu, "mu")
    lam = as_float(lam, like=dirs)
    g = torch.exp(-lam * _half_chord2(dirs, mu))
    if weight is None:
        return g
    return g.unsqueeze(-1) * as_float(weight, like=g)


@dispatch
def integral(lam, /, weight=None):
    """``∫ G dω = 2 pi (1 - exp(-2 lam)) / lam`` (``4 pi`` at ``lam = 0``), times ``weight``.

    Parameters
    ----------
    lam : (...) sharpness >= 0
    weight : optional (..., C)

    Returns
    -------
    (...), or (..., C) with ``weight``
    """
    lam = as_float(lam)
    out = _TWO_PI * _one_minus_exp_neg2_over(lam)
    return out if weight is None else out.unsqueeze(-1) * as_float(weight, like=out)


@dispatch
def product(mu1, lam1, mu2, lam2, /, *, log_scale: bool = False):
    """The product of two SGs is an SG: ``G1 G2 = scale * G(mu, lam)``.

    ``lam = |lam1 mu1 + lam2 mu2|``, ``mu = (lam1 mu1 + lam2 mu2) / lam`` and
    ``scale = exp(lam - lam1 - lam2)``. The exponent is computed as
    ``-lam1 lam2 |mu1 - mu2|**2 / (lam1 + lam2 + lam)`` (the same number, no cancellation when
    sharp lobes nearly coincide). When ``lam1 mu1 = -lam2 mu2`` the product is the constant
    ``scale``: then ``lam = 0`` and ``mu`` is returned as ``mu1``.

    Parameters
    ----------
    mu1, mu2 : (..., 3) unit means;  lam1, lam2 : (...) sharpness (all broadcast)
    log_scale : return ``log(scale)`` instead of ``scale`` (finite where ``scale`` underflows,
        e.g. two sharp lobes far apart)

    Returns
    -------
    mu : (..., 3);  lam : (...);  scale : (...) in ``[0, 1]`` (or its log, ``<= 0``)
    """
    mu1 = as_float(mu1)
    check_directions(mu1, "mu1")
    mu2 = as_float(mu2, like=mu1)
    check_directions(mu2, "mu2")
    lam1, lam2 = as_float(lam1, like=mu1), as_float(lam2, like=mu1)
    um = lam1.unsqueeze(-1) * mu1 + lam2.unsqueeze(-1) * mu2  # (..., 3)
    lam = torch.linalg.vector_norm(um, dim=-1)
    tiny = torch.finfo(lam.dtype).tiny
    zero = lam <= tiny
    mu = torch.where(zero.unsqueeze(-1), mu1.expand_as(um), um / lam.clamp_min(tiny).unsqueeze(-1))
    denom = (lam1 + lam2 + lam).clamp_min(tiny)
    log_s = -lam1 * lam2 * 2 * _half_chord2(mu1, mu2) / denom
    return mu, lam, (log_s if log_scale else torch.exp(log_s))


@dispatch
def inner_product(mu1, lam1, mu2, lam2, /):
    """``∫ G1 G2 dω = scale * 2 pi (1 - exp(-2 lam)) / lam`` with ``(mu, lam, scale)`` of
    :func:`product`; every factor is formed without overflow or cancellation.

    Parameters
    ----------
    mu1, mu2 : (..., 3) unit means;  lam1, lam2 : (...) sharpness (broadcast)

    Returns
    -------
    (...)
    """
    _, lam, scale = product(mu1, lam1, mu2, lam2)
    return scale * _TWO_PI * _one_minus_exp_neg2_over(lam)


@dispatch
def sigma_to_sharpness(sigma, /):
    """``lam = 1 / sigma**2`` (conventions.md), ``sigma`` in radians. (...) -> (...)."""
    sigma = as_float(sigma)
    return 1 / (sigma * sigma)


@dispatch
def sharpness_to_sigma(lam, /):
    """``sigma = 1 / sqrt(lam)``, inverse of :func:`sigma_to_sharpness`. (...) -> (...)."""
    return torch.rsqrt(as_float(lam))


@dispatch
def vmf_normalization(lam, /):
    """``1 / ∫ G dω = lam / (2 pi (1 - exp(-2 lam)))`` (``1/(4 pi)`` at 0). (...) -> (...).

    With it ``vmf = G * vmf_normalization(kappa)`` is the von Mises-Fisher density (kappa = lam).
    """
    lam = as_float(lam)
    return 1 / (_TWO_PI * _one_minus_exp_neg2_over(lam))


@dispatch
def vmf_pdf(dirs, mu, kappa, /):
    """von Mises-Fisher density on the sphere (integrates to 1), ``G / ∫ G``.

    Parameters
    ----------
    dirs : (..., 3);  mu : (..., 3);  kappa : (...) concentration (= sharpness)

    Returns
    -------
    (...) density per steradian
    """
    g = evaluate(dirs, mu, kappa)
    return g * vmf_normalization(as_float(kappa, like=g))


# --------------------------------------------------------------------------------------------
# mean cosine (the vMF mean resultant length, Langevin function) and its inverse

# coth x - 1/x = sum_n 2^(2n) B_2n x^(2n-1) / (2n)!  (n >= 1; Bernoulli numbers B_2n)
_SERIES = (
    1 / 3,
    -1 / 45,
    2 / 945,
    -1 / 4725,
    2 / 93555,
    -1382 / 638512875,
    4 / 18243225,
    -3617 / 162820783125,
    87734 / 38979295480125,
    -349222 / 1531329465290625,
)
# Below 0.5 the closed form loses ~eps/x^2 to cancellation; the ten terms above truncate at
# ~1e-16 relative there (terms shrink by x^2/pi^2).
_SERIES_BELOW = 0.5


def _two_over_expm1_2k(k: torch.Tensor) -> torch.Tensor:
    """``2 / (exp(2k) - 1) = coth(k) - 1`` for ``k > 0``, as ``2 e^{-2k} / (1 - e^{-2k})``: no
    overflow for large k (in the value or its gradient), no cancellation for small k."""
    e = torch.exp(-2 * k)
    return 2 * e / -torch.expm1(-2 * k)


def _mean_cosine64(k: torch.Tensor) -> torch.Tensor:
    """``coth k - 1/k`` in float64 for ``k >= 0``."""
    small = k < _SERIES_BELOW
    safe = torch.where(small, torch.ones_like(k), k)
    direct = 1 + _two_over_expm1_2k(safe) - 1 / safe
    k2 = k * k
    series = torch.zeros_like(k)
    for c in reversed(_SERIES):
        series = series * k2 + c
    return torch.where(small, k * series, direct)


def _gap64(k: torch.Tensor) -> torch.Tensor:
    """``1 - mean_cosine(k) = 1/k - (coth(k) - 1)`` in float64, precise when it is tiny."""
    small = k < _SERIES_BELOW
    safe = torch.where(small, torch.ones_like(k), k)
    return torch.where(small, 1 - _mean_cosine64(k), 1 / safe - _two_over_expm1_2k(safe))


def _mean_cosine_deriv64(k: torch.Tensor) -> torch.Tensor:
    """``d/dk (coth k - 1/k) = 1/k**2 - 1/sinh(k)**2`` in float64 (1/3 at 0)."""
    small = k < 0.05
    safe = torch.where(small, torch.ones_like(k), k)
    direct = 1 / (safe * safe) - 1 / torch.sinh(safe) ** 2  # sinh overflow -> 0, fine
    return torch.where(small, 1 / 3 - k * k / 15, direct)


@dispatch
def mean_cosine(lam, /):
    """``E[mu.w]`` under the vMF of concentration ``lam``: ``coth(lam) - 1/lam`` (0 at 0).

    Evaluated in float64 (series below 0.5, where the closed form cancels) and cast back.

    Parameters
    ----------
    lam : (...) >= 0

    Returns
    -------
    (...) in ``[0, 1)``
    """
    lam = as_float(lam)
    return _mean_cosine64(lam.double()).to(lam.dtype)


def _lam_from_gap(gap: torch.Tensor, *, iters: int = 8) -> torch.Tensor:
    """Solve ``1 - mean_cosine(lam) = gap`` for lam (float64 in and out)."""
    # For gap < 1/25 the root is past k = 25, where gap(k) = 1/k - 2/expm1(2k) is 1/k to within
    # 1e-21 relative: exact in float64, and no Newton step on a derivative that underflows.
    sharp = gap < 0.04
    d = torch.where(sharp, torch.full_like(gap, 0.5), gap).clamp(0.0, 1.0)
    r = 1 - d
    # Banerjee et al. 2005 (p = 3): lam ~ r (3 - r^2) / (1 - r^2), within a few percent
    k = r * (3 - r * r) / (d * (2 - d))
    for _ in range(iters):
        # Newton on gap(k) - d = 0; gap' = -mean_cosine'. The step is clamped to a factor of 4
        # so a poor start cannot jump to negative k; from Banerjee's start it never binds.
        step = (_gap64(k) - d) / _mean_cosine_deriv64(k)
        k = torch.minimum(torch.maximum(k + step, k / 4), k * 4)
    k = torch.where(sharp, 1 / gap.clamp_min(0.0), k)  # 1/0 = inf for r = 1
    return torch.where(gap >= 1, torch.zeros_like(k), k)


@dispatch
def lam_from_mean_cosine(r, /):
    """Inverse of :func:`mean_cosine`: the concentration whose vMF has mean cosine ``r``.

    Banerjee et al.'s closed-form estimate refined by Newton steps in float64, accurate to
    float64 rounding over ``(0, 1)``. ``r <= 0`` gives 0, ``r >= 1`` gives ``inf``. For sharp
    lobes ``r`` is within ``1/lam`` of 1, so float32 ``r`` limits ``lam`` to about
    ``lam * 6e-8`` relative; :func:`fit_from_samples` avoids this by working with ``1 - r``.

    Parameters
    ----------
    r : (...) mean cosine

    Returns
    -------
    (...) sharpness, dtype of ``r``
    """
    r = as_float(r)
    return _lam_from_gap(1 - r.double()).to(r.dtype)


# --------------------------------------------------------------------------------------------
# mixtures, rotation, fitting


@dispatch
def evaluate_mixture(dirs, mus, lams, weights, /):
    """Sum of ``N`` weighted lobes, ``sum_k weights_k G(dirs; mus_k, lams_k)``.

    Parameters
    ----------
    dirs : (..., 3)
    mus : (..., N, 3);  lams : (..., N);  weights : (..., N, C)  (leading dims broadcast)

    Returns
    -------
    (..., C)
    """
    dirs = as_float(dirs)
    check_directions(dirs, "dirs")
    mus = as_float(mus, like=dirs)
    check_directions(mus, "mus")
    weights = as_float(weights, like=dirs)
    if weights.ndim < 2:
        raise InputError("weights", f"must be (..., N, C), got shape {tuple(weights.shape)}")
    g = evaluate(dirs.unsqueeze(-2), mus, as_float(lams, like=dirs))  # (..., N)
    return (g.unsqueeze(-1) * weights).sum(-2)


@dispatch
def integrate_mixture_constant(lams, weights, /, *, radiance=1.0):
    """``∫ (sum_k weights_k G_k) L dω`` for a constant ``L = radiance``.

    Parameters
    ----------
    lams : (..., N);  weights : (..., N, C);  radiance : scalar or (..., C)

    Returns
    -------
    (..., C)
    """
    weights = as_float(weights)
    lams = as_float(lams, like=weights)
    return integral(lams, weights).sum(-2) * as_float(radiance, like=weights)


@dispatch
def rotate(mu, R, /):
    """Rotate lobe means: ``R @ mu``.

    To rotate the *lighting* by ``R`` instead, rotate the lobes by ``R.T`` (Green 2006, sec. 5).

    Parameters
    ----------
    mu : (..., 3);  R : (..., 3, 3) (broadcast)

    Returns
    -------
    (..., 3)
    """
    mu = as_float(mu)
    check_directions(mu, "mu")
    R = as_float(R, like=mu)
    if R.shape[-2:] != (3, 3):
        raise InputError("R", f"must be a (..., 3, 3) rotation, got shape {tuple(R.shape)}")
    return (R @ mu.unsqueeze(-1)).squeeze(-1)


@dispatch
def fit_from_samples(dirs, values, weights, /):
    """Moment estimate of one SG from samples of a non-negative function on the sphere.

    Treating ``values * weights`` as a density (``weights`` are quadrature solid angles):
    ``mu`` is the normalised mean direction; ``lam`` is the vMF concentration whose mean cosine
    is the mean resultant length ``r`` — solved from ``1 - r = E[|w - mu|**2 / 2]``, which keeps
    its precision for sharp lobes where ``r`` is 1 - 1e-5; the amplitude is the least-squares
    ``a = ∫ f G / ∫ G**2`` given ``mu`` and ``lam``. For an exact SG all three are recovered
    (up to quadrature error), so this is the natural initial guess for non-linear fits.
    Negative values are ignored (clamped to 0) for ``mu`` and ``lam``. Channel values use the
    channel sum for ``mu`` and ``lam`` and get one amplitude per channel.

    Parameters
    ----------
    dirs : (..., S, 3) unit sample directions
    values : (..., S) or (..., S, C)
    weights : (..., S) quadrature weights (broadcast)

    Returns
    -------
    mu : (..., 3);  lam : (...);  amplitude : (...) or (..., C)
    """
    dirs = as_float(dirs)
    check_directions(dirs, "dirs")
    values = as_float(values, like=dirs)
    w = as_float(weights, like=dirs)
    channels = values.ndim == dirs.ndim
    f = values.sum(-1) if channels else values  # (..., S)
    wf = w * f.clamp_min(0)  # (..., S) density
    mass = wf.sum(-1)  # (...)
    tiny = torch.finfo(dirs.dtype).tiny
    m = (wf.unsqueeze(-1) * dirs).sum(-2) / mass.clamp_min(tiny).unsqueeze(-1)  # (..., 3)
    norm = torch.linalg.vector_norm(m, dim=-1, keepdim=True)
    empty = norm <= tiny
    up = torch.tensor([0.0, 1.0, 0.0], dtype=dirs.dtype, device=dirs.device)
    mu = torch.where(empty, up, m / norm.clamp_min(tiny))  # (..., 3)
    gap = (wf * _half_chord2(dirs, mu.unsqueeze(-2))).sum(-1) / mass.clamp_min(tiny)  # 1 - r
    lam = _lam_from_gap(gap.double()).to(dirs.dtype)
    lam = torch.where(empty[..., 0], torch.zeros_like(lam), lam)
    g = evaluate(dirs, mu.unsqueeze(-2), lam.unsqueeze(-1))  # (..., S)
    den = (w * g * g).sum(-1).clamp_min(tiny)  # (...)
    if channels:
        amp = ((w * g).unsqueeze(-1) * values).sum(-2) / den.unsqueeze(-1)
    else:
        amp = (w * g * values).sum(-1) / den
    return mu, lam, amp
