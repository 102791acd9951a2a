"""Batched Levenberg-Marquardt for eq. (6): one small damped Gauss-Newton system per (vertex, view).

Each view's unknowns are ``3 N`` numbers, per Gaussian a tangent-plane step ``(a, b)`` of its
mean in units of its width and a step ``z`` of its log-sharpness, taken around the current
estimate (so the Jacobian is exact at the expansion point)::

    mu' = normalise(mu + sigma (a t + b s)),   lam' = lam exp(z),   sigma = lam^(-1/2)

Residuals of a view ``v`` (their squares sum to that view's share of the objective):

- data: ``sqrt(Omega_s / E) (sum_k w_kc G_k(omega_s) - T_c(omega_s))`` for every sample and
  channel, ``E`` the vertex's transport energy (so ``D`` is a relative error). The weights ``w``
  are solved exactly for the current means and widths (variable projection), by default under
  the constraint that the lobes carry the data's light (:func:`._objective.solve_gram`). The
  Jacobian is Kaufman's: the rows with the weights held, less their part that the weights' own
  move takes up (projected off the lobes' span, :func:`_projected`), which the weights' re-solve
  absorbs. Under the constraint it is the light each lobe carries, ``w_k Z(lam_k)``, that is
  held, and the weights move only so as to keep the sum. The held rows alone would make the
  iteration an alternation between weights and lobes, which crawls where two lobes overlap (a
  sharp core on a broad skirt). The gradient is the held-weights one either way (exact at
  solved weights).
- ``M``: ``sqrt(beta / J) (normalise(avg_r mu_k^r) - mu_k)`` per Gaussian (3 residuals);
- ``V``: ``sqrt(gamma / J) (avg_r sigma_k^r - sigma_k) / avg_r sigma_k^r``;
- ``S``: ``sqrt(delta / J) max(-<dmu_x, dmu_s>, 0)^(3/2)`` per pair of Gaussians and processed
  neighbour vertex.

``M`` and ``V`` couple the views: a view's mean enters its own residual and its neighbours'
averages. The gradient has both parts (without the second, the iteration settles where each
view is best given its neighbours, which is not the objective's minimum); the Hessian keeps its
per-view blocks only (block-Jacobi Gauss-Newton), so all views of all vertices step at once.
Each view keeps a damping factor, raised where its step is not kept and lowered where it is,
as in Marquardt's rule. A step is kept per view where it lowers the view's share of the
objective, as long as the vertex's whole objective falls (else the whole step where that lowers
it, else none): one view whose step overshoots does not hold back the vertex's other views.
With ``3 N <= 9`` unknowns per view the systems are solved in one batched call, so an
iteration costs about three evaluations of the mixture at the samples.
"""

from __future__ import annotations

import torch

from .._tol import DIVISOR_F32, DIVISOR_F64
from ..geometry import sphere
from ..lobes import sg
from ._data import FitData
from ._objective import (
    Weights,
    _neighbour_matrix,
    _neighbour_mean,
    _pair_diffs,
    across_views,
    conserve_factor,
    solve_gram,
    unit64,
)

__all__ = ["levenberg_marquardt"]


def _gauss(dirs64_t: torch.Tensor, mu: torch.Tensor, lam: torch.Tensor):
    """``G_k(omega_s)`` and its exponent ``lam_k (mu_k . omega_s - 1)``, both (P, N, S) in
    ``mu``'s dtype, by one batched matmul, for ``dirs64_t`` (P, 3, S), ``mu`` (P, N, 3),
    ``lam`` (P, N).

    The exponent is formed in float64 (``dirs64_t`` is the float64 copy of the sample
    directions, renormalised and transposed; ``mu`` is renormalised likewise) as
    ``(lam mu) . omega - lam``, one fused matmul: ``lam (mu.w - 1)``
    for ``lam = 3e4`` needs ``1 - mu.w`` to better than float32's 6e-8, which the matmul form
    (unlike a half-chord) would otherwise lose, and float64 keeps it (the product's rounding is
    ``lam`` times 1e-16). The exponent, once formed, is exact enough in float32 (relative error
    6e-8 of an argument down to -100 moves G by < 1e-5 relative), and float32 ``exp`` is
    several times cheaper.
    """
    lam64 = lam.double()
    ex = torch.baddbmm(-lam64[..., None], lam64[..., None] * unit64(mu), dirs64_t)
    ex = ex.to(mu.dtype)
    return torch.exp(ex), ex


def _components(axes: torch.Tensor, dirs_t: torch.Tensor) -> torch.Tensor:
    """``axes . omega_s`` (P, K, S) for ``axes`` (P, K, 3) and ``dirs_t`` (P, 3, S): three fused
    multiply-adds, which for K of a few beat a batched matmul of inner dimension 3."""
    out = axes[..., :1] * dirs_t[:, None, 0]
    out.addcmul_(axes[..., 1:2], dirs_t[:, None, 1])
    return out.addcmul_(axes[..., 2:], dirs_t[:, None, 2])


def _reg_cost(mu, lam, mbar, sbar, c, nbr_ds, nbr_mask):
    """Per-view cost of ``M``, ``V`` and ``S`` (B, J), the neighbours' averages held fixed;
    ``nbr_ds`` (B, Q, J, P, 3) the processed neighbours' pair differences (or None)."""
    cost = c["M"] ** 2 * ((mbar - mu) ** 2).sum((-1, -2))
    sigma = lam.rsqrt()
    cost = cost + c["V"] ** 2 * (((sbar - sigma) / sbar) ** 2).sum(-1)
    if nbr_ds is not None and mu.shape[-2] > 1:
        dot = (_pair_diffs(mu)[:, None] * nbr_ds).sum(-1)  # (B, Q, J, P)
        pen = (-dot).clamp_min(0) ** 3 * nbr_mask[:, :, None, None]
        cost = cost + c["S"] ** 2 * pen.sum((1, 3))
    return cost


def levenberg_marquardt(
    data: FitData,
    mu: torch.Tensor,
    lam: torch.Tensor,
    nbr_views: torch.Tensor,
    weights: Weights,
    *,
    nbr_mu: torch.Tensor | None = None,
    nbr_mask: torch.Tensor | None = None,
    lam_range=sg.LAM_RANGE,
    iters: int = 20,
    state: dict | None = None,
    conserve: bool = True,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Refine means (B, J, N, 3) and sharpness (B, J, N); returns the refined pair.

    ``state``, if given, receives the solved weights ``"w"`` (B, J, N, 3) and the data term
    ``"D"`` (B,) at the returned means and widths, so the caller need not evaluate them again.
    ``conserve``: the weights keep each view's light (:func:`._objective.solve_gram`).
    """
    b, j, n = lam.shape
    dt = mu.dtype
    energy = data.energy()  # (B, J)
    inv_e = 1 / energy.sum(1).clamp_min(DIVISOR_F32)  # (B,)
    c = {
        "M": (weights.beta / j) ** 0.5,
        "V": (weights.gamma / j) ** 0.5,
        "S": (weights.delta / j) ** 0.5,
    }
    damp = torch.full((b, j, 1), 1e-3, dtype=dt, device=mu.device)
    valid = (nbr_views >= 0).to(dt)  # (J, 6)
    inv_r = 1 / valid.sum(1)  # (J,) 1 / number of neighbours of each view
    avg = _neighbour_matrix(nbr_views, dt)  # (J, J)
    back = avg.T.contiguous()

    def to_neighbours(x: torch.Tensor) -> torch.Tensor:
        """sum over the views u that have v as a neighbour of x_u / R_u, (B, J, ...)."""
        return across_views(back, x)

    def nmean(x: torch.Tensor) -> torch.Tensor:
        return _neighbour_mean(x, nbr_views, avg)

    # Only views whose samples carry light have a data term: below the horizon, or fully
    # occluded, the transport is 0, the solved weights are 0 and so are the data residuals and
    # their Jacobian. On a typical vertex that is over half of the views (half lie below its
    # horizon), so the per-sample work runs on the P active views alone, packed, and is
    # scattered back to (B, J); M and V still act on every view.
    bj, n_s = b * j, data.dirs.shape[2]
    act = (energy > 0).reshape(-1).nonzero().squeeze(1)  # (P,) flat (vertex, view) indices
    p_n = act.numel()
    dirs_a = data.dirs.reshape(bj, n_s, 3)[act]  # (P, S, 3)
    dirs64_t = data.unit_dirs().reshape(bj, n_s, 3)[act].transpose(1, 2)  # (P, 3, S)
    wts_a = data.weights.reshape(bj, n_s)[act]  # (P, S)
    vals_a = data.values.reshape(bj, n_s, 3)[act]  # (P, S, 3)
    root_w = wts_a.sqrt()[:, None]  # (P, 1, S)
    # the data term from the normal equations: sum_s W_s |sum_k w_k G_k - T|^2
    # = int |T|^2 - 2 w.b + w^T A w per view (in float64, where the cancellation is harmless),
    # so no iteration evaluates the mixture and its residual at every sample; the products are
    # those of sqrt(W) G and sqrt(W) T, so all three terms are of one rounded data set
    tw64 = root_w.double().transpose(1, 2) * vals_a.double()  # (P, S, 3)
    t2 = (tw64**2).sum((-1, -2))  # (P,)
    light = (wts_a[..., None] * vals_a.clamp_min(0)).sum(1)[:, None]  # (P, 1, 3), as light_of
    no_below = torch.zeros(p_n, 1, dtype=torch.bool, device=mu.device)
    vertex_of = act // j  # (P,) which vertex each active view belongs to
    no_data = energy <= 0  # (B, J)
    inv_e_a = inv_e[vertex_of]  # (P,)

    def pack(x: torch.Tensor) -> torch.Tensor:
        """(B, J, ...) -> (P, ...) the active views."""
        return x.reshape(bj, *x.shape[2:])[act]

    def unpack(x: torch.Tensor) -> torch.Tensor:
        """(P, ...) -> (B, J, ...), zero on views without data."""
        out = x.new_zeros(bj, *x.shape[1:])
        return out.index_copy_(0, act, x).reshape(b, j, *x.shape[1:])

    def evaluate(mu_, lam_):
        """G, its exponent (float32, (P, N, S)), the solved weights (P, N, 3), each view's data
        term and its share of the other terms (B, J), and how the weights may move
        (:func:`_free_weights`)."""
        lam_a = pack(lam_)
        g_, ex_ = _gauss(dirs64_t, pack(mu_), lam_a)
        gw = (g_ * root_w).double()  # (P, N, S)
        a_ = torch.bmm(gw, gw.transpose(1, 2))  # (P, N, N)
        rhs = torch.bmm(gw, tw64)  # (P, N, 3)
        w_ = solve_gram(
            a_[:, None], rhs[:, None], lam_a[:, None], no_below, light, conserve=conserve
        )[:, 0]
        quad = torch.einsum("pkc,pkl,plc->p", w_, a_, w_)
        d_a = (t2 - 2 * (w_ * rhs).sum((-1, -2)) + quad).clamp_min(0) * inv_e_a
        free = _free_weights(a_ * inv_e_a[:, None, None], lam_a, w_, conserve)
        return g_, ex_, w_.to(dt), unpack(d_a), reg_views(mu_, lam_), free

    def reg_views(mu_, lam_):
        """Each view's share of ``M``, ``V`` and ``S`` (B, J) at these means and widths."""
        mb = torch.nn.functional.normalize(nmean(mu_), dim=-1)
        sb = nmean(lam_.rsqrt())
        return _reg_cost(mu_, lam_, mb, sb, c, nbr_ds, mask)

    sq_n = (wts_a * inv_e_a[:, None]).sqrt()[:, None]  # (P, 1, S) residual scale
    dflat = dirs_a.transpose(1, 2)  # (P, 3, S)
    vals_t = vals_a.transpose(1, 2)  # (P, 3, S)
    mask = None if nbr_mask is None else nbr_mask.to(dt)
    # the neighbours' pair differences are fixed through the iteration: formed once
    nbr_ds = None if nbr_mu is None or n < 2 else _pair_diffs(nbr_mu)  # (B, Q, J, P, 3)
    mu, lam = mu.clone(), lam.clone()
    g, ex, w, d0, r0, free = evaluate(mu, lam)
    # reused every iteration: the scaled Jacobian rows (3N), the lobes (N) and the residual
    # per lobe (N), so that one product gives the rows' products with all three
    buf = torch.empty(p_n, 5 * n, n_s, dtype=dt, device=mu.device)
    jac = buf[:, : 3 * n].view(p_n, n, 3, n_s)
    own = (4 * n + torch.arange(3 * n, device=mu.device) // 3).expand(p_n, -1)[..., None]
    for _ in range(iters):
        mbar = torch.nn.functional.normalize(nmean(mu), dim=-1)
        sigma = lam.rsqrt()  # (B, J, N)
        sbar = nmean(sigma)
        t, s, _ = sphere.frame(mu)  # (B, J, N, 3) each
        # tangent components of the sample directions: (P, N, S) each
        lam_a, sigma_a = pack(lam), pack(sigma)  # (P, N)
        ts = _components(torch.cat([pack(t), pack(s)], 1), dflat)  # (P, 2N, S)
        tw, sw = ts[:, :n], ts[:, n:]
        # scaled Jacobian rows d (w_k G_k) / d (a, b, z)_k / w_k * sqrt(W_s / E), in place:
        # dG/da = G lam sigma (t.w), dG/db = G lam sigma (s.w), dG/dz = G lam (mu.w - 1), and
        # with the light conserved, w_k = e_k / Z(lam_k) with the carried light e_k held, so
        # the z row gains G kappa (:func:`._objective.conserve_factor`)
        gs = torch.mul(g, sq_n, out=buf[:, 3 * n : 4 * n])
        q = gs * (lam_a * sigma_a)[..., None]
        torch.mul(q, tw, out=jac[:, :, 0])
        torch.mul(q, sw, out=jac[:, :, 1])
        zrow = ex  # lam (mu.w - 1)
        if conserve:
            zrow = zrow + conserve_factor(lam_a)[..., None]
        torch.mul(gs, zrow, out=jac[:, :, 2])
        ww = torch.bmm(w, w.transpose(1, 2))  # (P, N, N)
        # e_k = sum_c w_kc r_c with r the scaled residual: sqrt(W/E) (sum_l ww_kl G_l - w_k.T)
        e = torch.baddbmm(torch.bmm(ww, g), w, vals_t, alpha=-1)
        torch.mul(e, sq_n, out=buf[:, 4 * n :])
        # the rows' products with each other, with the lobes and with the residuals
        prods = torch.bmm(buf[:, : 3 * n], buf.transpose(1, 2))  # (P, 3N, 5N)
        grad = unpack(prods.gather(2, own)[..., 0])  # (B, J, 3N): row (k, i) with e_k
        prods = prods.double()
        h = _projected(prods[..., : 3 * n], prods[..., 3 * n : 4 * n], free)
        h = h.reshape(p_n, n, 3, n, 3) * ww.double().reshape(p_n, n, 1, n, 1)
        h = unpack(h.reshape(p_n, 3 * n, 3 * n).to(dt))
        # M: residual c_M (mbar - mu); d/d(a, b) = -c_M sigma (t, s); V: c_V (sbar - sigma) /
        # sbar, d/dz = c_V sigma / (2 sbar) (sigma = exp(-z/2) relative to the expansion point)
        rm = c["M"] * (mbar - mu)  # (B, J, N, 3)
        jm = -c["M"] * sigma[..., None, None] * torch.stack([t, s], -2)  # (B, J, N, 2, 3)
        gm = torch.einsum("bjnpx,bjnx->bjnp", jm, rm)  # (B, J, N, 2)
        hm = (c["M"] * sigma) ** 2  # (B, J, N): t and s are orthonormal
        rv = c["V"] * (sbar - sigma) / sbar
        jv = c["V"] * sigma / (2 * sbar)
        # the same residuals of the neighbours u, through their averages: d mbar_u / d mu_v
        # ~ 1 / R_u (normalisation's effect dropped), d sbar_u / d z_v = -sigma_v / (2 R_u)
        back_m = to_neighbours(rm)  # (B, J, N, 3)
        gm_n = (
            c["M"]
            * sigma[..., None]
            * torch.stack([(t * back_m).sum(-1), (s * back_m).sum(-1)], -1)
        )
        back_v = to_neighbours(rv / sbar)  # (B, J, N)
        gv_n = -c["V"] * sigma / 2 * back_v
        hn = to_neighbours(torch.ones_like(sigma))  # sum of 1 / R_u over neighbours
        hm = hm + hm * hn * inv_r.mean()
        diag_add = torch.stack([hm, hm, jv * jv], -1).reshape(b, j, 3 * n)
        grad_add = torch.stack(
            [gm[..., 0] + gm_n[..., 0], gm[..., 1] + gm_n[..., 1], jv * rv + gv_n], -1
        ).reshape(b, j, 3 * n)
        h = h + torch.diag_embed(diag_add)
        grad = grad + grad_add
        if nbr_mu is not None and n > 1:
            h, grad = _add_spatial(h, grad, mu, sigma, t, s, nbr_ds, mask, c["S"])
        hd = h.diagonal(dim1=-2, dim2=-1)
        # a parameter nothing sees (a Gaussian whose weight is 0 with M, V and S switched off)
        # has no curvature and no gradient; a floor relative to the system's largest curvature
        # keeps the solve regular (an absolute 1e-12 vanishes in float32) and moves it by 0
        floor = 1e-6 * hd.amax(-1, keepdim=True) + 1e-20
        lhs = h + torch.diag_embed(damp * torch.maximum(hd, floor) + floor)
        step = -torch.linalg.solve(lhs, grad).reshape(b, j, n, 3)
        step = step.clamp(-3, 3)  # at most 3 widths / a factor e^3 in sharpness per iteration
        mu1 = torch.nn.functional.normalize(
            mu + sigma[..., None] * (step[..., :1] * t + step[..., 1:2] * s), dim=-1
        )
        lam1 = (lam * torch.exp(step[..., 2])).clamp(*lam_range)
        g1, ex1, w1, d1, r1, free1 = evaluate(mu1, lam1)
        # a step is kept per view where it lowers the view's share of the objective (its data
        # term is its own; M, V and S are taken with the neighbours' averages of the step),
        # as long as the vertex's whole objective falls; else the whole step if that lowers
        # it; else none. Each view keeps its own damping.
        gain = (d1 + r1 <= d0 + r0) | no_data  # (B, J)
        mu_m = torch.where(gain[..., None, None], mu1, mu)
        lam_m = torch.where(gain[..., None], lam1, lam)
        d_m = torch.where(gain, d1, d0)
        r_m = reg_views(mu_m, lam_m)
        tot0, tot1, tot_m = (d0 + r0).sum(1), (d1 + r1).sum(1), (d_m + r_m).sum(1)
        mixed = tot_m <= torch.minimum(tot0, tot1)  # (B,)
        whole = ~mixed & (tot1 <= tot0)
        take = (mixed[:, None] & gain) | whole[:, None]  # (B, J)
        take_a = pack(take)[:, None]  # (P, 1)
        mu = torch.where(take[..., None, None], mu1, mu)
        lam = torch.where(take[..., None], lam1, lam)
        g = torch.where(take_a[..., None], g1, g)
        ex = torch.where(take_a[..., None], ex1, ex)
        w = torch.where(take_a[..., None], w1, w)
        free = torch.where(take_a[..., None], free1, free)
        d0 = torch.where(take, d1, d0)
        r0 = torch.where(mixed[:, None], r_m, torch.where(whole[:, None], r1, r0))
        stepped = (take & gain)[..., None]  # (B, J, 1)
        damp = torch.where(stepped, damp / 3, damp * 4).clamp(1e-9, 1e9)
    if state is not None:
        state["w"], state["D"] = unpack(w), d0.sum(1).to(dt)
    return mu, lam


def _free_weights(a: torch.Tensor, lam: torch.Tensor, w: torch.Tensor, conserve: bool):
    """How the solved weights may still move, (P, N, N) float64 for :func:`_projected`: the
    inverse Gram matrix of the lobes that carry light in every channel, with ``conserve``
    restricted to the moves that keep their light (``sum_k Z(lam_k) dw_k = 0``). ``a``
    (P, N, N) is the Gram matrix ``int G_k G_l`` in the data term's scale, ``w`` (P, N, 3) the
    weights. A lobe clamped to 0 (in some channel) is left out: its weight does not move."""
    n = a.shape[-1]
    live = (w > 0).all(-1)  # (P, N)
    both = live[..., :, None] & live[..., None, :]
    eye = torch.eye(n, dtype=a.dtype, device=a.device)
    ref = a.diagonal(dim1=-2, dim2=-1).amax(-1).clamp_min(DIVISOR_F64)[..., None, None]
    # the live lobes' block, the identity elsewhere (decoupled from it, and masked after)
    inv = torch.linalg.inv(torch.where(both, a, eye * ref) + 1e-12 * ref * eye)
    inv = torch.where(both, inv, torch.zeros_like(inv))
    if conserve:
        zl = (sg.integral(lam.double()) * live)[..., None]  # (P, N, 1)
        u = inv @ zl
        inv = inv - u @ u.transpose(1, 2) / (zl * u).sum(1, keepdim=True).clamp_min(DIVISOR_F64)
    return inv


def _projected(jj: torch.Tensor, jg: torch.Tensor, free: torch.Tensor) -> torch.Tensor:
    """Kaufman's Gauss-Newton matrix of the variable projection, per active view (P, 3N, 3N)
    float64, before the weights' products: the rows' products ``jj`` less the part that the
    weights' own move takes up, ``jg K jg^T``, with ``jg`` (P, 3N, N) the rows' products with
    the lobes and ``K`` from :func:`_free_weights`. The rows alone (the weights held) make
    the iteration an alternation between weights and lobes, slow where two lobes overlap."""
    return jj - jg @ free @ jg.transpose(1, 2)


def _add_spatial(h, grad, mu, sigma, t, s, ds, mask, c_s):
    """Gauss-Newton terms of ``S`` residuals ``c (max(-dot, 0))^(3/2)`` per pair and neighbour;
    ``ds`` (B, Q, J, P, 3) the neighbours' pair differences."""
    n = mu.shape[-2]
    i1, i2 = torch.triu_indices(n, n, offset=1, device=mu.device)
    dx = _pair_diffs(mu)[:, None]  # (B, 1, J, P, 3)
    neg = (-(dx * ds).sum(-1)).clamp_min(0) * mask[:, :, None, None]  # (B, Q, J, P)
    res = c_s * neg**1.5
    dres = -1.5 * c_s * neg**0.5  # d res / d dot
    # d dot / d (a, b) of Gaussian k1 is sigma_k1 (t, s).ds, of k2 minus that
    jac = torch.zeros(*neg.shape, n, 3, dtype=mu.dtype, device=mu.device)  # (B, Q, J, P, N, 3)
    for idx, sign in ((i1, 1.0), (i2, -1.0)):
        tt = t[:, :, idx][:, None]  # (B, 1, J, P, 3)
        ss = s[:, :, idx][:, None]
        sg_ = sigma[:, :, idx][:, None]  # (B, 1, J, P)
        da = sign * sg_ * (tt * ds).sum(-1)
        db = sign * sg_ * (ss * ds).sum(-1)
        onehot = torch.nn.functional.one_hot(idx, n).to(mu.dtype)  # (P, N)
        jac[..., 0] += (dres * da)[..., None] * onehot
        jac[..., 1] += (dres * db)[..., None] * onehot
    jac = jac.reshape(*neg.shape, 3 * n)
    h = h + torch.einsum("bqjpx,bqjpy->bjxy", jac, jac)
    grad = grad + torch.einsum("bqjpx,bqjp->bjx", jac, res)
    return h, grad
