"""The chunk: the unit of a bake's work, fitted, saved and resumed as one.

A bake (:func:`lobelight.fit.fit_mesh`) cuts the mesh's vertices into :class:`Chunk` s
(:func:`plan_chunks`) and runs them in order, in the flood fill (:func:`fit_chunk`) and again
in the relaxation (:func:`refit_chunk`); its checkpoint counts the chunks done
(:mod:`._checkpoint`). Each chunk reads and writes the bake's arrays (:class:`BakeState`) at
its own vertices, and reads them at their neighbours:

- In the flood fill with one Gaussian per view there is no spatial term, and a chunk reads
  nothing of other chunks: chunks are independent and may run in any order, or at once.
- With two or more, a chunk's vertices start from, and are held by ``S`` against, the
  neighbours fitted in the chunks before it: chunks run in order (a chunk depends on the
  earlier ones).
- The relaxation refits each chunk against all neighbours' current Gaussians, in order.

A chunk's indirect glossy paths are seeded by its index, not by when it runs, so a resumed bake
draws the paths an uninterrupted one does.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, fields

import torch

from ..geometry import cubemap, sphere
from ..scene import Mesh
from ..transport import DIFFUSE_ORDER, Transport
from ._data import gather, lobe_estimate
from ._objective import Weights, mixture, solve_weights
from ._optimize import Gaussians, fit_batch, initial_guess
from ._relax import SEPARATED, vertex_flips

__all__ = [
    "FILL_ITERATIONS",
    "MAX_NEIGHBOURS",
    "REFIT_ITERATIONS",
    "Bake",
    "BakeState",
    "Chunk",
    "fit_chunk",
    "plan_chunks",
    "refit_chunk",
]

#: Processed neighbours a vertex's S term reads (the rest of a high-valence fan is dropped).
MAX_NEIGHBOURS = 8
#: Levenberg-Marquardt iterations of a chunk's fit in the flood fill, and in the relaxation's
#: refit, which starts from the flood fill's converged lobes.
FILL_ITERATIONS = 14
REFIT_ITERATIONS = 8
#: Face resolution of the cube map of directions the self-shadowed diffuse transfer sums over.
DIFFUSE_RES = 16


@dataclass(frozen=True)
class Chunk:
    """Vertices fitted together: the unit of work that a bake runs, its checkpoint counts, and
    a resumed bake goes on after (module docstring).

    Attributes
    ----------
    index : its place in its pass, ``0..K-1``; seeds its indirect glossy paths
    vertices : (B,) int64 vertex ids, on the bake's device
    """

    index: int
    vertices: torch.Tensor

    def generator(self, seed: int) -> torch.Generator:
        """The random generator of the chunk's indirect glossy paths in a bake of ``seed``."""
        return torch.Generator().manual_seed(seed * 1_000_003 + 2 * self.index)


def plan_chunks(layers: list[torch.Tensor], *, n: int, batch: int, device) -> list[Chunk]:
    """The chunks of a bake, in the order they run: the flood fill's wavefronts ``layers``
    (:func:`lobelight.fit.wavefronts`) cut into chunks of at most ``batch`` vertices. With
    ``n = 1`` Gaussian per view there is no spatial term and a chunk runs across wavefronts;
    with ``n >= 2`` a chunk stays inside one wavefront."""
    if n == 1:  # no spatial term: any vertices may share a chunk
        order = torch.cat(layers)
        parts = [order[s : s + batch] for s in range(0, order.numel(), batch)]
    else:
        parts = [f[s : s + batch] for f in layers for s in range(0, f.numel(), batch)]
    return [Chunk(i, p.to(device)) for i, p in enumerate(parts)]


@dataclass(eq=False)
class BakeState:
    """What a bake has computed, per vertex: the arrays its checkpoint saves.

    Attributes
    ----------
    mu, w : (V, J, N, 3) and lam : (V, J, N), the fitted direct glossy Gaussians
    derr : (V,) relative L2 error squared of their fit (the data term D)
    diffuse : (V, 25, 3) SH diffuse transfer;  bounce : (V, 25, 3) its interreflected part
    done : (V,) bool, vertices the flood fill has reached
    glossy : (V,) bool, vertices whose material has a glossy lobe (BRDF samples carry weight;
        known once a vertex is reached): the others have no glossy transport at all, are
        given zero weights without a fit, and are nobody's neighbour in the spatial term
        (their means are arbitrary)
    ind_w, ind_mu : (V, J, 1, 3) and ind_lam : (V, J, 1), the indirect glossy Gaussian
    """

    mu: torch.Tensor
    lam: torch.Tensor
    w: torch.Tensor
    derr: torch.Tensor
    diffuse: torch.Tensor
    bounce: torch.Tensor
    done: torch.Tensor
    glossy: torch.Tensor
    ind_w: torch.Tensor
    ind_mu: torch.Tensor
    ind_lam: torch.Tensor

    @classmethod
    def empty(cls, v: int, j: int, n: int, *, device) -> BakeState:
        """The state before any chunk has run, for V vertices, J views and N Gaussians."""
        sh = DIFFUSE_ORDER**2
        return cls(
            mu=torch.zeros(v, j, n, 3, device=device),
            lam=torch.ones(v, j, n, device=device),
            w=torch.zeros(v, j, n, 3, device=device),
            derr=torch.zeros(v, device=device),
            diffuse=torch.zeros(v, sh, 3, device=device),
            bounce=torch.zeros(v, sh, 3, device=device),
            done=torch.zeros(v, dtype=torch.bool, device=device),
            glossy=torch.zeros(v, dtype=torch.bool, device=device),
            ind_w=torch.zeros(v, j, 1, 3, device=device),
            ind_mu=torch.tensor([0.0, 1.0, 0.0], device=device).expand(v, j, 1, 3).clone(),
            ind_lam=torch.ones(v, j, 1, device=device),
        )

    def arrays(self) -> dict[str, torch.Tensor]:
        """The arrays by name, as a checkpoint stores them (the tensors themselves)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def gaussians(self, ids: torch.Tensor | None = None) -> Gaussians:
        """The fitted direct glossy Gaussians of vertices ``ids`` (any index shape), or of all
        vertices (the arrays themselves)."""
        if ids is None:
            return Gaussians(self.w, self.mu, self.lam)
        return Gaussians(self.w[ids], self.mu[ids], self.lam[ids])


@dataclass(eq=False)
class Bake:
    """What every chunk of one bake reads and writes: the transport, the settings, the state.

    Attributes
    ----------
    transport : Transport of the scene;  views : (J, 3);  nbr_views : (J, 6) geodesic table
    n : Gaussians per view;  weights : the objective's;  indirect_paths : per vertex and view
    seed : the bake's;  state : BakeState
    diffuse_dirs, diffuse_weights : (D, 3) directions and (D,) solid angles of the diffuse sum
    flips_before, flips_after : flipped pairs (all, separated) after the flood fill and after
        the relaxation (:func:`lobelight.fit.count_flips`)
    indirect_seconds : time spent tracing indirect glossy paths
    """

    transport: Transport
    views: torch.Tensor
    nbr_views: torch.Tensor
    n: int
    weights: Weights
    indirect_paths: int
    seed: int
    state: BakeState
    diffuse_dirs: torch.Tensor
    diffuse_weights: torch.Tensor
    flips_before: tuple[int, int] = (0, 0)
    flips_after: tuple[int, int] = (0, 0)
    indirect_seconds: float = 0.0

    @classmethod
    def start(
        cls, tr: Transport, views: torch.Tensor, *, n: int, weights: Weights, indirect_paths, seed
    ) -> Bake:
        """A bake of ``tr``'s mesh at ``views`` (on ``tr``'s device), before any chunk."""
        dev = tr.device
        return cls(
            transport=tr,
            views=views,
            nbr_views=sphere.geodesic_neighbor_table(device=dev),
            n=n,
            weights=weights,
            indirect_paths=indirect_paths,
            seed=seed,
            state=BakeState.empty(tr.mesh.n_vertices, views.shape[0], n, device=dev),
            diffuse_dirs=cubemap.texel_directions(DIFFUSE_RES, device=dev).reshape(-1, 3),
            diffuse_weights=cubemap.texel_solid_angles(DIFFUSE_RES, device=dev).reshape(-1),
        )

    @property
    def mesh(self) -> Mesh:
        return self.transport.mesh


def fit_chunk(bake: Bake, chunk: Chunk) -> None:
    """The flood fill's work on a chunk: its vertices' self-shadowed diffuse transfer, their
    indirect glossy Gaussian, and their direct glossy Gaussians fitted against the processed
    neighbours (from the start that suits each one's data best, :func:`_better_start`)."""
    st, n = bake.state, bake.n
    lobe, vidx = _first_visit(bake, chunk.vertices)
    if vidx.numel() == 0:
        return
    if bake.indirect_paths > 0:
        _indirect(bake, chunk, vidx)
    # the relaxation samples the transport again rather than keeping it: all of it
    # (V x J x ~700 samples x 7 floats) would not fit in memory on a large mesh
    data = gather(bake.transport, vidx, bake.views, lobe=lobe).compact()
    # the chunk's own vertices are fitted together, now: none may read another's unfitted
    # state (zero means) as a processed neighbour, for S or as a start
    avail = st.done & st.glossy
    avail[vidx] = False
    ids, mask = _processed_neighbours(bake.mesh, vidx, avail)
    init = None
    if n > 1 and bool(mask[:, 0].all()):
        # start from a processed neighbour's Gaussians (the same correspondence of lobes)
        # where they fit this vertex's data, from the data's own guess where they do not
        init = _better_start(data, n, bake.nbr_views, st.gaussians(ids[:, 0]))
    g, terms = _fit(bake, data, ids, mask, init, iters=FILL_ITERATIONS)
    st.mu[vidx], st.lam[vidx], st.w[vidx] = g.mu, g.lam, g.w
    st.derr[vidx] = terms["D"]


def refit_chunk(bake: Bake, chunk: Chunk) -> None:
    """The relaxation's work on a chunk: its glossy vertices refitted from their Gaussians with
    ``S`` against all their neighbours, keeping the new lobes only where they add no flipped
    pair."""
    st = bake.state
    vidx = chunk.vertices
    vidx = vidx[st.glossy[vidx]]
    if vidx.numel() == 0:
        return
    data = gather(bake.transport, vidx, bake.views, lobe=None).compact()
    ids, mask = _processed_neighbours(bake.mesh, vidx, st.glossy)
    g, terms = _fit(bake, data, ids, mask, st.gaussians(vidx), iters=REFIT_ITERATIONS)
    # The refit keeps a vertex's new lobes only where they add no flipped pair against its
    # neighbours, counting all pairs and separated ones: S alone does not hold the lobes (its
    # cubic penalty vanishes for lobes a few tenths of a radian apart), and unguarded the pass
    # adds flips and knots the lobes into arrangements no reordering can undo (docs/method.md)
    old, nbr = st.gaussians(vidx), st.gaussians(ids)
    keep = torch.ones(vidx.numel(), dtype=torch.bool, device=vidx.device)
    for sep in (0.0, SEPARATED):
        keep &= vertex_flips(g, nbr, mask, min_separation=sep) <= vertex_flips(
            old, nbr, mask, min_separation=sep
        )
    g = Gaussians(
        torch.where(keep[:, None, None, None], g.w, old.w),
        torch.where(keep[:, None, None, None], g.mu, old.mu),
        torch.where(keep[:, None, None], g.lam, old.lam),
    )
    st.mu[vidx], st.lam[vidx], st.w[vidx] = g.mu, g.lam, g.w
    st.derr[vidx] = torch.where(keep, terms["D"], st.derr[vidx])


def _first_visit(bake: Bake, vidx: torch.Tensor):
    """A chunk's vertices reached by the flood fill: their diffuse transfer, which of them are
    glossy, and zero weights for the others. Returns the glossy ones' lobe estimate
    (:func:`lobelight.fit.lobe_estimate`) and ids."""
    st, tr = bake.state, bake.transport
    st.diffuse[vidx] = tr.diffuse(vidx, bake.diffuse_dirs, bake.diffuse_weights)
    st.done[vidx] = True
    axis, lam_est, scale = lobe_estimate(tr, vidx, bake.views)
    gl = (lam_est > 0).any(1)
    st.glossy[vidx] = gl
    rest = ~gl
    if bool(rest.any()):  # no glossy transport: zero weights, means at the lobe axis
        st.mu[vidx[rest]] = axis[rest][:, :, None].expand(-1, -1, bake.n, -1)
        st.lam[vidx[rest]], st.w[vidx[rest]], st.derr[vidx[rest]] = 1.0, 0.0, 0.0
    return (axis[gl], lam_est[gl], scale[gl]), vidx[gl]


def _indirect(bake: Bake, chunk: Chunk, vidx: torch.Tensor) -> None:
    """The indirect glossy Gaussian of the chunk's glossy vertices ``vidx``."""
    st = bake.state
    t = time.perf_counter()
    ig = bake.transport.indirect_lobes(
        vidx, bake.views, paths=bake.indirect_paths, generator=chunk.generator(bake.seed)
    )
    st.ind_w[vidx], st.ind_mu[vidx], st.ind_lam[vidx] = ig.w, ig.mu, ig.lam
    bake.indirect_seconds += time.perf_counter() - t


def _fit(bake: Bake, data, ids, mask, init: Gaussians | None, *, iters: int):
    """:func:`lobelight.fit.fit_batch` of a chunk's data in ``iters`` iterations, ``S`` against
    neighbours ``ids`` (B, Q) where ``mask`` (with two or more Gaussians per view)."""
    n = bake.n
    return fit_batch(
        data,
        n,
        bake.nbr_views,
        weights=bake.weights,
        init=init,
        iters=iters,
        nbr_mu=bake.state.mu[ids] if n > 1 else None,  # (B, Q, J, N, 3)
        nbr_mask=mask if n > 1 else None,
    )


def _processed_neighbours(
    mesh: Mesh, vidx: torch.Tensor, done: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Up to MAX_NEIGHBOURS processed neighbours per vertex: ids (B, Q) and mask (B, Q)."""
    off, nb = mesh.adjacency
    dev = vidx.device
    q = MAX_NEIGHBOURS
    starts, lens = off[vidx], (off[vidx + 1] - off[vidx]).clamp(max=4 * q)
    slot = torch.arange(4 * q, device=dev)
    idx = (starts[:, None] + slot).clamp(max=nb.numel() - 1)
    cand = nb[idx]  # (B, 4Q)
    ok = (slot[None] < lens[:, None]) & done[cand]
    # keep the first Q processed ones: sort slots so that valid ones come first
    order = torch.argsort((~ok).to(torch.int8), dim=1, stable=True)[:, :q]
    ids = torch.gather(cand, 1, order)
    mask = torch.gather(ok, 1, order)
    return ids, mask


def _better_start(data, n: int, nbr_views: torch.Tensor, neighbour: Gaussians) -> Gaussians:
    """Per view, the neighbour's Gaussians or the data's own initial guess, whichever fits the
    view's samples better (weights solved for both).

    Why: a neighbour's lobes keep the labels coherent across the mesh, but on a coarse mesh
    neighbouring vertices' mirror directions differ by tens of degrees, so a sharp lobe taken
    over from a neighbour can miss this vertex's data altogether; with no overlap the fit has
    no gradient and stays there. Always starting from the neighbour ends at a larger mean
    error than never starting from it; this choice per view keeps both the coherence and the
    fit.
    """
    own = initial_guess(data, n, nbr_views=nbr_views)
    w_nb = solve_weights(data, neighbour.mu, neighbour.lam)

    def per_view(g_w, g_mu, g_lam):
        r = mixture(data, g_w, g_mu, g_lam) - data.values  # (B, J, S, 3)
        return (data.weights[..., None] * r * r).sum((-1, -2))  # (B, J)

    take = per_view(w_nb, neighbour.mu, neighbour.lam) <= per_view(own.w, own.mu, own.lam)
    t = take[..., None]
    return Gaussians(
        torch.where(t[..., None], w_nb, own.w),
        torch.where(t[..., None], neighbour.mu, own.mu),
        torch.where(t, neighbour.lam, own.lam),
    )
