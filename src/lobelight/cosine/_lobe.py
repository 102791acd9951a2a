"""Cosine lobes ``c(w) = s max(a.w, 0)^e``: evaluation, closed-form integrals, the product peak.

Convention (docs/conventions.md and the paper, eq. 4): ``a`` is a **unit** axis, ``s`` the scale and
``e >= 0`` the exponent. Where a model writes a lobe with a non-unit vector, as Lafortune's
``max(M v . w, 0)^e`` (paper eq. 30), the length goes into the scale: ``|M v|^e``
(:func:`from_vector`). At ``e = 0`` the lobe is the indicator of the open hemisphere around
``a`` (so ``c_unit`` of the paper's eq. 40 is 1 on the hemisphere and the integral stays
``2 pi s / (e + 1)``).

The product of two lobes, geometry used throughout
    Put ``a1`` and ``a2`` (angle ``alpha`` apart) in a plane and measure the longitude ``lam``
    in that plane from ``a1`` towards ``a2``; the polar angle ``theta`` is taken from the plane's
    normal. Then ``a_i . w = sin(theta) cos(lam - lam_i)``, so every product of lobes whose axes
    lie in the plane separates::

        ∫ prod_i max(a_i.w, 0)^(e_i) dw = K(sum e_i + 1) * ∫_lune prod_i cos(lam - lam_i)^(e_i) dlam

    with ``K(n) = ∫_0^pi sin^n = sqrt(pi) Gamma((n+1)/2) / Gamma(n/2 + 1)`` in closed form and
    the 1-D integral over the lune ``lam in (alpha - pi/2, pi/2)`` (width ``pi - alpha``) where
    both lobes are positive. The fitted lobe's axis lies in the same plane (it maximises
    ``c1 c2``, whose maximum lies on the arc between the axes), so products, their squares and
    their inner products with the fitted lobe are all 1-D integrals: this is what makes the
    product table cheap to build (:mod:`lobelight.cosine._tables`).

    The maximiser of ``c1 c2`` along the arc, at angle ``beta`` from ``a1`` (``gamma = alpha -
    beta`` from ``a2``), solves ``e1 tan(beta) = e2 tan(gamma)``, i.e. the quadratic
    ``e1 sin(alpha) t^2 + (e1 + e2) cos(alpha) t - e2 sin(alpha) = 0`` in ``t = tan(beta)``: the
    paper's Nelder-Mead search (its eq. 18) has a closed-form answer, see :func:`product_peak`.

All functions are torch-first and accept numpy (numpy in, numpy out; :mod:`lobelight._backend`).
"""

from __future__ import annotations

import functools
import math

import torch

from .._backend import as_float, dispatch
from .._checks import check_directions
from .._tol import DIVISOR_F32, DIVISOR_F64
from ..errors import InputError
from ..geometry.sphere import frame, normalize

__all__ = [
    "evaluate",
    "from_vector",
    "integral",
    "product_integral",
    "product_peak",
]

_TWO_PI = 2 * math.pi
_HALF_PI = math.pi / 2


def _check_exponent(e: torch.Tensor, name: str) -> None:
    """Exponents must be finite and >= 0 (one reduction, so one sync on a GPU)."""
    if not bool(torch.all(torch.isfinite(e) & (e >= 0))):
        raise InputError(name, "cosine-lobe exponents must be finite and >= 0")


# --------------------------------------------------------------------------------------------
# one lobe


@dispatch
def evaluate(dirs, axis, exponent, /, scale=None):
    """``c(dirs) = scale * max(axis . dirs, 0)^exponent`` (0 on and below the horizon).

    Parameters
    ----------
    dirs : (..., 3) unit directions
    axis : (..., 3) unit axes (broadcast with ``dirs``)
    exponent : (...) or scalar, >= 0
    scale : optional (...) scales, broadcast (colour: multiply the result by ``(..., C)``)

    Returns
    -------
    (...)
    """
    dirs = as_float(dirs)
    check_directions(dirs, "dirs")
    axis = as_float(axis, like=dirs)
    check_directions(axis, "axis")
    e = as_float(exponent, like=dirs)
    cos = (dirs * axis).sum(-1)
    pos = cos > 0
    val = torch.where(pos, torch.exp(torch.special.xlogy(e, cos.clamp_min(0))), 0.0)
    return val if scale is None else val * as_float(scale, like=val)


@dispatch
def integral(exponent, /, scale=None):
    """``∫ c dw = 2 pi scale / (exponent + 1)`` over the sphere, exactly.

    The paper tabulates this integral (128 samples per decade, adaptive Gauss quadrature, its
    section 4.2) because it did not use the closed form; the closed form is exact and cheaper
    than a table lookup, so lobelight has no integral table. Proof: ``∫ max(a.w,0)^e dw =
    2 pi ∫_0^1 mu^e dmu``.

    Parameters
    ----------
    exponent : (...) >= 0
    scale : optional (...) scales, broadcast

    Returns
    -------
    (...)
    """
    e = as_float(exponent)
    out = _TWO_PI / (e + 1)
    return out if scale is None else out * as_float(scale, like=out)


@dispatch
def from_vector(v, exponent, /):
    """A lobe written with a non-unit vector, ``max(v . w, 0)^e``, as a unit axis and a scale.

    ``max(v.w, 0)^e = |v|^e max((v/|v|).w, 0)^e`` (the paper's Lafortune lobes, eq. 30).

    Parameters
    ----------
    v : (..., 3) non-zero vectors;  exponent : (...) >= 0

    Returns
    -------
    axis : (..., 3) unit;  scale : (...) ``|v|^exponent``
    """
    v = as_float(v)
    check_directions(v, "v")
    e = as_float(exponent, like=v)
    norm = torch.linalg.vector_norm(v, dim=-1)
    return normalize(v), torch.exp(torch.special.xlogy(e, norm))


# --------------------------------------------------------------------------------------------
# the product of two lobes: peak (closed form) and exact integrals (1-D quadrature)


def _log_cos(c: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
    """``log(cos x)`` from ``(cos x, sin x)``, ``cos x >= 0``: ``log1p(-sin^2/(1+cos))`` near
    ``x = 0`` (no cancellation for sharp lobes), ``log(cos)`` elsewhere."""
    small = c > 0.5
    near = torch.log1p(-(s * s) / (1 + c))
    return torch.where(small, near, torch.log(c.clamp_min(0)))


def _arc_point(e1, e2, c, s):
    """``(cos, sin)`` of the angle from ``a1`` of the maximiser of ``c1 c2`` (unit scales).

    Root of ``w1 s t^2 + c t - w2 s = 0`` (``t = tan(beta)``, ``w_i = e_i/(e1+e2)``), from the
    form without cancellation: ``t = 2 C / (B + r)`` for ``B >= 0`` and ``(r - B) / 2A`` for
    ``B < 0`` (``r = sqrt(B^2 + 4 A C)``), kept as a (numerator, denominator) pair so that both
    ``cos`` and ``sin`` of ``beta`` keep full relative precision. ``e1 = e2 = 0`` (the product is
    the lune between two hemispheres) gives the bisector.
    """
    tot = e1 + e2
    zero = tot <= 0
    w1 = torch.where(zero, torch.full_like(tot, 0.5), e1 / torch.where(zero, 1.0, tot))
    w2 = 1 - w1
    A, B, C = w1 * s, c, w2 * s
    r = torch.sqrt(B * B + 4 * A * C)
    pos = B >= 0
    num = torch.where(pos, 2 * C, r - B)
    den = torch.where(pos, B + r, 2 * A)
    h = torch.sqrt(num * num + den * den)
    degenerate = h <= 0  # alpha = pi/2 with e2 = 0 (C = B = 0): the peak is a1 itself
    h = torch.where(degenerate, 1.0, h)
    cb = torch.where(degenerate, torch.ones_like(h), den / h)
    sb = torch.where(degenerate, torch.zeros_like(h), num / h)
    # both exponents zero: the bisector, by half-angle formulas
    hc = torch.sqrt(((1 + c) / 2).clamp_min(0))
    hs = torch.where(
        c > 0, s / (2 * hc.clamp_min(DIVISOR_F32)), torch.sqrt(((1 - c) / 2).clamp_min(0))
    )
    return torch.where(zero, hc, cb), torch.where(zero, hs, sb)


def _peak(e1, e2, c, s):
    """Peak of ``c1 c2`` for axes with ``cos(alpha) = c``, ``sin(alpha) = s >= 0``.

    Returns ``(cos b, sin b, cos g, sin g, log_peak)``: ``b`` the angle from ``a1`` to the peak,
    ``g = alpha - b`` from ``a2`` (each from its own quadratic, so both keep full relative
    precision near pi/2), ``log_peak = e1 log cos b + e2 log cos g`` (``0 log 0 = 0``).
    """
    cb, sb = _arc_point(e1, e2, c, s)
    cg, sg = _arc_point(e2, e1, c, s)
    log_peak = _xlog(e1, _log_cos(cb, sb)) + _xlog(e2, _log_cos(cg, sg))
    return cb, sb, cg, sg, log_peak


def _xlog(e: torch.Tensor, logc: torch.Tensor) -> torch.Tensor:
    """``e * log c`` with ``0 * log 0 = 0`` (a zero exponent is the hemisphere indicator)."""
    return torch.where(e == 0, torch.zeros_like(logc), e * logc)


def _axis_pair(axis1: torch.Tensor, axis2: torch.Tensor):
    """``cos(alpha)``, ``sin(alpha)`` and the unit tangent at ``a1`` towards ``a2``."""
    c = (axis1 * axis2).sum(-1)
    perp = axis2 - c.unsqueeze(-1) * axis1  # (..., 3) component of a2 orthogonal to a1
    s = torch.linalg.vector_norm(perp, dim=-1)
    tiny = torch.finfo(s.dtype).tiny
    # parallel or opposite axes: any tangent will do (beta is 0, or the product is zero)
    fallback = frame(axis1)[0]
    t = torch.where((s > tiny).unsqueeze(-1), perp / s.clamp_min(tiny).unsqueeze(-1), fallback)
    return c.clamp(-1, 1), s, t


@dispatch
def product_peak(e1, e2, angle, /):
    """Where and how high ``c1 c2`` peaks, in closed form (unit scales).

    The axis of the paper's product lobe is the maximiser of ``c1 c2`` (its eq. 18, found there
    with Nelder-Mead); it lies on the arc from ``a1`` to ``a2`` at the angle ``beta`` solving
    ``e1 tan(beta) = e2 tan(angle - beta)`` (see the module docstring). When one exponent is 0
    and the angle exceeds pi/2, the peak is on the zero-exponent lobe's horizon (the nearest
    point of its hemisphere to the other axis); for ``e1 = e2 = 0`` it is the bisector.

    Parameters
    ----------
    e1, e2 : (...) exponents >= 0;  angle : (...) angle between the axes in ``[0, pi]``
        (all broadcast)

    Returns
    -------
    beta : (...) angle from ``a1`` towards ``a2`` in ``[0, angle]``
    log_peak : (...) ``log(c1 c2)`` at the peak (``-inf`` where the product is 0)
    """
    e1 = as_float(e1)
    e2, angle = as_float(e2, like=e1), as_float(angle, like=e1)
    e1, e2, angle = torch.broadcast_tensors(e1, e2, angle)
    cb, sb, _, _, log_peak = _peak(e1, e2, torch.cos(angle), torch.sin(angle).clamp_min(0))
    return torch.atan2(sb, cb), log_peak


def _log_sin_power_integral(n: torch.Tensor) -> torch.Tensor:
    """``log K(n) = log ∫_0^pi sin(theta)^n dtheta = log(sqrt(pi) G(y) / G(y + 1/2))``,
    ``y = (n+1)/2``. For ``y >= 20`` the difference of log-gammas (each ~``y log y``, so the
    direct difference loses ~1e-10 at ``y = 1e5``) is the asymptotic series
    ``1/2 log y - 1/(8y) + 1/(192 y^3) - 1/(640 y^5) + 17/(14336 y^7)`` (truncation < 1e-14)."""
    y = (n + 1) / 2
    big = y >= 20
    yb = torch.where(big, y, 20.0)
    series = (
        0.5 * torch.log(yb)
        - 1 / (8 * yb)
        + 1 / (192 * yb**3)
        - 1 / (640 * yb**5)
        + 17 / (14336 * yb**7)
    )
    ys = torch.where(big, 1.0, y)
    direct = torch.lgamma(ys + 0.5) - torch.lgamma(ys)
    return 0.5 * math.log(math.pi) - torch.where(big, series, direct)


@functools.lru_cache(maxsize=8)
def _tanh_sinh(n: int, device_str: str):
    """Tanh-sinh (double-exponential) rule on [0, 1]: nodes as ``x`` and ``1 - x`` (each exact
    near its end), weights. ``2 n + 1`` nodes on ``|t| <= 3.2``, where the weights fall below
    1e-30: endpoint singularities (``sin(d)^e`` with fractional ``e`` at the lune's edge) and a
    peak at the other end are both resolved, which Gauss-Legendre does poorly."""
    t = torch.linspace(-3.2, 3.2, 2 * n + 1, dtype=torch.float64)
    h = 3.2 / n
    u = _HALF_PI * torch.sinh(t)
    x = torch.sigmoid(2 * u)  # (1 + tanh u) / 2
    xm = torch.sigmoid(-2 * u)  # 1 - x, exact near x = 1
    w = h * (math.pi / 4) * torch.cosh(t) / torch.cosh(u) ** 2
    dev = torch.device(device_str)
    return x.to(dev), xm.to(dev), w.to(dev)


_WINDOW_LOG_DROP = 40.0  # quadrature window: where log(c1 c2 / peak) >= -40 (e^-40 = 4e-18)


def _half_lune(e_end, e_other, width, peak, curv, n):
    """Nodes on one half of the lune, from the window's outer end to the peak.

    Distances ``d`` are measured from the lune's edge where the ``e_end`` lobe vanishes
    (``cos = sin(d)``); the other lobe is ``sin(width - d)``. Returns, per node, ``log(c1 c2 /
    peak)`` (``g``), ``log cos`` of the angle to the peak (``ell``) and the weight (radians).

    The window starts where ``log(c1 c2)`` has dropped by 40 below the peak: ``log(c1 c2)`` is
    concave along the arc with curvature at least ``curv`` on this half (each ``e log cos``
    term has curvature ``e sec^2 >= e``, growing towards the lobe's horizon), so the drop over a
    distance ``x`` is at least ``curv x^2 / 2`` and ``sqrt(2 * 40 / curv)`` is a safe width.
    """
    x, xm, w = _tanh_sinh(n, str(peak.device))
    span = torch.sqrt(2 * _WINDOW_LOG_DROP / curv.clamp_min(DIVISOR_F64))
    start = (peak - span).clamp_min(0)
    length = (peak - start).unsqueeze(-1)  # (m, 1)
    dist = length * xm  # (m, nodes) distance to the peak, exact near it
    d = torch.where(x < 0.5, start.unsqueeze(-1) + length * x, peak.unsqueeze(-1) - dist)
    e_end_, e_other_ = e_end.unsqueeze(-1), e_other.unsqueeze(-1)
    far = (width - peak).unsqueeze(-1)  # distance of the peak to the other edge
    g = _xlog(e_end_, torch.log(torch.sin(d)) - torch.log(torch.sin(peak)).unsqueeze(-1))
    g = g + _xlog(e_other_, torch.log(torch.sin(far + dist)) - torch.log(torch.sin(far)))
    g = torch.where(length > 0, g, -math.inf)  # an empty half (peak on the lune's edge)
    ell = torch.log1p(-2 * torch.sin(dist / 2) ** 2)  # log cos(dist), exact for small dist
    return g, ell, length * w


def _lune_nodes(e1, e2, alpha, *, nodes):
    """Quadrature over the lune for the product of lobes ``e1``, ``e2`` at angle ``alpha``.

    Float64 tensors of shape (m,). Returns ``log_peak`` (m,); per node (m, 2 (2 n + 1)):
    ``g = log(c1 c2 / peak)``, ``ell = log cos`` (angle to the peak) and weights in radians, so
    that ``∫_lune (c1 c2)(lam)^k cos(lam - beta)^e dlam = peak^k sum w exp(k g + e ell)``; and
    ``k_arc`` (m,), the curvature of ``-log(c1 c2)`` along the arc at the peak.
    """
    c, s = torch.cos(alpha), torch.sin(alpha).clamp_min(0)
    cb, sb, cg, sg, log_peak = _peak(e1, e2, c, s)
    width = torch.atan2(s, -c)  # pi - alpha, exact near alpha = pi
    to_left = torch.atan2(cg, sg)  # pi/2 - gamma: peak's distance from a2's horizon
    to_right = torch.atan2(cb, sb)  # pi/2 - beta: from a1's horizon
    sec_b = torch.where(e1 == 0, 0.0, e1 / (cb * cb))
    sec_g = torch.where(e2 == 0, 0.0, e2 / (cg * cg))
    gl, ll, wl = _half_lune(e2, e1, width, to_left, e1 + sec_g, nodes)
    gr, lr, wr = _half_lune(e1, e2, width, to_right, sec_b + e2, nodes)
    g, ell, w = torch.cat([gl, gr], -1), torch.cat([ll, lr], -1), torch.cat([wl, wr], -1)
    return log_peak, g, ell, w, sec_b + sec_g


@dispatch
def product_integral(e1, e2, angle, /, *, nodes: int = 48):
    """``∫ c1 c2 dw`` for unit-scale lobes at ``angle`` apart, by the separated 1-D quadrature.

    Exact up to the tanh-sinh rule on the lune (relative error ~1e-14 with the default nodes
    for exponents up to 1e5; computed in float64 and cast back). This is the product's true
    integral, the reference that the product table approximates.

    Parameters
    ----------
    e1, e2 : (...) exponents >= 0;  angle : (...) radians in ``[0, pi]`` (broadcast)
    nodes : the rule has ``2 (2 nodes + 1)`` points per product

    Returns
    -------
    (...)
    """
    e1 = as_float(e1)
    e2, angle = as_float(e2, like=e1), as_float(angle, like=e1)
    _check_exponent(e1, "e1")
    _check_exponent(e2, "e2")
    shape = torch.broadcast_shapes(e1.shape, e2.shape, angle.shape)
    a, b, al = (t.double().expand(shape).reshape(-1) for t in (e1, e2, angle))
    if not bool(torch.all((al >= 0) & (al <= math.pi))):
        raise InputError("angle", "must lie in [0, pi]")
    log_peak, g, _, w, _ = _lune_nodes(a, b, al, nodes=nodes)
    lune = (w * torch.exp(g)).sum(-1)
    out = torch.exp(log_peak + _log_sin_power_integral(a + b + 1)) * lune
    out = torch.where(al >= math.pi, 0.0, out)  # the lune is empty
    return out.reshape(shape).to(e1.dtype)
