"""The fitting objective of Green et al. 2006, eq. (6): ``alpha D + beta M + gamma V + delta S``.

For one vertex, all J views and N Gaussians per view ``(w_k, mu_k, sigma_k)``:

``D`` (eq. 7)  data term: the L2 distance between the mixture and the transport, integrated
    with the sample set's quadrature weights and summed over views and channels. We divide it by
    the vertex's transport energy ``sum_v int |T_v|^2``, so ``D`` is a squared relative error and
    the weights ``beta, gamma, delta`` mean the same on dim and bright vertices.
``M`` (eq. 8)  mean alignment: ``sum_v sum_k |avg_{r(v)} mu_k^r - mu_k^v|^2`` over the views'
    geodesic neighbours ``r(v)``; it fills the means of views with no data (below the horizon,
    fully occluded) and keeps corresponding Gaussians corresponding across views.
``V`` (eq. 9)  the same for ``sigma = 1/sqrt(lam)``, measured relative to the neighbours'
    average ``((avg sigma - sigma) / avg sigma)^2``: scale-free like our ``D``, so one ``gamma``
    serves lobes of width 0.01 and 0.7 rad (in radians^2 the term vanishes for sharp lobes).
``S`` (eq. 10) spatial arrangement against already-processed neighbouring vertices ``s``:
    ``sum_{k1<k2} sum_s max(-<dmu_x, dmu_s>, 0)^3`` with ``dmu = mu_k1 - mu_k2``. The i3D text cubes
    the dot product; the squared form of the report cannot be negative and would penalise
    consistent arrangements too, so the cube it is.

``M``, ``V`` and ``S`` are averaged over views (not summed) so that their weights do not depend
on how many views a vertex has.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from .._tol import DIVISOR_F32, DIVISOR_F64, SHARPNESS_MIN
from ..lobes import sg
from ._data import FitData

__all__ = [
    "Weights",
    "data_term",
    "flip_count",
    "flipped_views",
    "mean_term",
    "sigma_term",
    "spatial_term",
]


@dataclass(frozen=True)
class Weights:
    """Weights of the four terms (``alpha`` on the data term, relative error squared).

    The defaults keep the alignment terms an order of magnitude below a good fit's data error
    on smooth transport (tests/test_fit.py: two lobes recovered to 3 % in sharpness), while
    still filling views without data; raise ``beta, gamma`` for noisy transport.
    """

    alpha: float = 1.0
    beta: float = 0.01
    gamma: float = 0.01
    delta: float = 0.05


def unit64(x: torch.Tensor) -> torch.Tensor:
    """``x`` (..., 3) as float64 unit vectors (float32 directions are unit to 6e-8 only)."""
    return torch.nn.functional.normalize(x.double(), dim=-1)


def gaussians_at(
    dirs: torch.Tensor, mu: torch.Tensor, lam: torch.Tensor, *, unit: torch.Tensor | None = None
) -> torch.Tensor:
    """``G_k(omega_s)`` of N Gaussians per (vertex, view) at its samples, (B, J, N, S) in
    ``dirs``' dtype, for ``dirs`` (B, J, S, 3), ``mu`` (B, J, N, 3), ``lam`` (B, J, N);
    ``unit``: ``unit64(dirs)`` where the caller has it (:meth:`lobelight.fit.FitData.unit_dirs`).

    The exponent ``lam (mu.w - 1)`` is formed as ``(lam mu).w - lam`` in one float64 batched
    matmul of the directions renormalised in float64 (its rounding is ``lam`` times 1e-16,
    where float32, or float32 vectors' norms off 1 by 6e-8, would lose a sharp lobe's
    ``1 - mu.w``), then exponentiated in float32; the same values as
    :func:`lobelight.lobes.sg.evaluate` up to rounding, without its per-call checks and its
    (B, J, N, S, 3) differences.
    """
    b, j, s, _ = dirs.shape
    n = mu.shape[2]
    lam64 = lam.double().reshape(b * j, n, 1)
    a = lam64 * unit64(mu).reshape(b * j, n, 3)
    unit = unit64(dirs) if unit is None else unit
    ex = torch.baddbmm(-lam64, a, unit.reshape(b * j, s, 3).transpose(1, 2))
    return torch.exp(ex.to(dirs.dtype)).reshape(b, j, n, s)


def mixture(data: FitData, w: torch.Tensor, mu: torch.Tensor, lam: torch.Tensor) -> torch.Tensor:
    """The mixture at the sample directions, (B, J, S, 3).

    Parameters
    ----------
    w : (B, J, N, 3);  mu : (B, J, N, 3);  lam : (B, J, N)
    """
    g = gaussians_at(data.dirs, mu, lam, unit=data.unit_dirs())  # (B, J, N, S)
    return torch.einsum("bjns,bjnc->bjsc", g, w)


def solve_weights(
    data: FitData,
    mu: torch.Tensor,
    lam: torch.Tensor,
    *,
    ridge: float = 1e-9,
    g: torch.Tensor | None = None,
    conserve: bool = True,
) -> torch.Tensor:
    """Least-squares RGB weights given means and sharpness (variable projection), ``(B, J, N, 3)``.

    ``A w = b`` with ``A_kl = int G_k G_l`` and ``b_k = int G_k T`` under the sample quadrature,
    with ``conserve`` under the constraint that the Gaussians carry the data's light per
    channel (:func:`solve_gram`); views below the horizon get 0.
    """
    if g is None:  # (B, J, N, S); callers that have it pass it
        g = gaussians_at(data.dirs, mu, lam, unit=data.unit_dirs())
    gw = g * data.weights[:, :, None]
    a = torch.einsum("bjks,bjls->bjkl", gw, g)  # (B, J, N, N)
    rhs = torch.einsum("bjks,bjsc->bjkc", gw, data.values)  # (B, J, N, 3)
    return solve_gram(a, rhs, lam, data.below, light_of(data), ridge=ridge, conserve=conserve)


def light_of(data: FitData) -> torch.Tensor:
    """``int max(T, 0)`` per vertex, view and channel, (B, J, 3): the light of
    :func:`solve_gram` (:meth:`FitData.light`)."""
    return data.light()


def conserve_factor(lam: torch.Tensor) -> torch.Tensor:
    """``-d ln Z / d ln lam = 1 - 2 lam / (exp(2 lam) - 1)`` for ``Z`` the SG integral, (...).

    With a lobe's carried light ``w Z(lam)`` held, ``d w / d ln lam`` is ``w`` times this: the
    term a width step adds to the Jacobian of the constrained fit (:mod:`._lm`). 1 for sharp
    lobes (``Z ~ 2 pi / lam``), 0 at ``lam = 0``.
    """
    x = 2 * lam
    small = x < 1e-6
    safe = torch.where(small, torch.ones_like(x), x)
    return torch.where(small, x / 2, 1 - safe / torch.expm1(safe))


def solve_gram(
    a: torch.Tensor,
    rhs: torch.Tensor,
    lam: torch.Tensor,
    below: torch.Tensor,
    light: torch.Tensor,
    *,
    ridge: float = 1e-9,
    conserve: bool = True,
) -> torch.Tensor:
    """The weights of :func:`solve_weights` from its normal equations.

    ``conserve``: the least-squares weights under the constraint ``sum_k w_kc Z(lam_k) =
    light_c``, the lobes' exact integrals (Lagrange: ``w = A^-1 (b - nu Z)``, ``nu`` per
    channel), negative ones clamped to 0 and the rest scaled to the light again. The rendered
    light ``w Z`` is then the data's. Constraining each lobe's integral under the sample
    quadrature instead, ``sum_s W_s G_k``, would leave the L2 optimum of data a mixture
    represents exactly untouched by the quadrature's error, but where the samples do not
    resolve a lobe (a round Gaussian over a grazing view's sliver of samples) its rendered
    light strays.

    Why the constraint: the transport's L2 optimum follows its peak, and a long-tailed lobe
    (GGX, Beckmann; visibility cuts) carries much of its light in tails one Gaussian does not:
    the unconstrained fit keeps only part of a GGX metal's light (docs/method.md), which a
    renderer integrating each lobe shows as a darker object. The constrained fit trades peak
    height for width and keeps every function's integral, which is what a lobe contributes
    under smooth lighting.

    Without ``conserve``: the plain least-squares weights, clamped at 0. Either way no lobe may
    carry more than twice the data's light (a lobe far sharper than the samples around it has a
    tiny ``<G, G>`` and quadrature integral, and would get an unbounded weight that still fits
    the samples).

    Parameters
    ----------
    a : (B, J, N, N) ``int G_k G_l``;  rhs : (B, J, N, 3) ``int G_k T``;  lam : (B, J, N)
    below : (B, J) views below the horizon;  light : (B, J, 3) from :func:`light_of`

    Returns
    -------
    (B, J, N, 3) in ``rhs``'s dtype
    """
    n = a.shape[-1]
    # float64 for the N x N solve: two coincident lobes make the system singular up to the
    # ridge, which float32 cannot represent next to the diagonal
    a64 = a.double()
    eye = torch.eye(n, dtype=a64.dtype, device=a.device)
    scale = a64.diagonal(dim1=-2, dim2=-1).mean(-1)[..., None, None]  # (B, J, 1, 1)
    # views below the horizon, and lobes that sit where no sample is (all G underflow), get
    # weight 0 from an identity system: solving the singular one would poison the gradients
    bad = below[..., None, None] | (scale < DIVISOR_F32)
    a64 = torch.where(bad, eye, a64 + ridge * scale * eye)
    rhs64 = torch.where(bad, torch.zeros_like(rhs), rhs).double()
    exact = sg.integral(lam.double())  # (B, J, N)
    cap = 2 * light[:, :, None].double() / exact[..., None]
    if not conserve:
        w = torch.linalg.solve(a64, rhs64).clamp_min(0)
        return torch.minimum(w, cap).to(rhs.dtype)
    z = exact
    lit = torch.where(bad[..., 0], torch.zeros_like(light), light).double()  # (B, J, 3)
    sol = torch.linalg.solve(a64, torch.cat([rhs64, z[..., None]], -1))  # (B, J, N, 4)
    ab, az = sol[..., :3], sol[..., 3:]  # A^-1 b, A^-1 Z
    zaz = (z[..., None] * az).sum(-2)  # (B, J, 1), > 0 (A is positive definite)
    nu = ((z[..., None] * ab).sum(-2) - lit) / zaz.clamp_min(DIVISOR_F64)  # (B, J, 3)
    w = (ab - az * nu[:, :, None]).clamp_min(0)
    carried = (z[..., None] * w).sum(-2)  # (B, J, 3)
    # every weight clamped (rare, N > 1): the light goes to the lobe the data favours most
    first = torch.nn.functional.one_hot(ab.argmax(-2), n).transpose(-1, -2).to(w.dtype)
    w = torch.where(carried[:, :, None] > 0, w, first / z[..., None])
    carried = (z[..., None] * w).sum(-2)
    w = w * (lit / carried.clamp_min(DIVISOR_F64))[:, :, None]
    return torch.minimum(w, cap).to(rhs.dtype)


def data_term(data: FitData, w, mu, lam) -> torch.Tensor:
    """``D`` per vertex, (B,): the relative L2 error squared over all views."""
    r = mixture(data, w, mu, lam) - data.values  # (B, J, S, 3)
    err = (data.weights[..., None] * r * r).sum((1, 2, 3))
    return err / data.energy().sum(1).clamp_min(DIVISOR_F32)


def _neighbour_matrix(nbr: torch.Tensor, dtype: torch.dtype) -> torch.Tensor:
    """The averaging matrix (J, J) of the views' neighbour table ``nbr`` (J, 6) (-1 padded):
    row ``v`` holds ``1 / R_v`` at each of its ``R_v`` neighbours."""
    j = nbr.shape[0]
    valid = nbr >= 0
    rows = torch.arange(j, device=nbr.device)[:, None].expand_as(nbr)[valid]
    m = torch.zeros(j, j, dtype=dtype, device=nbr.device)
    m.index_put_((rows, nbr[valid]), torch.ones_like(rows, dtype=dtype), accumulate=True)
    return m / valid.sum(1, keepdim=True).to(dtype)


def _neighbour_mean(
    x: torch.Tensor, nbr: torch.Tensor, matrix: torch.Tensor | None = None
) -> torch.Tensor:
    """Average of ``x`` (B, J, ...) over each view's neighbours ``nbr`` (J, 6) (-1 padded), as
    one product with their averaging matrix (:func:`_neighbour_matrix`, or ``matrix``)."""
    m = _neighbour_matrix(nbr, x.dtype) if matrix is None else matrix
    return across_views(m, x)


def across_views(m: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """``m`` (J, J) applied to the views' axis of ``x`` (B, J, ...): ``out[b, v] = sum_u m[v, u]
    x[b, u]``, as one matrix product with every vertex's views side by side (a product per
    vertex, as broadcasting would make it, is several times slower on the CPU)."""
    b, j, rest = x.shape[0], x.shape[1], math.prod(x.shape[2:])
    cols = x.reshape(b, j, rest).transpose(0, 1).reshape(j, b * rest)
    return (m @ cols).reshape(j, b, rest).transpose(0, 1).reshape(x.shape)


def mean_term(mu: torch.Tensor, nbr: torch.Tensor) -> torch.Tensor:
    """``M`` per vertex, (B,): mean over views of ``sum_k |avg_r mu_k^r - mu_k^v|^2``.

    The neighbours' average is renormalised to a unit vector before the difference: the plain
    average of unit vectors is shorter than 1 by half their spread, which would pull every
    mean by a constant amount that has nothing to do with smoothness.
    """
    d = torch.nn.functional.normalize(_neighbour_mean(mu, nbr), dim=-1) - mu  # (B, J, N, 3)
    return (d * d).sum((-1, -2)).mean(1)


def sigma_term(lam: torch.Tensor, nbr: torch.Tensor) -> torch.Tensor:
    """``V`` per vertex, (B,): the same for ``sigma = 1 / sqrt(lam)``, relative."""
    sigma = lam.clamp_min(SHARPNESS_MIN).rsqrt()  # (B, J, N)
    avg = _neighbour_mean(sigma, nbr)
    d = (avg - sigma) / avg
    return (d * d).sum(-1).mean(1)


def _pair_diffs(mu: torch.Tensor) -> torch.Tensor:
    """``mu_k1 - mu_k2`` for all pairs ``k1 < k2``: (..., P, 3)."""
    n = mu.shape[-2]
    i, j = torch.triu_indices(n, n, offset=1, device=mu.device)
    return mu[..., i, :] - mu[..., j, :]


def spatial_term(mu: torch.Tensor, nbr_mu: torch.Tensor, nbr_mask: torch.Tensor) -> torch.Tensor:
    """``S`` per vertex, (B,), against processed neighbours.

    Parameters
    ----------
    mu : (B, J, N, 3);  nbr_mu : (B, Q, J, N, 3) means of up to Q processed neighbours
    nbr_mask : (B, Q) which neighbour slots are real
    """
    if mu.shape[-2] < 2 or nbr_mu.shape[1] == 0:
        return mu.new_zeros(mu.shape[0])
    dx = _pair_diffs(mu)[:, None]  # (B, 1, J, P, 3)
    ds = _pair_diffs(nbr_mu)  # (B, Q, J, P, 3)
    dot = (dx * ds).sum(-1)  # (B, Q, J, P)
    pen = (-dot).clamp_min(0) ** 3
    pen = pen * nbr_mask[:, :, None, None].to(pen.dtype)
    return pen.sum((1, 3)).mean(1)


def flip_count(
    mu_a: torch.Tensor,
    mu_b: torch.Tensor,
    active: torch.Tensor,
    live_a: torch.Tensor | None = None,
    live_b: torch.Tensor | None = None,
    pair_ok: torch.Tensor | None = None,
) -> torch.Tensor:
    """Flipped Gaussian pairs between two vertices' fits: views where some pair's difference
    vectors point against each other (``<dmu_a, dmu_b> < 0``), counted over ``active`` views.

    A pair has an arrangement only where both its Gaussians carry light at both vertices: a
    Gaussian of zero weight sits wherever the fit left it, and counting it would make about half
    of all views "flipped" by chance. ``live_*`` say which Gaussians carry light (default all).

    Parameters
    ----------
    mu_a, mu_b : (E, J, N, 3);  active : (E, J) bool (e.g. both views above the horizon)
    live_a, live_b : optional (E, J, N) bool
    pair_ok : optional (E, J, P) bool, which pairs ``k1 < k2`` to count at all

    Returns
    -------
    (E,) int64 number of flipped views per vertex pair
    """
    if mu_a.shape[-2] < 2:
        return torch.zeros(mu_a.shape[0], dtype=torch.int64, device=mu_a.device)
    return (flipped_views(mu_a, mu_b, live_a, live_b, pair_ok) & active).sum(-1)


def flipped_views(
    mu_a: torch.Tensor,
    mu_b: torch.Tensor,
    live_a: torch.Tensor | None = None,
    live_b: torch.Tensor | None = None,
    pair_ok: torch.Tensor | None = None,
) -> torch.Tensor:
    """Which views are flipped between two fits, (..., J) bool: the test of :func:`flip_count`
    per view, for any broadcastable leading shapes of ``mu_*`` (..., J, N, 3), ``live_*``
    (..., J, N) and ``pair_ok`` (..., J, P)."""
    flipped = (_pair_diffs(mu_a) * _pair_diffs(mu_b)).sum(-1) < 0  # (..., J, P)
    if live_a is not None and live_b is not None:
        live = live_a & live_b  # (..., J, N)
        n = live.shape[-1]
        i, j = torch.triu_indices(n, n, offset=1, device=live.device)
        flipped = flipped & live[..., i] & live[..., j]
    if pair_ok is not None:
        flipped = flipped & pair_ok
    return flipped.any(-1)
