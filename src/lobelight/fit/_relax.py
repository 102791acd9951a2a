"""The relaxation pass's reordering: the order of every vertex's Gaussians, over the whole mesh.

Beyond the paper. Its relaxation (revisit each vertex with all neighbours known, section 7)
refits means and widths with ``S`` against every neighbour; measured, that pass *adds* flipped
pairs (docs/method.md): ``S``'s cubic penalty grows as ``|dmu|^6`` and is all but zero for
lobes a few tenths of a radian apart, so further LM iterations move lobes more than ``S``
holds them. A flip, though, is a labelling fault, and labels are discrete: this pass changes no
lobe, only which slot holds it, per (vertex, view), choosing the order that lowers

    beta M + gamma V + (flip_weight / J) * (flipped neighbour pairs)

over the mesh. ``M`` and ``V`` keep the order coherent across a vertex's views (as
:func:`lobelight.fit._optimize.relabel` does); the last term counts, per view, the neighbouring
vertices whose live Gaussians are arranged the other way (:func:`lobelight.fit.flip_count`, the
measure reported), and being a count it weighs lobes 0.05 and 0.5 rad apart alike, which ``S``
cannot. The data term does not see the order, so the fit's error is unchanged.

It is iterated conditional modes, vectorised: every (vertex, view) node computes its best gain
with all others held, and a node moves only where no node it interacts with (the neighbouring
views of its vertex, the same view of neighbouring vertices) gains more, so the gains of one
sweep add up and the objective falls. Two kinds of flip stay, by design: lobes so close that
the direction between them is noise while their widths differ (a sharp core on a broad skirt,
whose order ``V`` holds by width), and pairs whose swap would break a view's coherence more than
it mends between vertices.
"""

from __future__ import annotations

import itertools

import torch

from .._tol import SHARPNESS_MIN
from ..lobes import sg
from ..model import LIVE_FLOOR
from ..progress import ProgressFn
from ..scene import Mesh
from ._objective import Weights, _pair_diffs, flipped_views, mean_term, sigma_term
from ._optimize import Gaussians, _permuted, _swap_gain

__all__ = [
    "FLIP_WEIGHT",
    "SEPARATED",
    "live_gaussians",
    "neighbour_table",
    "reorder_mesh",
    "separated_pairs",
    "vertex_flips",
]

# One flipped neighbour pair costs what M charges for one mean 1 rad out of line with its
# neighbouring views at the default beta (0.01 x 1^2): a flip outweighs the small incoherence
# of exchanging two nearby lobes, not the large one of exchanging distant ones. The flip counts
# of a bake with N = 2 change little for a weight ten times smaller or larger.
FLIP_WEIGHT = 1e-2
#: Lobes this many widths apart or more have an arrangement that a flip visibly breaks; closer
#: ones (a sharp core on a broad skirt) are ordered by width, and the direction between them is
#: noise (:func:`lobelight.fit.count_flips`).
SEPARATED = 0.5
#: The least drop of the objective for which a node moves: gains at round-off level are ties,
#: and moving on them would let two orders of equal cost trade places sweep after sweep.
MIN_GAIN = 1e-12


def live_gaussians(g: Gaussians, live_fraction: float = 0.05) -> torch.Tensor:
    """Gaussians that carry light, (V, J, N) bool: at least ``live_fraction`` of the light of the
    view's brightest Gaussian (``w int G``, summed over channels)."""
    carried = g.w.sum(-1) * sg.integral(g.lam)  # (V, J, N)
    return carried > live_fraction * carried.amax(-1, keepdim=True).clamp_min(LIVE_FLOOR)


def neighbour_table(mesh: Mesh) -> tuple[torch.Tensor, torch.Tensor]:
    """All neighbours of every vertex, padded: ids (V, Q) (0 where padded) and mask (V, Q)."""
    off, nb = mesh.adjacency
    deg = off[1:] - off[:-1]
    q = max(int(deg.max()), 1) if deg.numel() else 1
    slot = torch.arange(q, device=nb.device)
    mask = slot[None] < deg[:, None]
    idx = (off[:-1, None] + slot).clamp(max=max(nb.numel() - 1, 0))
    ids = torch.where(mask, nb[idx], 0) if nb.numel() else torch.zeros_like(mask, dtype=torch.long)
    return ids, mask


def separated_pairs(g: Gaussians, min_separation: float) -> torch.Tensor:
    """Pairs ``k1 < k2`` of Gaussians whose means lie at least ``min_separation`` widths
    (``sigma`` of the wider) apart, (..., J, P) bool for Gaussians (..., J, N)."""
    n = g.mu.shape[-2]
    i, j = torch.triu_indices(n, n, offset=1, device=g.mu.device)
    sigma = g.lam.clamp_min(SHARPNESS_MIN).rsqrt()
    wide = torch.maximum(sigma[..., i], sigma[..., j])
    return _pair_diffs(g.mu).norm(dim=-1) >= min_separation * wide


def _flipped(mu, live, nbr_mu, nbr_live, nbr_mask, pair_ok=None) -> torch.Tensor:
    """Per (vertex, view), how many neighbours are flipped against it: (B, J) float.

    mu (B, J, N, 3), live (B, J, N); nbr_mu (B, Q, J, N, 3), nbr_live (B, Q, J, N), nbr_mask (B, Q);
    pair_ok (B, Q, J, P) optional, which pairs of Gaussians to count
    """
    flip = flipped_views(mu[:, None], nbr_mu, live[:, None], nbr_live, pair_ok)  # (B, Q, J)
    return (flip & nbr_mask[:, :, None]).sum(1).to(mu.dtype)


def vertex_flips(
    g: Gaussians, nbr: Gaussians, nbr_mask: torch.Tensor, *, min_separation: float = 0.0
) -> torch.Tensor:
    """Flipped (neighbour, view) pairs of each vertex, (B,) float: as
    :func:`lobelight.fit.count_flips` counts them, for B vertices against their neighbours.

    g : Gaussians (B, J, N);  nbr : Gaussians (B, Q, J, N) of up to Q neighbours
    nbr_mask : (B, Q) which neighbour slots are real
    """
    if g.mu.shape[-2] < 2:
        return g.mu.new_zeros(g.mu.shape[0])
    pair_ok = None
    if min_separation > 0:
        pair_ok = separated_pairs(g, min_separation)[:, None] & separated_pairs(nbr, min_separation)
    live, nbr_live = live_gaussians(g), live_gaussians(nbr)
    return _flipped(g.mu, live, nbr.mu, nbr_live, nbr_mask, pair_ok).sum(1)


def _with_neighbours(moved: torch.Tensor, nbrs: torch.Tensor, nmask: torch.Tensor) -> torch.Tensor:
    """The vertices (V,) bool that moved or have a neighbour that did (ids ``nbrs`` (V, Q),
    ``nmask`` (V, Q) which slots are real; the mesh's adjacency is symmetric)."""
    return moved | (moved[nbrs] & nmask).any(1)


def _beaten(rank, node, other, other_node, ok) -> torch.Tensor:
    """Nodes (V, J) some interacting node beats: a higher gain, or an equal gain and a lower
    index. ``other``/``other_node`` (V, J, K) are the K interacting nodes' gains and indices."""
    r, me = rank[..., None], node[..., None]
    return (((other > r) | ((other == r) & (other_node < me))) & ok).any(-1)


def reorder_mesh(
    mesh: Mesh,
    g: Gaussians,
    nbr_views: torch.Tensor,
    *,
    weights: Weights | None = None,
    flip_weight: float = FLIP_WEIGHT,
    live_fraction: float = 0.05,
    sweeps: int = 64,
    chunk: int = 2048,
    progress: ProgressFn | None = None,
) -> Gaussians:
    """Reorder the Gaussians of every (vertex, view) where that lowers the module's objective.

    Parameters
    ----------
    mesh : the fitted mesh (its edges are the neighbour pairs)
    g : Gaussians (V, J, N) of the whole mesh;  nbr_views : (J, 6) geodesic neighbour table
    weights : ``beta`` and ``gamma`` weigh ``M`` and ``V`` (``delta`` is not used: the flip
        count stands in for ``S``)
    flip_weight : cost of one flipped neighbour pair in one view, times J
    sweeps : at most this many sweeps (each moves a set of non-interacting nodes)
    chunk : vertices per batch of the gain computation (bounds memory: ~chunk x Q x J x N x 40
        bytes)
    progress : called ``progress("reorder", k, sweeps)`` after sweep ``k``, and with ``done ==
        total`` (the sweeps made) when the reordering ends: the first sweep weighs every order
        of every (vertex, view), N! - 1 of them (later ones what moved and its neighbours),
        so with three lobes it takes minutes

    Returns
    -------
    Gaussians: per (vertex, view) the same lobes, perhaps in another order
    """
    weights = Weights() if weights is None else weights
    v, j, n = g.lam.shape
    if n < 2 or v == 0:
        return g
    dev = g.mu.device
    mv_weights = Weights(alpha=0.0, beta=weights.beta, gamma=weights.gamma, delta=0.0)
    perms = torch.tensor(list(itertools.permutations(range(n))), device=dev)[1:]  # (P, N)
    ident = torch.arange(n, device=dev)
    nbrs, nmask = neighbour_table(mesh)
    nbrs, nmask = nbrs.to(dev), nmask.to(dev)
    nb_v, valid_v = nbr_views.clamp_min(0), nbr_views >= 0  # (J, 6)
    node = torch.arange(v * j, device=dev).reshape(v, j)  # tie-break: the lower index moves
    w, mu, lam = g.w.clone(), g.mu.clone(), g.lam.clone()
    live = live_gaussians(g, live_fraction)
    prev = None
    made = 0
    # Each vertex's share of the objective and its best moves, kept between sweeps: they
    # depend on the vertex's own lobes and its neighbours', so after a sweep only the vertices
    # that moved and their neighbours are weighed again (the rest would come out the same)
    energy_v = torch.zeros(v, dtype=torch.float64, device=dev)
    gain = torch.zeros(v, j, dtype=mu.dtype, device=dev)
    which = torch.zeros(v, j, dtype=torch.long, device=dev)
    vgain = torch.zeros(v, dtype=mu.dtype, device=dev)
    vwhich = torch.zeros(v, dtype=torch.long, device=dev)
    dirty = torch.ones(v, dtype=torch.bool, device=dev)
    for made in range(1, sweeps + 1):
        if progress is not None and made > 1:
            progress("reorder", made - 1, sweeps)
        todo = torch.nonzero(dirty).flatten()
        for s in range(0, todo.numel(), chunk):  # bounded memory
            ids = todo[s : s + chunk]
            sub = Gaussians(w[ids], mu[ids], lam[ids])
            q, m = nbrs[ids], nmask[ids]
            nbr_mu, nbr_live = mu[q], live[q]  # (B, Q, J, N, 3), (B, Q, J, N)
            f0 = _flipped(mu[ids], live[ids], nbr_mu, nbr_live, m)
            energy_v[ids] = (
                weights.beta * mean_term(sub.mu, nbr_views)
                + weights.gamma * sigma_term(sub.lam, nbr_views)
                + flip_weight * f0.sum(1) / (2 * j)  # each pair seen from both ends
            ).double()
            per, whole = [], []
            for p in perms:  # N! - 1 <= 5 orders
                f1 = _flipped(mu[ids][:, :, p], live[ids][:, :, p], nbr_mu, nbr_live, m)
                mv = _swap_gain(sub, p, nbr_views, mv_weights, None, None)  # (B, J)
                per.append(mv + flip_weight * (f0 - f1) / j)
                # the same order in all views of the vertex: M and V do not see it
                whole.append(flip_weight * (f0 - f1).sum(1) / j)
            gain[ids], which[ids] = torch.stack(per).max(0)
            vgain[ids], vwhich[ids] = torch.stack(whole).max(0)
        energy = float(energy_v.sum())
        # the gains of one sweep add up exactly in the flip count, and to first order in M
        # and V (two views moving beside a third both change its neighbours' average); a
        # sweep that did not lower the objective is undone, and the pass ends
        if prev is not None and energy >= prev[0]:
            w, mu, lam, live = prev[1:]
            break
        prev = (energy, w, mu, lam, live)
        # Whole vertices first: a vertex ordered the other way in every view is coherent
        # across its views, so no single view of it gains by moving (it would break that
        # coherence), while reordering all its views at once mends its flips and costs nothing.
        # Vertices move where no neighbouring vertex gains more.
        vwant = vgain > MIN_GAIN
        if bool(vwant.any()):
            vrank = torch.where(vwant, vgain, torch.full_like(vgain, -1.0))
            ids_v = torch.arange(v, device=dev)
            vmove = vwant & ~_beaten(vrank, ids_v, vrank[nbrs], ids_v[nbrs], nmask)
            perm = torch.where(vmove[:, None], perms[vwhich], ident)[:, None].expand(v, j, n)
            w, mu, lam, live = (_permuted(x, perm) for x in (w, mu, lam, live))
            dirty = _with_neighbours(vmove, nbrs, nmask)
            continue
        want = gain > MIN_GAIN
        rank = torch.where(want, gain, torch.full_like(gain, -1.0))

        # the neighbouring views of the same vertex, and the same view of neighbouring vertices
        by_view = _beaten(rank, node, rank[:, nb_v], node[:, nb_v], valid_v)
        by_vertex = _beaten(
            rank, node, rank[nbrs].transpose(1, 2), node[nbrs].transpose(1, 2), nmask[:, None, :]
        )
        move = want & ~by_view & ~by_vertex
        if not bool(move.any()):
            break
        perm = torch.where(move[..., None], perms[which], ident)  # (V, J, N)
        w, mu, lam, live = (_permuted(x, perm) for x in (w, mu, lam, live))
        dirty = _with_neighbours(move.any(1), nbrs, nmask)
    if progress is not None:
        progress("reorder", made, made)
    return Gaussians(w, mu, lam)
