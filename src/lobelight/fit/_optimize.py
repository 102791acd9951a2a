"""Fitting N spherical Gaussians per view to the transport of a batch of vertices, all views.

Unknowns per (vertex, view, Gaussian): an offset ``(a, b)`` on the tangent plane of the starting
mean ``mu0``, in units of the starting width ``sigma0``: ``mu = normalise(mu0 + sigma0 (a t + b
s))`` (unit means without constraints, and gradients of the same size for a lobe of sharpness 2
or 2e4 — in plain coordinates they scale with ``lam`` and break the line search), and ``z`` with
``lam = exp(z)``, kept in ``[lam_min, lam_max]`` by a quadratic penalty on ``z`` outside the
range (a saturating map such as a sigmoid leaves flat directions in which the line search
extrapolates without end) and a final clamp. The RGB weights are not unknowns: for given means
and sharpness the data term is quadratic in them, so they are solved exactly (and clamped at 0)
inside the objective — variable projection, which removes the worst-conditioned directions of
the problem. The batch's objective is the sum of its vertices' objectives (they are independent:
a wavefront of the flood fill), minimised by batched Levenberg-Marquardt (:mod:`._lm`) on any
torch device, or by Adam through autograd as an independent check. Both are local; the data
term does not see the order of a view's Gaussians, so :func:`relabel` then makes the discrete
moves of eq. (6) they cannot: reordering Gaussians where ``M``, ``V`` or ``S`` prefer it.

This replaces the paper's MATLAB ``fmincon`` on a 20-machine cluster.
"""

from __future__ import annotations

import itertools
import math

import torch

from .._tol import SHARPNESS_MIN, SMALL
from ..errors import InputError
from ..geometry import sphere
from ..lobes import sg
from ..lobes.sg import Gaussians
from ._data import FitData
from ._lm import levenberg_marquardt
from ._objective import (
    Weights,
    _neighbour_matrix,
    _neighbour_mean,
    _pair_diffs,
    across_views,
    data_term,
    gaussians_at,
    mean_term,
    sigma_term,
    solve_weights,
    spatial_term,
)

__all__ = ["Gaussians", "fit_batch", "initial_guess", "relabel"]

#: Default sharpness range (:data:`lobelight.lobes.sg.LAM_RANGE`).
LAM_RANGE = sg.LAM_RANGE
#: Levenberg-Marquardt iterations of :func:`initial_guess`'s joint refinement of the lobes so
#: far, before each further lobe is placed.
INIT_ITERATIONS = 8


def _moments(data: FitData, values: torch.Tensor, lam_range) -> tuple[torch.Tensor, torch.Tensor]:
    """Moment estimate of one Gaussian per view; views with no data take their vertex's
    average mean and median sharpness (the M and V terms refine them)."""
    b, j, s = data.shape
    mass = (data.weights[..., None] * values.clamp_min(0)).sum((-1, -2))
    empty = data.below | (mass <= 0)
    # moments of the views with data only (typically under half: the rest lie below the
    # horizon or are occluded), packed; the others are filled below
    act = (~empty).reshape(-1).nonzero().squeeze(1)
    m_a, l_a, _ = sg.fit_from_samples(
        data.dirs.reshape(b * j, s, 3)[act],
        values.reshape(b * j, s, -1)[act],
        data.weights.reshape(b * j, s)[act],
    )
    mu0 = m_a.new_zeros(b * j, 3).index_copy_(0, act, m_a).reshape(b, j, 3)
    lam0 = l_a.new_zeros(b * j).index_copy_(0, act, l_a).reshape(b, j)
    has = (~empty).to(mu0.dtype)[..., None]
    # a vertex without data in any view sums to a zero vector: SMALL makes it a direction
    avg = torch.nn.functional.normalize((mu0 * has).sum(1, keepdim=True) + SMALL, dim=-1)
    mu0 = torch.where(empty[..., None], avg.expand_as(mu0), mu0)
    lam_valid = torch.where(empty, torch.full_like(lam0, float("nan")), lam0)
    med = torch.nanmedian(lam_valid, dim=1, keepdim=True).values
    med = torch.where(torch.isnan(med), torch.full_like(med, 10.0), med)
    return mu0, torch.where(empty, med.expand_as(lam0), lam0).clamp(*lam_range)


def initial_guess(
    data: FitData,
    n: int,
    *,
    lam_range=LAM_RANGE,
    nbr_views: torch.Tensor | None = None,
    solve: bool = True,
    conserve: bool = True,
) -> Gaussians:
    """A starting point from the data alone.

    The first Gaussian is the moment estimate of the transport per view
    (:func:`lobelight.lobes.sg.fit_from_samples`, exact for a single SG). Each further Gaussian is
    the moment estimate of what the Gaussians so far leave unexplained (the squared positive
    residual),
    after a short joint refinement of those so far (greedy, then joint: a sharp highlight over a
    broad base separates into two lobes with their own means). ``nbr_views`` is needed for the
    refinement when ``n > 1``. ``solve=False`` leaves the weights at zero for a caller that
    solves them itself (the LM does, in its first evaluation).
    """
    mu, lam = _moments(data, data.values, lam_range)
    mus, lams = mu[:, :, None], lam[:, :, None]
    for _ in range(1, n):
        if nbr_views is not None:
            mus, lams = levenberg_marquardt(
                data,
                mus,
                lams,
                nbr_views,
                Weights(),
                lam_range=lam_range,
                iters=INIT_ITERATIONS,
                conserve=False,
            )
        # the greedy steps look for what the lobes so far leave unexplained: the plain L2
        # residual, where one lobe held to all the light would smear over the sharp and the
        # broad part alike
        w = solve_weights(data, mus, lams, conserve=False)
        g = gaussians_at(data.dirs, mus, lams, unit=data.unit_dirs())
        resid = (data.values - torch.einsum("bjns,bjnc->bjsc", g, w)).clamp_min(0)
        # moments of the squared residual: weighted by energy, not mass, so a small sharp peak
        # left over is found rather than the broad misfit around it; a Gaussian squared is
        # the Gaussian of twice the sharpness
        mu_k, lam_k = _moments(data, resid.pow(2).sum(-1, keepdim=True), lam_range)
        lam_k = (lam_k / 2).clamp(*lam_range)
        mus = torch.cat([mus, mu_k[:, :, None]], 2)
        lams = torch.cat([lams, lam_k[:, :, None]], 2)
    if nbr_views is not None:
        empty = data.below | (data.energy() <= 0)
        mus, lams = _fill_empty(mus, lams, empty, nbr_views)
    if not solve:
        return Gaussians(torch.zeros(*lams.shape, 3, dtype=mus.dtype, device=mus.device), mus, lams)
    return Gaussians(solve_weights(data, mus, lams, conserve=conserve), mus, lams)


def _fill_empty(mu, lam, empty, nbr, *, sweeps: int = 30):
    """Harmonic fill of views without data: repeated neighbour averages of the means and
    log-sharpness, on the empty views only. The M and V terms would get there too, but a few
    dozen Jacobi steps through the optimiser cost far more than these averages.
    """
    avg = _neighbour_matrix(nbr, mu.dtype)  # (J, J)
    e = empty[..., None]  # (B, J, 1)
    loglam = lam.log()
    for _ in range(sweeps):
        avg_mu = across_views(avg, mu)
        avg_ll = across_views(avg, loglam)
        mu = torch.where(e[..., None], torch.nn.functional.normalize(avg_mu, dim=-1), mu)
        loglam = torch.where(e, avg_ll, loglam)
    return mu, loglam.exp()


def _permuted(x: torch.Tensor, perm: torch.Tensor) -> torch.Tensor:
    """``x`` (B, J, N, ...) with its Gaussians reordered by ``perm`` (B, J, N) indices."""
    idx = perm.reshape(*perm.shape, *([1] * (x.ndim - 3))).expand_as(x)
    return torch.gather(x, 2, idx)


def _spatial_per_view(mu, nbr_mu, nbr_mask) -> torch.Tensor:
    """``S`` of each view before the average over views, (B, J)."""
    dot = (_pair_diffs(mu)[:, None] * _pair_diffs(nbr_mu)).sum(-1)  # (B, Q, J, P)
    pen = (-dot).clamp_min(0) ** 3 * nbr_mask[:, :, None, None].to(mu.dtype)
    return pen.sum((1, 3))


def _swap_gain(
    g: Gaussians, perm: torch.Tensor, nbr_views, weights: Weights, nbr_mu, nbr_mask
) -> torch.Tensor:
    """How much eq. (6) drops when view ``v`` alone reorders its Gaussians by ``perm`` (N,),
    every other view held: (B, J). ``D`` is invariant; ``M`` and ``V`` change in the view's own
    term and in its neighbours' terms, through their averages; ``S`` in the view's own term."""
    mu, sigma = g.mu, g.lam.clamp_min(SHARPNESS_MIN).rsqrt()  # (B, J, N, 3), (B, J, N)
    j = mu.shape[1]
    nb = nbr_views.clamp_min(0)  # (J, 6)
    valid = (nbr_views >= 0).to(mu.dtype)
    count = valid.sum(1)  # (J,)
    mu_p, sigma_p = mu[:, :, perm], sigma[:, :, perm]
    # M: own term with the neighbours' average held, plus each neighbour u's term through its
    # average, which holds mu_v / R_u
    avg = _neighbour_mean(mu, nbr_views)  # (B, J, N, 3)
    mbar = torch.nn.functional.normalize(avg, dim=-1)
    own = ((mbar - mu_p) ** 2).sum((-1, -2)) - ((mbar - mu) ** 2).sum((-1, -2))  # (B, J)
    shift = (mu_p - mu)[:, :, None] / count[nb][None, :, :, None, None]  # (B, J, 6, N, 3)
    avg_u, mu_u = avg[:, nb], mu[:, nb]  # (B, J, 6, N, 3)
    new_u = torch.nn.functional.normalize(avg_u + shift, dim=-1)
    old_u = torch.nn.functional.normalize(avg_u, dim=-1)
    nbr_m = ((new_u - mu_u) ** 2).sum((-1, -2)) - ((old_u - mu_u) ** 2).sum((-1, -2))
    d_m = own + (nbr_m * valid).sum(-1)

    def rel2(avg_s: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        return (((avg_s - x) / avg_s) ** 2).sum(-1)

    # V: the same for sigma, relative to the neighbours' average
    sbar = _neighbour_mean(sigma, nbr_views)  # (B, J, N)
    own = rel2(sbar, sigma_p) - rel2(sbar, sigma)
    sbar_u, sigma_u = sbar[:, nb], sigma[:, nb]  # (B, J, 6, N)
    new_s = sbar_u + (sigma_p - sigma)[:, :, None] / count[nb][None, :, :, None]
    d_v = own + ((rel2(new_s, sigma_u) - rel2(sbar_u, sigma_u)) * valid).sum(-1)
    delta = weights.beta * d_m + weights.gamma * d_v
    if nbr_mu is not None and nbr_mask is not None and weights.delta > 0:
        d_s = _spatial_per_view(mu_p, nbr_mu, nbr_mask) - _spatial_per_view(mu, nbr_mu, nbr_mask)
        delta = delta + weights.delta * d_s
    return -delta / j


def _order_cost(g: Gaussians, nbr_views, weights: Weights, nbr_mu, nbr_mask) -> torch.Tensor:
    """The part of eq. (6) that depends on the order of the Gaussians, per vertex (B,)."""
    cost = weights.beta * mean_term(g.mu, nbr_views) + weights.gamma * sigma_term(g.lam, nbr_views)
    if nbr_mu is not None and nbr_mask is not None and weights.delta > 0:
        cost = cost + weights.delta * spatial_term(g.mu, nbr_mu, nbr_mask)
    return cost


def relabel(
    g: Gaussians,
    nbr_views: torch.Tensor,
    *,
    weights: Weights | None = None,
    nbr_mu: torch.Tensor | None = None,
    nbr_mask: torch.Tensor | None = None,
    sweeps: int = 16,
) -> Gaussians:
    """Reorder each vertex's Gaussians where that lowers eq. (6): moves a local optimiser
    cannot make.

    The data term does not see the order of the N Gaussians (any permutation fits equally),
    while ``M``, ``V`` and ``S`` do. Changing the order by moving means continuously would take
    two lobes through each other, across the data term's barrier, so the optimiser keeps the
    order it was started with or, where a lobe lies several of its widths from where the start
    put it (a neighbour's fit on a curved or finely detailed surface), the order the data
    happens to lead it to, view by view: a lobe handed from one Gaussian to the other in some
    views only ("Gaussian flipping"). Two exact steps, each applied only where it lowers the
    objective:

    1. per vertex, the permutation of all its views at once that minimises ``S`` against the
       processed neighbours (``D``, ``M`` and ``V`` do not change under it);
    2. per view, the permutation that lowers ``beta M + gamma V + delta S`` the most with the
       other views held (``M`` and ``V`` through the view's own term and its neighbours'
       averages), applied at once to the views whose gain is the largest among their
       neighbouring views, in sweeps until no vertex gains.

    Parameters
    ----------
    g : Gaussians (B, J, N);  nbr_views : (J, 6) geodesic neighbour table (-1 padded)
    nbr_mu, nbr_mask : processed neighbours' means (B, Q, J, N, 3) and slots (B, Q), for ``S``
    sweeps : at most this many sweeps of step 2

    Returns
    -------
    Gaussians: per view, the same lobes, perhaps in another order
    """
    weights = Weights() if weights is None else weights
    b, j, n = g.lam.shape
    if n < 2:
        return g
    dev = g.mu.device
    perms = torch.tensor(list(itertools.permutations(range(n))), device=dev)  # (P, N), id first
    ident = torch.arange(n, device=dev)

    def apply(x: Gaussians, perm: torch.Tensor) -> Gaussians:  # perm (B, J, N)
        return Gaussians(_permuted(x.w, perm), _permuted(x.mu, perm), _permuted(x.lam, perm))

    if weights.delta > 0 and nbr_mu is not None and nbr_mask is not None:
        s = torch.stack([spatial_term(g.mu[:, :, p], nbr_mu, nbr_mask) for p in perms])  # (P, B)
        best = torch.where(s.min(0).values < s[0], s.argmin(0), 0)  # N! <= 6 orders looped
        g = apply(g, perms[best][:, None].expand(b, j, n))
    nb, valid = nbr_views.clamp_min(0), nbr_views >= 0
    ids = torch.arange(j, device=dev)
    cost = _order_cost(g, nbr_views, weights, nbr_mu, nbr_mask)
    for _ in range(sweeps):
        gains = torch.stack(
            [_swap_gain(g, p, nbr_views, weights, nbr_mu, nbr_mask) for p in perms[1:]]
        )  # (P - 1, B, J)
        gain, which = gains.max(0)
        want = gain > 0
        # a view moves if no neighbouring view that also wants to move gains more (ties: the
        # lower index moves), so the gains, each computed with the others held, add up
        rank = torch.where(want, gain, torch.full_like(gain, -1.0))
        other = rank[:, nb]  # (B, J, 6)
        beats = (other > rank[..., None]) | ((other == rank[..., None]) & (nb < ids[:, None]))
        move = want & ~(beats & valid).any(-1)
        cand = apply(g, torch.where(move[..., None], perms[1:][which], ident))
        new_cost = _order_cost(cand, nbr_views, weights, nbr_mu, nbr_mask)
        better = new_cost < cost  # (B,): a sweep that does not lower the objective is undone
        if not bool(better.any()):
            break
        g = Gaussians(
            torch.where(better[:, None, None, None], cand.w, g.w),
            torch.where(better[:, None, None, None], cand.mu, g.mu),
            torch.where(better[:, None, None], cand.lam, g.lam),
        )
        cost = torch.where(better, new_cost, cost)
    return g


class _Params:
    """The unconstrained parametrisation around a starting point (module docstring)."""

    def __init__(self, g: Gaussians, lam_range):
        self.lo, self.hi = math.log(lam_range[0]), math.log(lam_range[1])
        self.mu0 = g.mu.detach()
        t, s, _ = sphere.frame(self.mu0)
        self.t, self.s = t, s
        self.sigma0 = g.lam.detach().clamp_min(1e-6).rsqrt()[..., None]  # (B, J, N, 1)
        self.ab = torch.zeros(*g.lam.shape, 2, dtype=g.mu.dtype, device=g.mu.device)
        self.z = g.lam.detach().clamp(math.exp(self.lo), math.exp(self.hi)).log().clone()

    def decode(self, *, clamp: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
        off = self.ab[..., :1] * self.t + self.ab[..., 1:] * self.s
        mu = torch.nn.functional.normalize(self.mu0 + self.sigma0 * off, dim=-1)
        z = self.z.clamp(self.lo, self.hi) if clamp else self.z
        return mu, torch.exp(z)

    def penalty(self) -> torch.Tensor:
        """Per vertex (B,): keeps ``z`` in range and the offsets finite where nothing else does."""
        out = (self.lo - self.z).clamp_min(0) ** 2 + (self.z - self.hi).clamp_min(0) ** 2
        return out.sum((1, 2)) + 1e-9 * (self.ab**2).sum((1, 2, 3))


def objective(
    data: FitData,
    mu: torch.Tensor,
    lam: torch.Tensor,
    nbr_views: torch.Tensor,
    weights: Weights,
    nbr_mu: torch.Tensor | None = None,
    nbr_mask: torch.Tensor | None = None,
    conserve: bool = True,
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """Per-vertex objective (B,) and its terms, with the weights solved for."""
    w = solve_weights(data, mu, lam, conserve=conserve)
    terms = {
        "D": data_term(data, w, mu, lam),
        "M": mean_term(mu, nbr_views),
        "V": sigma_term(lam, nbr_views),
    }
    if nbr_mu is not None and nbr_mask is not None:
        terms["S"] = spatial_term(mu, nbr_mu, nbr_mask)
    else:
        terms["S"] = torch.zeros_like(terms["D"])
    total = (
        weights.alpha * terms["D"]
        + weights.beta * terms["M"]
        + weights.gamma * terms["V"]
        + weights.delta * terms["S"]
    )
    return total, terms


def fit_batch(
    data: FitData,
    n: int,
    nbr_views: torch.Tensor,
    *,
    weights: Weights | None = None,
    init: Gaussians | None = None,
    nbr_mu: torch.Tensor | None = None,
    nbr_mask: torch.Tensor | None = None,
    lam_range=LAM_RANGE,
    method: str = "lm",
    iters: int | None = None,
    lr: float = 0.05,
    conserve: bool = True,
) -> tuple[Gaussians, dict[str, torch.Tensor]]:
    """Minimise eq. (6) for a batch of independent vertices: a local optimiser over the means
    and widths, then :func:`relabel` over the order of each view's Gaussians.

    Parameters
    ----------
    data : FitData of B vertices x J views;  n : Gaussians per view
    nbr_views : (J, 6) geodesic neighbour table of the views (-1 padded)
    init : starting point (default :func:`initial_guess`)
    nbr_mu, nbr_mask : processed neighbours' means (B, Q, J, N, 3) and slots (B, Q) for ``S``

    method : "lm" (batched Levenberg-Marquardt, :mod:`._lm`; default) or "adam" (autograd
        on the same objective: slower, kept as an independent check of the LM steps)
    iters : iterations (default 20 for LM, 150 for Adam)
    conserve : the weights keep each view's light, the integral of its data
        (:func:`._objective.solve_gram`: what a long-tailed lobe's L2 fit loses)

    Returns
    -------
    Gaussians, and the final terms ``{"D", "M", "V", "S"}`` per vertex (B,)
    """
    weights = Weights() if weights is None else weights
    g0 = init
    if g0 is None:
        g0 = initial_guess(
            data,
            n,
            lam_range=lam_range,
            nbr_views=nbr_views,
            solve=method != "lm",
            conserve=conserve,
        )
    if method == "lm":
        st: dict = {}
        mu, lam = levenberg_marquardt(
            data,
            g0.mu,
            g0.lam,
            nbr_views,
            weights,
            nbr_mu=nbr_mu,
            nbr_mask=nbr_mask,
            lam_range=lam_range,
            iters=20 if iters is None else iters,
            state=st,
            conserve=conserve,
        )
        g = relabel(
            Gaussians(st["w"], mu, lam),
            nbr_views,
            weights=weights,
            nbr_mu=nbr_mu,
            nbr_mask=nbr_mask,
        )
        # the LM's last evaluation already holds the weights and the data term (the costly
        # parts, which the order of the Gaussians does not change); the alignment terms are
        # cheap
        terms = {"D": st["D"], "M": mean_term(g.mu, nbr_views), "V": sigma_term(g.lam, nbr_views)}
        if nbr_mu is not None and nbr_mask is not None:
            terms["S"] = spatial_term(g.mu, nbr_mu, nbr_mask)
        else:
            terms["S"] = torch.zeros_like(terms["D"])
        return g, terms
    if method != "adam":
        raise InputError("method", f"must be 'lm' or 'adam', got {method!r}")
    iters = 150 if iters is None else iters
    p = _Params(g0, lam_range)
    p.ab.requires_grad_(True)
    p.z.requires_grad_(True)
    # Adam, not L-BFGS: the objective has directions it saturates along (a mean pushed far
    # along its tangent plane, a view with no data), where torch's strong-Wolfe line search
    # extrapolates without bound; Adam's steps are bounded by its learning rate, which is in
    # units of each lobe's own width (offsets) and of log-sharpness.
    opt = torch.optim.Adam([p.ab, p.z], lr=lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, iters, eta_min=lr * 0.02)
    for _ in range(iters):
        opt.zero_grad()
        mu, lam = p.decode()
        total, _ = objective(data, mu, lam, nbr_views, weights, nbr_mu, nbr_mask, conserve)
        (total + p.penalty()).sum().backward()
        opt.step()
        sched.step()
    with torch.no_grad():
        mu, lam = p.decode(clamp=True)
        g = relabel(
            Gaussians(solve_weights(data, mu, lam, conserve=conserve), mu, lam),
            nbr_views,
            weights=weights,
            nbr_mu=nbr_mu,
            nbr_mask=nbr_mask,
        )
        _, terms = objective(data, g.mu, g.lam, nbr_views, weights, nbr_mu, nbr_mask, conserve)
    return g, terms
