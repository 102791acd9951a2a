"""The scene-independent tables of the cosine-lobes paper: lobe product and spherical cap.

Product table (paper section 4.1)
    The product of two unit-scale lobes at angle ``alpha`` apart is approximated by one lobe,
    ``c1 c2 ~ p_r max(a_r.w, 0)^(e_r)``. As in the paper, the axis ``a_r`` maximises ``c1 c2``
    and then ``(p_r, e_r)`` minimise the L2 distance over the sphere (its eq. 19). Here:

    * the axis is the closed-form root of a quadratic (:func:`~._lobe.product_peak`), exact,
      instead of a Nelder-Mead search, so it is computed at lookup time and not stored;
    * for a given ``e`` the best ``p`` is linear least squares, ``p = ∫ f g / ∫ g^2``, so the
      fit is a 1-D maximisation of ``(∫ f g)^2 / ∫ g^2`` over ``e`` (variable projection: the
      same minimiser as the paper's Levenberg-Marquardt on ``(p, e)``), solved for all entries at
      once by Newton's method on ``t = log(1 + e)`` with a bisection safeguard (4-6 steps),
      started from the Gaussian-limit answer ``e = sqrt(k_arc k_perp)``, the geometric mean of
      the product's two curvatures at its peak;
    * every integral is the closed-form ``theta`` factor times a 1-D tanh-sinh quadrature over
      the lune, on a window sized to the product's width (see :mod:`._lobe`), so exponents up
      to 1e5 and beyond are resolved.

    Stored per ``(e1, e2, alpha)``: ``q = p_r / peak`` (the partial scale divided by the exact
    peak value of ``c1 c2``; 1 for parallel axes), ``rho = log((e_r + 1)/(e1 + e2 + 1))`` (0 for
    parallel axes) and ``log(∫ c1 c2 / ∫ c_r)``, which lets a lookup return the lobe scaled to
    the product's exact integral instead (``preserve_integral``; the L2 fit misses the integral,
    most where one lobe fits the product badly). All three are
    smooth where ``p_r`` itself spans hundreds of decades, so linear interpolation works; the
    peak and the axis are exact at lookup.

    Grid. Exponents: uniform in ``u = log10(e + 0.1)`` with 16 nodes per unit (a decade above
    e ~ 1, the paper's 16 per decade), from ``e = 0`` (a node) to ``1e5`` (97 nodes); the 0.1
    offset keeps ``[0, 1]`` resolved (17 nodes) where the table is smooth in ``e`` rather than
    ``log e``. Angles (166 nodes): uniform in ``v(alpha) = alpha / h + 6 asinh((alpha - pi/2) /
    1e-3) + 2 asinh((alpha - pi) / 1e-2)`` with ``h = pi/55``: spacing ~pi/55 far from pi/2,
    graded down to 1.6e-4 rad at pi/2 and to 5e-3 rad at pi. Why: a sharp lobe (``e2 =
    1e4..1e5``, width ``1/sqrt(e2) ~ 0.003``) near the horizon of a broad one (``e1 < ~10``) is
    cut by that horizon, so the fitted lobe changes within a few widths of ``alpha = pi/2``,
    faster than a uniform grid of angles can interpolate; the graded nodes follow it.
    Towards pi the lune between the lobes closes and ``e_r`` grows like ``1 / (pi - alpha)^2``.
    The table is symmetric in ``(e1, e2)`` and stores one triangle: 4753 pairs x 166 angles x 3
    float32 = 9.5 MB. Exponents above ``1e5`` look up ``(e1, e2) * 1e5 / max(e1, e2)``: in the
    sharp limit ``q`` and ``rho`` depend on the ratio ``e1 : e2`` and the angle only (tested
    against direct fits up to 1e6).

    Accuracy (``tests/test_cosine_tables.py`` bounds it; products uniform in these table
    coordinates, unit scales): lookups follow the direct fits closely; against the exact
    product, the paper's measure ``|∫ c1 c2 - ∫ c_r|`` is the L2 fit's own error (the same as
    the direct fit's; the paper reports 7.1e-4 on average), and far smaller with
    ``preserve_integral``. The worst lookups are products of two near-hemispheres (both
    exponents below 0.1), whose peak, the paper's axis, jumps with ``e1 / e2`` while ``c1 c2``
    is nearly flat.

Spherical-cap table (paper section 5.2)
    The cap of angular radius ``theta`` is represented by the unit-scale lobe (eq. 34) whose
    exponent minimises ``∫ (f_cap - max(h.w, 0)^e)^2`` (eq. 32). That L2 distance is closed
    form, ``2 pi [(1 - c) - 2 (1 - c^(e+1)) / (e + 1) + 1 / (2 e + 1)]`` with ``c = cos theta``,
    so each entry is a 1-D root solve. Stored: ``kappa = e (1 - cos theta)`` at 1000 angles
    uniform on ``[0, pi/2]`` (smooth, with the small-cap limit ``(1 + kappa) exp(-kappa) = 3/4``,
    ``kappa = 0.9613``); caps of ``theta >= pi/2`` get ``e = 0``. Note the paper's definition
    keeps the scale at 1, so the lobe's integral ``2 pi / (e + 1)`` differs from the cap's solid
    angle by -6.9 % (at 1.32 rad) to +4.0 % (``1/kappa - 1``, small caps), exactly 0 at pi/2.

No integral table: ``∫ max(a.w, 0)^e dw = 2 pi / (e + 1)`` exactly (:func:`~._lobe.integral`).

Cache. :func:`get_tables` keeps one ``.npz`` (no pickles) in :func:`lobelight._cache.cache_dir`
(``$LOBELIGHT_CACHE``, else the platform's user cache folder), holding a format version and
the grid parameters; it rebuilds the file when either differs, writes it atomically, and
reports a corrupt file as an :class:`~lobelight.errors.InputError` naming it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import time
import zipfile
import zlib
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch

from .. import _cache
from .._backend import as_float, dispatch
from .._checks import check_directions
from .._io import atomic_writer
from .._tol import DIVISOR_F32
from ..errors import InputError
from ._fused import kernel
from ._lobe import (
    _axis_pair,
    _check_exponent,
    _log_sin_power_integral,
    _lune_nodes,
    _peak,
)

__all__ = [
    "FORMAT_VERSION",
    "LobeTables",
    "TableParams",
    "build_tables",
    "cache_dir",
    "cap_exponent",
    "cpu_threads",
    "default_path",
    "fit_cap_exponent",
    "fit_product",
    "get_tables",
    "load_tables",
    "product",
    "save_tables",
]

#: Bumped whenever the meaning or layout of the stored arrays changes; a cached file of another
#: version is rebuilt by :func:`get_tables`.
FORMAT_VERSION = 1

_F64 = torch.float64
_LOG_2PI = math.log(2 * math.pi)
_HALF_PI = math.pi / 2


# --------------------------------------------------------------------------------------------
# grid parameters


@dataclasses.dataclass(frozen=True)
class TableParams:
    """Resolution of the tables (stored in the file; a different set means a rebuild).

    Attributes
    ----------
    per_decade : exponent nodes per unit of ``log10(e + e_offset)`` (the paper: 16 per decade)
    e_max : largest tabulated exponent (the paper: 1e5)
    e_offset : the exponent axis is uniform in ``log10(e + e_offset)``; ``e = 0`` is a node
    angle_uniform : angle nodes over ``[0, pi]`` that the grid would have without grading
    angle_grading : extra nodes per e-fold of distance from ``pi/2`` (0: uniform in angle)
    angle_width : radians within which the grading near ``pi/2`` saturates
    angle_pi_grading, angle_pi_width : the same towards ``alpha = pi`` (the lune closes)
    cap_nodes : entries of the spherical-cap table, uniform in the cap angle on ``[0, pi/2]``
    quad_nodes : tanh-sinh nodes ``n`` of each half-lune rule (``2 n + 1`` points)
    """

    per_decade: int = 16
    e_max: float = 1e5
    e_offset: float = 0.1
    angle_uniform: int = 56
    angle_grading: float = 6.0
    angle_width: float = 1e-3
    angle_pi_grading: float = 2.0
    angle_pi_width: float = 1e-2
    cap_nodes: int = 1000
    quad_nodes: int = 32

    def __post_init__(self) -> None:
        checks = {
            "per_decade": self.per_decade >= 1,
            "e_max": self.e_max > 1,
            "e_offset": self.e_offset > 0,
            "angle_uniform": self.angle_uniform >= 2,
            "angle_grading": self.angle_grading >= 0,
            "angle_width": self.angle_width > 0,
            "angle_pi_grading": self.angle_pi_grading >= 0,
            "angle_pi_width": self.angle_pi_width > 0,
            "cap_nodes": self.cap_nodes >= 2,
            "quad_nodes": self.quad_nodes >= 4,
        }
        for name, ok in checks.items():
            if not ok:
                raise InputError(name, f"invalid table parameter {getattr(self, name)!r}")

    # exponent axis: uniform in u = log10(e + e_offset)
    @property
    def _u_range(self) -> tuple[float, float]:
        return math.log10(self.e_offset), math.log10(self.e_max + self.e_offset)

    @property
    def n_exponent(self) -> int:
        u0, u1 = self._u_range
        return max(2, round((u1 - u0) * self.per_decade) + 1)

    def exponent_nodes(self, *, device: Any = None) -> torch.Tensor:
        """(n_exponent,) float64 exponents, ``0`` first and ``e_max`` last."""
        u0, u1 = self._u_range
        u = torch.linspace(u0, u1, self.n_exponent, dtype=_F64, device=device)
        e = (10**u - self.e_offset).clamp_min(0)
        e[0], e[-1] = 0.0, self.e_max
        return e

    # angle axis: uniform in v(alpha) = alpha / h + g1 asinh((alpha - pi/2) / w1)
    #                                              + g2 asinh((alpha - pi) / w2)
    def _angle_coord(self, alpha: torch.Tensor) -> torch.Tensor:
        h = math.pi / (self.angle_uniform - 1)
        return _angle_coordinate(
            alpha, h, self.angle_grading, self.angle_width, self.angle_pi_grading,
            self.angle_pi_width,
        )  # fmt: skip

    @property
    def _v_range(self) -> tuple[float, float]:
        ends = self._angle_coord(torch.tensor([0.0, math.pi], dtype=_F64))
        return float(ends[0]), float(ends[1])

    @property
    def n_angle(self) -> int:
        v0, v1 = self._v_range
        return math.ceil(v1 - v0 - 1e-9) + 1

    def angle_nodes(self, *, device: Any = None) -> torch.Tensor:
        """(n_angle,) float64 angles in ``[0, pi]`` (``v`` inverted by bisection)."""
        v0, v1 = self._v_range
        v = torch.linspace(v0, v1, self.n_angle, dtype=_F64)
        lo, hi = torch.zeros_like(v), torch.full_like(v, math.pi)
        for _ in range(64):  # v is increasing; 64 halvings of [0, pi] reach float64 rounding
            mid = (lo + hi) / 2
            below = self._angle_coord(mid) < v
            lo, hi = torch.where(below, mid, lo), torch.where(below, hi, mid)
        a = (lo + hi) / 2
        a[0], a[-1] = 0.0, math.pi
        return a.to(device)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


# --------------------------------------------------------------------------------------------
# direct fits (what the tables store)


def _psi_half_diff(x: torch.Tensor) -> torch.Tensor:
    """``digamma(x + 1/2) - digamma(x)``, without the cancellation of the direct difference at
    large ``x`` (asymptotic series for ``x >= 20``, truncation < 1e-13 relative)."""
    big = x >= 20
    xs = torch.where(big, x, 20.0)
    y = xs + 0.5
    asym = (
        torch.log1p(0.5 / xs)
        + 1 / (2 * xs * (2 * xs + 1))
        + (1 / xs**2 - 1 / y**2) / 12
        - (1 / xs**4 - 1 / y**4) / 120
        + (1 / xs**6 - 1 / y**6) / 252
    )
    xd = torch.where(big, 1.0, x)
    return torch.where(big, asym, torch.digamma(xd + 0.5) - torch.digamma(xd))


def _fit_chunk(e1, e2, alpha, *, nodes: int, iters: int = 60, tol: float = 1e-9):
    """L2 fit of ``(p_r, e_r)`` for float64 entries (m,) with ``alpha < pi``.

    Returns ``log_peak``, ``q = p_r / peak``, ``e_r``, the relative L2 error and
    ``log(∫ c1 c2 / peak)`` (all (m,)), and the number of entries that did not converge.
    """
    log_peak, g, ell, w, k_arc = _lune_nodes(e1, e2, alpha, nodes=nodes)
    tot = e1 + e2
    t = torch.log1p(torch.sqrt(k_arc * tot).nan_to_num(posinf=1e300))  # Gaussian-limit start
    t_lo, t_hi = torch.zeros_like(t), torch.full_like(t, math.inf)
    active = torch.arange(t.numel(), device=t.device)
    for _ in range(iters):
        ga, la, wa, ta, sa = g[active], ell[active], w[active], t[active], tot[active]
        e = torch.expm1(ta)
        h = wa * torch.exp(ga + e.unsqueeze(-1) * la)  # (a, nodes)
        hl = h * la
        m0, m1, m2 = h.sum(-1), hl.sum(-1), (hl * la).sum(-1)
        big = sa + e
        # d/de of psi(e) = 2 log ∫fg - log ∫g^2 and its second derivative
        d1 = -_psi_half_diff((big + 2) / 2) + 2 * m1 / m0 + 2 / (2 * e + 1)
        d2 = (
            0.5 * (torch.polygamma(1, (big + 2) / 2) - torch.polygamma(1, (big + 3) / 2))
            + 2 * (m2 / m0 - (m1 / m0) ** 2)
            - 4 / (2 * e + 1) ** 2
        )
        jac = e + 1  # de/dt
        dt1, dt2 = d1 * jac, d2 * jac * jac + d1 * jac
        lo = torch.where(d1 > 0, ta, t_lo[active])
        hi = torch.where(d1 > 0, t_hi[active], ta)
        newton = ta - dt1 / dt2
        ok = (dt2 < 0) & (newton >= lo) & (newton <= hi)
        bisect = torch.where(torch.isinf(hi), lo + 2, (lo + hi) / 2)
        tn = torch.where(ok, newton, bisect)
        tn = torch.where((d1 <= 0) & (ta <= 0), torch.zeros_like(tn), tn)  # optimum at e = 0
        done = ((tn - ta).abs() < tol) | ((hi - lo) < tol)
        t[active], t_lo[active], t_hi[active] = tn, lo, hi
        active = active[~done]
        if active.numel() == 0:
            break
    e = torch.expm1(t)
    m0 = (w * torch.exp(g + e.unsqueeze(-1) * ell)).sum(-1)
    log_fg = _log_sin_power_integral(tot + e + 1) + torch.log(m0)  # / peak
    log_q = log_fg + torch.log(2 * e + 1) - _LOG_2PI
    log_ff = _log_sin_power_integral(2 * tot + 1) + torch.log((w * torch.exp(2 * g)).sum(-1))
    rel2 = -torch.expm1(2 * log_fg - (_LOG_2PI - torch.log(2 * e + 1)) - log_ff)
    log_mass = _log_sin_power_integral(tot + 1) + torch.log((w * torch.exp(g)).sum(-1))
    return log_peak, torch.exp(log_q), e, rel2.clamp_min(0).sqrt(), log_mass, int(active.numel())


def _default_chunk(device: torch.device) -> int:
    """Entries fitted at once: cache-sized on a CPU (far faster there than one big batch),
    large on a GPU (kernel launches, not memory, are the cost there)."""
    return 4096 if device.type == "cpu" else 1 << 17


def _fit_flat(e1, e2, alpha, *, nodes: int, chunk: int | None = None, progress=None):
    """:func:`_fit_chunk` over (m,) float64 entries in chunks. Entries at ``alpha = pi`` (empty
    lune) get ``q = 0``, ``e_r = e1 + e2``. ``progress(stage, done, total)`` after each chunk."""
    m = e1.numel()
    chunk = chunk or _default_chunk(e1.device)
    out = [torch.empty(m, dtype=_F64, device=e1.device) for _ in range(5)]
    unconverged = 0
    for i in range(0, m, chunk):
        sl = slice(i, i + chunk)
        a = alpha[sl].clamp(max=math.pi)
        empty = a >= math.pi
        safe = torch.where(empty, torch.full_like(a, 1.0), a)
        lp, q, e, rel, mass, bad = _fit_chunk(e1[sl], e2[sl], safe, nodes=nodes)
        out[0][sl] = torch.where(empty, -math.inf, lp)
        out[1][sl] = torch.where(empty, 0.0, q)
        out[2][sl] = torch.where(empty, e1[sl] + e2[sl], e)
        out[3][sl] = torch.where(empty, 0.0, rel)
        out[4][sl] = torch.where(empty, -math.inf, mass)
        unconverged += bad
        if progress is not None:
            progress("lobe tables", min(i + chunk, m), m)
    return (*out, unconverged)


@dispatch
def fit_product(e1, e2, angle, /, *, nodes: int = 32):
    """Direct fit of the product lobe, the paper's eqs. 17-19, with no table.

    ``c1 c2 ~ scale * max(a_r . w, 0)^exponent`` for unit-scale lobes ``angle`` apart; the axis
    ``a_r`` is at ``beta`` from ``a1`` towards ``a2``. See the module docstring for the method.

    Parameters
    ----------
    e1, e2 : (...) exponents >= 0;  angle : (...) in ``[0, pi]`` (broadcast)
    nodes : tanh-sinh nodes per half-lune

    Returns
    -------
    beta : (...);  scale : (...) the partial scale ``p_r``;  exponent : (...) ``e_r``;
    rel_l2 : (...) ``||c1 c2 - c_r|| / ||c1 c2||`` over the sphere (0 where ``c1 c2 = 0``)
    """
    e1 = as_float(e1)
    e2, angle = as_float(e2, like=e1), as_float(angle, like=e1)
    _check_exponent(e1, "e1")
    _check_exponent(e2, "e2")
    shape = torch.broadcast_shapes(e1.shape, e2.shape, angle.shape)
    a, b, al = (x.to(_F64).expand(shape).reshape(-1) for x in (e1, e2, angle))
    if not bool(torch.all((al >= 0) & (al <= math.pi))):
        raise InputError("angle", "must lie in [0, pi]")
    log_peak, q, e, rel, _, _ = _fit_flat(a, b, al, nodes=nodes)
    c, s = torch.cos(al), torch.sin(al).clamp_min(0)
    cb, sb, _, _, _ = _peak(a, b, c, s)
    out = (torch.atan2(sb, cb), q * torch.exp(log_peak), e, rel)
    return tuple(x.reshape(shape).to(e1.dtype) for x in out)


# spherical cap


def _cap_equation(kappa: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
    """``(e+1)^2 / (4 pi) dJ/de`` for the cap fit, ``e = kappa / s``, ``s = 1 - cos(theta)``:
    ``1 - C + C (e+1) log(c) - ((e+1)/(2e+1))^2`` with ``C = c^(e+1)``. Negative below the
    optimum, positive above."""
    e = kappa / s
    log_c = torch.log1p(-s)
    big_c = torch.exp((e + 1) * log_c)
    return 1 - big_c + big_c * (e + 1) * log_c - ((e + 1) / (2 * e + 1)) ** 2


#: Floor of ``s = 1 - cos theta`` in :func:`_cap_kappa`: a cap narrower than about 1.4e-6 rad
#: is solved as one that wide (``e = kappa / s`` stays finite; its lobe is a spike either way).
_CAP_S_MIN = 1e-12
#: Lower end of the bisection's bracket of ``kappa`` in :func:`_cap_kappa` (the upper end is 4).
_CAP_KAPPA_LOW = 1e-30


def _cap_kappa(theta: torch.Tensor) -> torch.Tensor:
    """``kappa = e (1 - cos theta)`` of the L2-best cap lobe, float64 (m,), by bisection in
    ``log kappa`` (the equation is monotone; 200 halvings of [1e-30, 4] reach float64)."""
    s = (2 * torch.sin(theta.clamp(0, _HALF_PI) / 2) ** 2).clamp(_CAP_S_MIN, 1.0)
    lo = torch.full_like(s, math.log(_CAP_KAPPA_LOW))
    hi = torch.full_like(s, math.log(4.0))
    for _ in range(200):
        mid = (lo + hi) / 2
        below = _cap_equation(torch.exp(mid), s) < 0
        lo, hi = torch.where(below, mid, lo), torch.where(below, hi, mid)
    kappa = torch.exp((lo + hi) / 2)
    return torch.where(s >= 1.0, torch.zeros_like(kappa), kappa)  # theta = pi/2: e = 0


@dispatch
def fit_cap_exponent(theta, /):
    """Exponent of the unit-scale lobe closest in L2 to the cap of half-angle ``theta``.

    The paper's eq. 32-34, solved exactly (no table): ``theta >= pi/2`` gives 0, ``theta = 0``
    gives ``inf``.

    Parameters
    ----------
    theta : (...) cap half-angles in radians, >= 0

    Returns
    -------
    (...) exponents
    """
    theta = as_float(theta)
    if not bool(torch.all(theta >= 0)):
        raise InputError("theta", "cap angles must be >= 0")
    th = theta.to(_F64).reshape(-1)
    kappa = _cap_kappa(th)
    s = 2 * torch.sin(th.clamp(max=_HALF_PI) / 2) ** 2
    e = torch.where(th >= _HALF_PI, 0.0, kappa / s)
    return e.reshape(theta.shape).to(theta.dtype)


# --------------------------------------------------------------------------------------------
# the tables


@dataclasses.dataclass(frozen=True, eq=False)
class LobeTables:
    """The product and spherical-cap tables on one device, with trilinear lookup.

    Attributes
    ----------
    params : :class:`TableParams`
    product_table : (n_pairs, n_angle, 3) float32; ``[..., 0] = q = p_r / peak``,
        ``[..., 1] = rho = log((e_r + 1)/(e1 + e2 + 1))``, ``[..., 2] = log(∫ c1 c2 / ∫ c_r)``;
        pair ``(i, j)``, ``i <= j``, is row ``i n - i (i - 1)/2 + j - i`` (the upper triangle,
        row-major, ``n = n_exponent``)
    cap_table : (cap_nodes,) float32 ``kappa = e (1 - cos theta)`` at ``theta`` uniform on
        ``[0, pi/2]``
    info : build facts (seconds, fits, unconverged fits, torch version)
    """

    params: TableParams
    product_table: torch.Tensor
    cap_table: torch.Tensor
    info: dict = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        # the grid as Python numbers, once: a compiled lookup reads them as constants
        object.__setattr__(self, "_grid", _Grid.of(self.params))

    @property
    def device(self) -> torch.device:
        return self.product_table.device

    @property
    def nbytes(self) -> int:
        return sum(t.numel() * t.element_size() for t in (self.product_table, self.cap_table))

    @property
    def shapes(self) -> dict:
        p = self.params
        return {
            "product": [p.n_exponent, p.n_exponent, p.n_angle, 3],
            "product_stored": list(self.product_table.shape),
            "cap": list(self.cap_table.shape),
        }

    def to(self, device: Any) -> LobeTables:
        """The same tables on ``device`` (self when already there)."""
        device = torch.device(device)
        if device == self.device:
            return self
        return dataclasses.replace(
            self, product_table=self.product_table.to(device), cap_table=self.cap_table.to(device)
        )

    # ---- product

    def _product_cs(self, e1, e2, c, s, preserve_integral):
        """Lookup from ``cos``/``sin`` of the angle: ``(cos b, sin b, exponent, log p_r)``."""
        tab = self.product_table.to(e1.device)
        return _product_lookup(e1, e2, c, s, tab, self._grid, bool(preserve_integral))

    @dispatch
    def product(self, e1, e2, angle, /, *, preserve_integral: bool = False):
        """The product lobe of unit-scale lobes ``angle`` apart, from the table.

        Parameters
        ----------
        e1, e2 : (...) exponents >= 0;  angle : (...) in ``[0, pi]`` (broadcast)
        preserve_integral : scale the lobe so that its integral is the product's exact integral
            (also tabulated) instead of the paper's L2-best scale; the axis and exponent are
            the same. The L2 fit (default, the paper's) misses ``∫ c1 c2`` by a few percent on
            average; when a product is integrated next rather than multiplied again, this
            option removes that error up to interpolation.

        Returns
        -------
        beta : (...) axis angle from ``a1`` towards ``a2`` (exact, closed form)
        scale : (...) partial scale ``p_r`` (``q`` interpolated times the exact peak)
        exponent : (...) ``e_r``
        """
        e1 = as_float(e1)
        e2, angle = as_float(e2, like=e1), as_float(angle, like=e1)
        _check_exponent(e1, "e1")
        _check_exponent(e2, "e2")
        e1, e2, angle = torch.broadcast_tensors(e1, e2, angle)
        cb, sb, exponent, log_scale = self._product_cs(
            e1, e2, torch.cos(angle), torch.sin(angle).clamp_min(0), preserve_integral
        )
        return torch.atan2(sb, cb), torch.exp(log_scale), exponent

    @dispatch
    def product_lobes(
        self, axis1, e1, axis2, e2, /, scale1=None, scale2=None, *, preserve_integral=False
    ):
        """Multiply lobes given by axes: ``c1 c2 ~ scale * max(axis . w, 0)^exponent``.

        Parameters
        ----------
        axis1, axis2 : (..., 3) unit axes;  e1, e2 : (...) exponents >= 0 (broadcast)
        scale1, scale2 : optional (...) scales (default 1), broadcast
        preserve_integral : see :meth:`product`

        Returns
        -------
        axis : (..., 3) unit;  exponent : (...);  scale : (...)
        """
        axis1 = as_float(axis1)
        check_directions(axis1, "axis1")
        axis2 = as_float(axis2, like=axis1)
        check_directions(axis2, "axis2")
        e1, e2 = as_float(e1, like=axis1), as_float(e2, like=axis1)
        _check_exponent(e1, "e1")
        _check_exponent(e2, "e2")
        axis1, axis2 = torch.broadcast_tensors(axis1, axis2)
        c, s, tangent = _axis_pair(axis1, axis2)
        batch = torch.broadcast_shapes(c.shape, e1.shape, e2.shape)
        e1, e2, c, s = (x.expand(batch) for x in (e1, e2, c, s))
        cb, sb, exponent, log_scale = self._product_cs(e1, e2, c, s, preserve_integral)
        axis = cb.unsqueeze(-1) * axis1 + sb.unsqueeze(-1) * tangent  # (..., 3)
        scale = torch.exp(log_scale)
        for extra in (scale1, scale2):
            if extra is not None:
                scale = scale * as_float(extra, like=scale)
        return axis, exponent, scale

    # ---- spherical cap

    @dispatch
    def cap_exponent(self, theta, /):
        """Exponent of the lobe standing for a cap of half-angle ``theta`` (paper eq. 32-34).

        Linear interpolation of ``kappa`` in ``theta`` over the 1000-entry table, then
        ``e = kappa / (1 - cos theta)``: ``inf`` at ``theta = 0``, 0 from ``pi/2`` on.

        Parameters
        ----------
        theta : (...) radians >= 0

        Returns
        -------
        (...) exponents (the lobe's scale is 1: ``max(h.w, 0)^e``)
        """
        theta = as_float(theta)
        return _cap_lookup(theta, self.cap_table.to(theta.device))


@kernel
def _cap_lookup(theta: torch.Tensor, tab: torch.Tensor) -> torch.Tensor:
    """:meth:`LobeTables.cap_exponent` on a (cap_nodes,) ``kappa`` table."""
    n = tab.shape[0]
    f = (theta.clamp(0, _HALF_PI) * ((n - 1) / _HALF_PI)).clamp(0, n - 1)
    i = f.floor().clamp(max=n - 2)
    t = (f - i).to(tab.dtype)
    i = i.long()
    kappa = ((1 - t) * tab[i] + t * tab[i + 1]).to(theta.dtype)
    s = 2 * torch.sin(theta.clamp(0, _HALF_PI) / 2) ** 2  # 1 - cos, exact for small caps
    return torch.where(theta >= _HALF_PI, 0.0, kappa / s)


def _angle_coordinate(alpha, h: float, g1: float, w1: float, g2: float, w2: float):
    """The angle axis's coordinate ``alpha / h + g1 asinh((alpha - pi/2) / w1) + g2 asinh((alpha
    - pi) / w2)`` (:class:`TableParams`), on Python numbers so a compiled lookup can use it."""
    v = alpha / h + g1 * torch.asinh((alpha - _HALF_PI) / w1)
    return v + g2 * torch.asinh((alpha - math.pi) / w2)


class _Grid(NamedTuple):
    """The product table's grid as Python numbers (constants for a compiled lookup)."""

    n: int  # exponent nodes
    na: int  # angle nodes
    e_max: float
    e_offset: float
    u0: float  # log10(e_offset)
    du: float  # exponent-node spacing in u
    v0: float  # angle coordinate of alpha = 0
    v_scale: float  # angle nodes per unit of v
    h: float  # the ungraded angle spacing
    g1: float
    w1: float
    g2: float
    w2: float

    @classmethod
    def of(cls, p: TableParams) -> _Grid:
        u0, u1 = p._u_range
        v0, v1 = p._v_range
        n, na = p.n_exponent, p.n_angle
        return cls(
            n, na, float(p.e_max), float(p.e_offset), u0, (u1 - u0) / (n - 1), v0,
            (na - 1) / (v1 - v0), math.pi / (p.angle_uniform - 1), float(p.angle_grading),
            float(p.angle_width), float(p.angle_pi_grading), float(p.angle_pi_width),
        )  # fmt: skip


@kernel
def _product_lookup(e1, e2, c, s, tab: torch.Tensor, g: _Grid, preserve_integral: bool):
    """Trilinear lookup of the (upper-triangle) product table: ``(cos b, sin b, e_r, log p_r)``.

    e1, e2, c, s : (...) exponents and cos/sin of the angle between the axes;
    tab : (n_pairs, n_angle, 3) :attr:`LobeTables.product_table`
    """
    n, na = g.n, g.na
    cb, sb, _, _, log_peak = _peak(e1, e2, c, s)
    # normalised table coordinates; above e_max keep the ratio e1 : e2 (sharp limit)
    top = torch.maximum(e1, e2)
    k = torch.where(top > g.e_max, g.e_max / top.clamp_min(DIVISOR_F32), 1.0)
    f1 = ((torch.log10(e1 * k + g.e_offset) - g.u0) / g.du).clamp(0, n - 1)
    f2 = ((torch.log10(e2 * k + g.e_offset) - g.u0) / g.du).clamp(0, n - 1)
    f1, f2 = torch.minimum(f1, f2), torch.maximum(f1, f2)  # symmetric table: i <= j
    v = _angle_coordinate(torch.atan2(s, c), g.h, g.g1, g.w1, g.g2, g.w2)
    fa = ((v - g.v0) * g.v_scale).clamp(0, na - 1)
    i, j, m = (f.floor().clamp(max=top_ - 2) for f, top_ in ((f1, n), (f2, n), (fa, na)))
    ti, tj, tm = f1 - i, f2 - j, fa - m
    i, j, m = i.long(), j.long(), m.long()
    flat = tab.view(-1, 3)
    acc = torch.zeros((*e1.shape, 3), dtype=tab.dtype, device=tab.device)
    for di, wi in ((0, 1 - ti), (1, ti)):
        for dj, wj in ((0, 1 - tj), (1, tj)):
            a, b = i + di, j + dj
            lo, hi = torch.minimum(a, b), torch.maximum(a, b)
            row = (lo * n - lo * (lo - 1) // 2 + (hi - lo)) * na + m  # (...,) flat index
            wij = (wi * wj).to(tab.dtype)
            for dm, wm in ((0, 1 - tm), (1, tm)):
                acc = acc + (wij * wm.to(tab.dtype)).unsqueeze(-1) * flat[row + dm]
    acc = acc.to(e1.dtype)
    q, rho, ratio = acc.unbind(-1)
    exponent = (torch.exp(rho) * (e1 + e2 + 1) - 1).clamp_min(0)
    log_scale = torch.log(q.clamp_min(0)) + log_peak
    if preserve_integral:
        log_scale = log_scale + ratio
    return cb, sb, exponent, log_scale


@contextlib.contextmanager
def cpu_threads(n: int | None):
    """Run with ``n`` torch intra-op threads (process-wide), restoring the old count after."""
    old = torch.get_num_threads()
    if n is not None:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(old)


def build_tables(
    params: TableParams | None = None,
    *,
    device: Any = "cpu",
    chunk: int | None = None,
    threads: int | None = 1,
    progress=None,
) -> LobeTables:
    """Fit every table entry (float64, vectorised, in cache-sized chunks) on ``device``.

    Parameters
    ----------
    params : grid resolution (default :class:`TableParams`: 4753 x 160 product fits)
    device : where to fit (the tables are returned there)
    chunk : entries fitted at once (default 4096 on a CPU, 131072 on a GPU)
    threads : torch CPU threads during the build (``None``: leave as set). One by default: the
        build is thousands of small tensor operations, for which a second thread gains little
        on an idle machine and slows the build down when other processes keep the cores busy
        (docs/benchmarks.md).
    progress : optional ``progress(stage, done, total)`` after each chunk of product fits

    Returns
    -------
    :class:`LobeTables`
    """
    p = params or TableParams()
    dev = torch.device(device)
    with cpu_threads(threads if dev.type == "cpu" else None):
        return _build(p, dev, chunk, progress)


def _build(p: TableParams, dev: torch.device, chunk: int | None, progress=None) -> LobeTables:
    t0 = time.perf_counter()
    ex = p.exponent_nodes(device=dev)  # (n,)
    angles = p.angle_nodes(device=dev)  # (na,)
    n, na = p.n_exponent, p.n_angle
    r, c = torch.triu_indices(n, n, device=dev)  # (pairs,) row-major upper triangle
    pairs = r.numel()
    inner = angles[:-1]  # the last node is pi: empty lune, q = 0
    e1 = ex[r].repeat_interleave(na - 1)  # (pairs * (na - 1),) pair-major
    e2 = ex[c].repeat_interleave(na - 1)
    al = inner.repeat(pairs)
    _, q, e, _, mass, bad = _fit_flat(
        e1, e2, al, nodes=p.quad_nodes, chunk=chunk, progress=progress
    )
    rho = torch.log((e + 1) / (e1 + e2 + 1))
    # log(∫ c1 c2 / ∫ c_r), with ∫ c_r = peak q 2 pi / (e_r + 1)
    ratio = mass - torch.log(q) - _LOG_2PI + torch.log(e + 1)
    q, rho, ratio = (x.reshape(pairs, na - 1) for x in (q, rho, ratio))
    q = torch.cat([q, torch.zeros_like(q[:, :1])], 1)  # (pairs, na)
    # at pi the product is 0: e_r and the ratio are immaterial, continue them
    rho = torch.cat([rho, rho[:, -1:]], 1)
    ratio = torch.cat([ratio, ratio[:, -1:]], 1)
    t1 = time.perf_counter()
    theta = torch.linspace(0, _HALF_PI, p.cap_nodes, dtype=_F64, device=dev)
    kappa = _cap_kappa(theta)
    t2 = time.perf_counter()
    info = {
        "seconds": t2 - t0,
        "seconds_product": t1 - t0,
        "seconds_cap": t2 - t1,
        "product_fits": int(e1.numel()),
        "unconverged_fits": bad,
        "torch": torch.__version__,
        "device": str(dev),
    }
    return LobeTables(p, torch.stack([q, rho, ratio], -1).float(), kappa.float(), info)


# --------------------------------------------------------------------------------------------
# disk cache


def cache_dir() -> Path:
    """lobelight's cache folder, :func:`lobelight._cache.cache_dir` (``$LOBELIGHT_CACHE`` if set,
    else the platform's user cache folder)."""
    return _cache.cache_dir()


def default_path() -> Path:
    """Where :func:`get_tables` keeps the tables: ``cache_dir() / "cosine-tables.npz"``."""
    return cache_dir() / "cosine-tables.npz"


_KEYS = ("format_version", "params", "info", "product", "cap")


def save_tables(tables: LobeTables, path: str | os.PathLike) -> Path:
    """Write ``tables`` to ``path`` (``.npz``, no pickles), whole (:mod:`lobelight._io`)."""
    path = Path(path)
    arrays = {
        "format_version": np.array(FORMAT_VERSION, dtype=np.int64),
        "params": np.array(json.dumps(tables.params.to_dict(), sort_keys=True)),
        "info": np.array(json.dumps(tables.info, sort_keys=True)),
        "product": tables.product_table.detach().cpu().numpy().astype(np.float32),
        "cap": tables.cap_table.detach().cpu().numpy().astype(np.float32),
    }
    with atomic_writer(path) as f:
        np.savez(f, **arrays)
    return path


# what a damaged .npz raises from zipfile, zlib and numpy's .npy reader: a bad zip structure,
# an unknown compression method or flags (NotImplementedError, RuntimeError), corrupt deflate
# data, a short member, an impossible header (ValueError, MemoryError for absurd shapes)
_UNREADABLE = (
    OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zipfile.LargeZipFile,
    NotImplementedError, RuntimeError, zlib.error, MemoryError, OverflowError,
)  # fmt: skip


def _read(path: Path) -> dict[str, np.ndarray]:
    """All arrays of a tables file; any unreadable container is an InputError naming it."""
    try:
        z = np.load(path, allow_pickle=False)
        if not isinstance(z, np.lib.npyio.NpzFile):  # a bare .npy file loads as one array
            raise InputError(path, "not a lobe-table file (a single .npy array); delete it")
        with z:
            missing = [k for k in _KEYS if k not in z.files]
            if missing:
                raise InputError(path, f"corrupt lobe-table file: missing {missing}; delete it")
            arrays = {k: z[k] for k in _KEYS}
    except InputError:
        raise
    except _UNREADABLE as exc:
        raise InputError(path, f"corrupt lobe-table file ({exc!r}); delete it to rebuild") from exc
    for k, a in arrays.items():  # NpzFile hands back a member without the .npy magic as bytes
        if not isinstance(a, np.ndarray):
            raise InputError(path, f"corrupt lobe-table file: {k} is not an array; delete it")
    return arrays


def _header(arrays: dict[str, np.ndarray], path: Path) -> tuple[int, dict]:
    try:
        version = int(arrays["format_version"])
        params = json.loads(str(arrays["params"]))
        if not isinstance(params, dict):
            raise ValueError("params is not a JSON object")
    except (TypeError, ValueError, OverflowError) as exc:  # OverflowError: int(inf)
        raise InputError(path, f"corrupt lobe-table header ({exc}); delete it") from exc
    return version, params


def _from_arrays(arrays: dict[str, np.ndarray], params: dict, path: Path) -> LobeTables:
    try:
        p = TableParams(**params)
        info = json.loads(str(arrays["info"]))
        n = p.n_exponent  # grid sizes from the parameters: inf or NaN in them fail here
        want = (n * (n + 1) // 2, p.n_angle, 3)
    except (TypeError, ValueError, OverflowError) as exc:  # InputError is a ValueError
        raise InputError(path, f"corrupt lobe-table parameters ({exc}); delete it") from exc
    prod, cap = arrays["product"], arrays["cap"]
    if prod.dtype != np.float32 or prod.shape != want:
        raise InputError(path, f"corrupt lobe table: product {prod.shape}, expected {want}")
    if cap.dtype != np.float32 or cap.shape != (p.cap_nodes,):
        raise InputError(path, f"corrupt lobe table: cap {cap.shape}, expected {p.cap_nodes}")
    if not (np.isfinite(prod).all() and np.isfinite(cap).all()):
        raise InputError(path, "corrupt lobe table: non-finite entries; delete it")
    return LobeTables(p, torch.from_numpy(prod.copy()), torch.from_numpy(cap.copy()), info)


def load_tables(path: str | os.PathLike) -> LobeTables:
    """Read tables written by :func:`save_tables` (CPU tensors).

    Raises
    ------
    InputError
        naming ``path`` if it is missing, corrupt, or of another format version.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "no lobe-table file here")
    arrays = _read(path)
    version, params = _header(arrays, path)
    if version != FORMAT_VERSION:
        raise InputError(
            path, f"lobe tables of format version {version}, this lobelight reads {FORMAT_VERSION}"
        )
    return _from_arrays(arrays, params, path)


_MEMO: dict[tuple, LobeTables] = {}


def get_tables(
    *,
    path: str | os.PathLike | None = None,
    params: TableParams | None = None,
    device: Any = None,
    progress=None,
) -> LobeTables:
    """The tables, from memory, else from the disk cache, else built (and cached) now.

    A file of another format version or other :class:`TableParams` is rebuilt and replaced; a
    corrupt file raises :class:`~lobelight.errors.InputError` naming it (delete it to rebuild).

    Parameters
    ----------
    path : the ``.npz`` (default :func:`default_path`)
    params : grid resolution (default :class:`TableParams`)
    device : where the returned tensors live (default CPU)
    progress : optional ``progress(stage, done, total)`` while the tables are built
    """
    p = params or TableParams()
    path = Path(path) if path is not None else default_path()
    dev = torch.device(device if device is not None else "cpu")
    key = (str(path.resolve()), p, str(dev))
    if key in _MEMO:
        return _MEMO[key]
    tables = None
    if path.is_file():
        arrays = _read(path)
        version, stored = _header(arrays, path)
        if version == FORMAT_VERSION and stored == p.to_dict():
            tables = _from_arrays(arrays, stored, path)
    if tables is None:
        tables = build_tables(p, progress=progress)
        save_tables(tables, path)
    tables = tables.to(dev)
    _MEMO[key] = tables
    return tables


# --------------------------------------------------------------------------------------------
# module-level conveniences on the default tables


@dispatch
def product(
    axis1, e1, axis2, e2, /, scale1=None, scale2=None, *, preserve_integral=False, tables=None
):
    """Multiply two lobes with the (default, cached) product table.

    See :meth:`LobeTables.product_lobes`; ``tables`` defaults to :func:`get_tables` on the
    device of ``axis1``.

    Returns
    -------
    axis : (..., 3);  exponent : (...);  scale : (...)
    """
    axis1 = as_float(axis1)
    tables = tables if tables is not None else get_tables(device=axis1.device)
    return tables.product_lobes(
        axis1, e1, axis2, e2, scale1, scale2, preserve_integral=preserve_integral
    )


@dispatch
def cap_exponent(theta, /, *, tables=None):
    """Exponent of the lobe of a cap of half-angle ``theta``, from the (default) cap table.

    See :meth:`LobeTables.cap_exponent`.
    """
    theta = as_float(theta)
    tables = tables if tables is not None else get_tables(device=theta.device)
    return tables.cap_exponent(theta)
