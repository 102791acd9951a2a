"""The chunk: the unit of a bake's work, fitted, saved and resumed as one.

A bake (:func:`lobelight.fit.fit_mesh`) cuts the mesh's vertices into :class:`Chunk` s
(:func:`plan_chunks`) and runs them in the flood fill and again in the relaxation
(:func:`compute_chunk`), in groups whose chunks run at once (:mod:`lobelight.fit._runner`); its
checkpoint counts the chunks done (:mod:`._checkpoint`). Each chunk reads and writes the bake's
arrays (:class:`BakeState`) at its own vertices, and reads them at their neighbours:

- In the flood fill with one Gaussian per view there is no spatial term, and a chunk reads
  nothing of other chunks: chunks are independent and may run in any order, or at once.
- With two or more, a chunk's vertices start from, and are held by ``S`` against, the
  neighbours fitted in the wavefronts before its own (:func:`fit_inputs`' ``readable``): the
  chunks of one wavefront run at once, the wavefronts in order.
- The relaxation refits each chunk against all neighbours' Gaussians as its group found them.

A chunk's work is split in three, so that it may run on another thread or in another process
(:mod:`lobelight.fit._cluster`): what it reads of the bake's state is gathered first
(:func:`fit_inputs`, :func:`refit_inputs`: its processed neighbours' Gaussians, tensors of the
chunk's size), the work itself reads nothing else of the state and returns a
:class:`ChunkResult` (:func:`compute_fit`, :func:`compute_refit`), which is then written into
the state (:meth:`ChunkResult.apply`).

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
from ._data import CAP_SAMPLES, GLOBAL_SAMPLES, gather, lobe_estimate
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
    "ChunkResult",
    "Neighbours",
    "RefitInputs",
    "compute_chunk",
    "compute_fit",
    "compute_refit",
    "fit_inputs",
    "plan_chunks",
    "refit_inputs",
]

#: Processed neighbours a vertex's S term reads (the rest of a high-valence fan is dropped).
MAX_NEIGHBOURS = 8
#: Levenberg-Marquardt iterations of a chunk's fit in the flood fill, and in the relaxation's
#: refit, which starts from the flood fill's converged lobes.
FILL_ITERATIONS = 14
REFIT_ITERATIONS = 8
#: Face resolution of the cube map of directions the self-shadowed diffuse transfer sums over.
DIFFUSE_RES = 16
_BITS = 1 << torch.arange(8, dtype=torch.uint8)


def pack_bits(x: torch.Tensor) -> torch.Tensor:
    """(..., K) bool as (..., ceil(K / 8)) uint8, eight to a byte, the first in the lowest bit."""
    k = x.shape[-1]
    pad = torch.nn.functional.pad(x.to(torch.uint8), (0, -k % 8))
    bytes8 = pad.reshape(*x.shape[:-1], -1, 8) * _BITS.to(x.device)
    return bytes8.sum(-1, dtype=torch.uint8)


def unpack_bits(p: torch.Tensor, k: int) -> torch.Tensor:
    """The (..., k) bool that :func:`pack_bits` packed into ``p`` (..., ceil(k / 8))."""
    bits = (p[..., None] & _BITS.to(p.device)) != 0
    return bits.reshape(*p.shape[:-1], -1)[..., :k]


@dataclass(frozen=True)
class Chunk:
    """Vertices fitted together: the unit of work that a bake runs, its checkpoint counts, and
    a resumed bake goes on after (module docstring).

    Attributes
    ----------
    index : its place in its pass, ``0..K-1``; seeds its indirect glossy paths
    vertices : (B,) int64 vertex ids, on the bake's device
    front : the flood fill's wavefront its vertices belong to (two or more Gaussians per
        view); 0 where chunks run across wavefronts (one Gaussian)
    """

    index: int
    vertices: torch.Tensor
    front: int = 0

    def generator(self, seed: int) -> torch.Generator:
        """The random generator of the chunk's indirect glossy paths in a bake of ``seed``."""
        return torch.Generator().manual_seed(seed * 1_000_003 + 2 * self.index)


def plan_chunks(layers: list[torch.Tensor], *, n: int, batch: int, device) -> list[Chunk]:
    """The chunks of a bake, in the order they start: the flood fill's wavefronts ``layers``
    (:func:`lobelight.fit.wavefronts`) cut into chunks of at most ``batch`` vertices. With
    ``n = 1`` Gaussian per view there is no spatial term and a chunk runs across wavefronts;
    with ``n >= 2`` a chunk stays inside one wavefront."""
    if n == 1:  # no spatial term: any vertices may share a chunk
        order = torch.cat(layers)
        parts = [(order[s : s + batch], 0) for s in range(0, order.numel(), batch)]
    else:
        parts = [
            (f[s : s + batch], k) for k, f in enumerate(layers) for s in range(0, f.numel(), batch)
        ]
    return [Chunk(i, p.to(device), k) for i, (p, k) in enumerate(parts)]


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
    lobe_axis : (V, J, 3), lobe_lam, lobe_scale : (V, J), the material's lobe estimate
        (:func:`lobelight.fit.lobe_estimate`) that sized the flood fill's samples, kept so
        that the relaxation samples the same directions without estimating it again
    vis_cap : (V, J, CAP_SAMPLES / 8) and vis_global : (V, GLOBAL_SAMPLES / 8) uint8, the
        visibility of those samples (:func:`pack_bits`), kept so that the relaxation casts no
        ray
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
    lobe_axis: torch.Tensor
    lobe_lam: torch.Tensor
    lobe_scale: torch.Tensor
    vis_cap: torch.Tensor
    vis_global: torch.Tensor

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
            lobe_axis=torch.zeros(v, j, 3, device=device),
            lobe_lam=torch.zeros(v, j, device=device),
            lobe_scale=torch.full((v, j), 2.0, device=device),
            vis_cap=torch.zeros(v, j, -(-CAP_SAMPLES // 8), dtype=torch.uint8, device=device),
            vis_global=torch.zeros(v, -(-GLOBAL_SAMPLES // 8), dtype=torch.uint8, device=device),
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
    seed : the bake's;  state : BakeState, or None in a process that only computes chunks
        (a worker of :mod:`lobelight.fit._cluster`)
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
    state: BakeState | None
    diffuse_dirs: torch.Tensor
    diffuse_weights: torch.Tensor
    flips_before: tuple[int, int] = (0, 0)
    flips_after: tuple[int, int] = (0, 0)
    indirect_seconds: float = 0.0

    @classmethod
    def start(
        cls,
        tr: Transport,
        views: torch.Tensor,
        *,
        n: int,
        weights: Weights,
        indirect_paths,
        seed,
        state: bool = True,
    ) -> Bake:
        """A bake of ``tr``'s mesh at ``views`` (on ``tr``'s device), before any chunk; without
        a state where ``state`` is False."""
        dev = tr.device
        v, j = tr.mesh.n_vertices, views.shape[0]
        return cls(
            transport=tr,
            views=views,
            nbr_views=sphere.geodesic_neighbor_table(device=dev),
            n=n,
            weights=weights,
            indirect_paths=indirect_paths,
            seed=seed,
            state=BakeState.empty(v, j, n, device=dev) if state else None,
            diffuse_dirs=cubemap.texel_directions(DIFFUSE_RES, device=dev).reshape(-1, 3),
            diffuse_weights=cubemap.texel_solid_angles(DIFFUSE_RES, device=dev).reshape(-1),
        )

    @property
    def mesh(self) -> Mesh:
        return self.transport.mesh


@dataclass(eq=False)
class Neighbours:
    """The processed neighbours a chunk's vertices read (the spatial term, a start): up to
    :data:`MAX_NEIGHBOURS` per vertex, with their Gaussians as the state held them.

    Attributes
    ----------
    ids : (B, Q) int64 vertex ids;  mask : (B, Q) bool, slots that hold a processed neighbour
    w, mu : (B, Q, J, N, 3) and lam : (B, Q, J, N), their Gaussians
    """

    ids: torch.Tensor
    mask: torch.Tensor
    w: torch.Tensor
    mu: torch.Tensor
    lam: torch.Tensor

    @classmethod
    def read(cls, bake: Bake, vidx: torch.Tensor, readable: torch.Tensor) -> Neighbours:
        """The neighbours of vertices ``vidx`` (B,) among ``readable`` (V,) bool."""
        ids, mask = _processed_neighbours(bake.mesh, vidx, readable)
        st = bake.state
        return cls(ids, mask, st.w[ids], st.mu[ids], st.lam[ids])

    def rows(self, keep: torch.Tensor) -> Neighbours:
        """The neighbours of the vertices ``keep`` (a (B,) bool or an index) selects."""
        return Neighbours(*(getattr(self, f.name)[keep] for f in fields(self)))

    def first(self) -> Gaussians:
        """Each vertex's first neighbour's Gaussians (w (B, J, N, 3), ...)."""
        return Gaussians(self.w[:, 0], self.mu[:, 0], self.lam[:, 0])

    def to(self, device) -> Neighbours:
        return Neighbours(*(getattr(self, f.name).to(device) for f in fields(self)))


@dataclass(eq=False)
class RefitInputs:
    """What the relaxation's refit of a chunk reads of the state: its glossy vertices (B,),
    their Gaussians (w (B, J, N, 3), ...), data error (B,), lobe estimate (axis (B, J, 3),
    sharpness and scale (B, J)) and their samples' visibility (packed, :class:`BakeState`'s
    ``vis_cap`` and ``vis_global``), and their neighbours."""

    vertices: torch.Tensor
    old: Gaussians
    derr: torch.Tensor
    lobe: tuple[torch.Tensor, torch.Tensor, torch.Tensor]
    visibility: tuple[torch.Tensor, torch.Tensor]
    neighbours: Neighbours

    def to(self, device) -> RefitInputs:
        o = self.old
        return RefitInputs(
            self.vertices.to(device),
            Gaussians(o.w.to(device), o.mu.to(device), o.lam.to(device)),
            self.derr.to(device),
            tuple(x.to(device) for x in self.lobe),
            tuple(x.to(device) for x in self.visibility),
            self.neighbours.to(device),
        )


@dataclass(eq=False)
class ChunkResult:
    """What a chunk's work computed: new values of some of :class:`BakeState`'s arrays at its
    vertices.

    Attributes
    ----------
    index : the chunk's;  vertices : (B,) int64 the vertices written
    arrays : :class:`BakeState` field name -> (B, ...) values at ``vertices``
    indirect_seconds : time spent tracing indirect glossy paths
    """

    index: int
    vertices: torch.Tensor
    arrays: dict[str, torch.Tensor]
    indirect_seconds: float = 0.0

    def to(self, device) -> ChunkResult:
        arrays = {k: v.to(device) for k, v in self.arrays.items()}
        return ChunkResult(self.index, self.vertices.to(device), arrays, self.indirect_seconds)

    def nonfinite(self) -> torch.Tensor:
        """(k,) the vertices where any value is NaN or infinite."""
        bad = torch.zeros(self.vertices.shape, dtype=torch.bool, device=self.vertices.device)
        for v in self.arrays.values():
            if v.is_floating_point():
                bad |= ~v.isfinite().reshape(v.shape[0], -1).all(1)
        return self.vertices[bad]

    def apply(self, bake: Bake) -> None:
        """Write the values into ``bake``'s state."""
        state = bake.state.arrays()
        for k, v in self.arrays.items():
            state[k][self.vertices] = v
        bake.indirect_seconds += self.indirect_seconds


def fit_inputs(bake: Bake, chunk: Chunk, readable: torch.Tensor | None = None):
    """What the flood fill of ``chunk`` reads of the state: the processed neighbours of its
    vertices (with two or more Gaussians per view; None with one). A neighbour is processed
    where the flood fill has reached it, it is glossy, it is not in the chunk, and it is in
    ``readable`` (V,) bool where given."""
    if bake.n == 1:
        return None
    st = bake.state
    avail = st.done & st.glossy
    avail[chunk.vertices] = False  # none may read another's unfitted state (zero means)
    if readable is not None:
        avail &= readable
    return Neighbours.read(bake, chunk.vertices, avail)


def compute_fit(bake: Bake, chunk: Chunk, nbrs: Neighbours | None) -> ChunkResult:
    """The flood fill's work on a chunk, reading nothing of the state but ``nbrs``
    (:func:`fit_inputs`): its vertices' self-shadowed diffuse transfer, their indirect glossy
    Gaussian, and their direct glossy Gaussians fitted against the processed neighbours (from
    the start that suits each one's data best, :func:`_better_start`)."""
    vidx, n = chunk.vertices, bake.n
    out = _first_visit(bake, vidx)
    gl = out["glossy"]
    if not bool(gl.any()):
        return ChunkResult(chunk.index, vidx, out)
    lobe = tuple(out[k][gl] for k in ("lobe_axis", "lobe_lam", "lobe_scale"))
    seconds = _indirect(bake, chunk, vidx[gl], out, gl) if bake.indirect_paths > 0 else 0.0
    # the relaxation samples the transport again rather than keeping it: all of it
    # (V x J x ~700 samples x 7 floats) would not fit in memory on a large mesh
    data = gather(bake.transport, vidx[gl], bake.views, lobe=lobe)
    out["vis_cap"][gl] = pack_bits(data.visibility[0])
    out["vis_global"][gl] = pack_bits(data.visibility[1])
    data = data.compact()
    init, nb = None, None
    if nbrs is not None:
        nb = nbrs.rows(gl)
        if bool(nb.mask[:, 0].all()):
            # start from a processed neighbour's Gaussians (the same correspondence of lobes)
            # where they fit this vertex's data, from the data's own guess where they do not
            init = _better_start(data, n, bake.nbr_views, nb.first())
    g, terms = _fit(bake, data, nb, init, iters=FILL_ITERATIONS)
    out["mu"][gl], out["lam"][gl], out["w"][gl] = g.mu, g.lam, g.w
    out["derr"][gl] = terms["D"]
    return ChunkResult(chunk.index, vidx, out, seconds)


def compute_chunk(stage: str, bake: Bake, chunk: Chunk, inputs) -> ChunkResult:
    """One chunk's work in ``stage``: the flood fill's (``"fit"``, :func:`compute_fit` on
    :func:`fit_inputs`) or the relaxation's (``"relax"``, :func:`compute_refit` on
    :func:`refit_inputs`)."""
    if stage == "fit":
        return compute_fit(bake, chunk, inputs)
    return compute_refit(bake, chunk, inputs)


def refit_inputs(bake: Bake, chunk: Chunk) -> RefitInputs:
    """What the relaxation's refit of ``chunk`` reads of the state: its glossy vertices, their
    Gaussians, data error, lobe estimate and samples' visibility, and their glossy
    neighbours."""
    st = bake.state
    vidx = chunk.vertices
    vidx = vidx[st.glossy[vidx]]
    lobe = (st.lobe_axis[vidx], st.lobe_lam[vidx], st.lobe_scale[vidx])
    vis = (st.vis_cap[vidx], st.vis_global[vidx])
    nbrs = Neighbours.read(bake, vidx, st.glossy)
    return RefitInputs(vidx, st.gaussians(vidx), st.derr[vidx], lobe, vis, nbrs)


def compute_refit(bake: Bake, chunk: Chunk, inputs: RefitInputs) -> ChunkResult:
    """The relaxation's work on a chunk, reading nothing of the state but ``inputs``: its
    glossy vertices refitted from their Gaussians with ``S`` against all their neighbours,
    keeping the new lobes only where they add no flipped pair."""
    vidx, old, nb = inputs.vertices, inputs.old, inputs.neighbours
    if vidx.numel() == 0:
        return ChunkResult(chunk.index, vidx, {})
    # the flood fill's samples again: the same lobe estimate sizes the same cap, whose
    # visibility the flood fill kept
    vis = (
        unpack_bits(inputs.visibility[0], CAP_SAMPLES),
        unpack_bits(inputs.visibility[1], GLOBAL_SAMPLES),
    )
    data = gather(bake.transport, vidx, bake.views, lobe=inputs.lobe, visibility=vis).compact()
    g, terms = _fit(bake, data, nb, old, iters=REFIT_ITERATIONS)
    # The refit keeps a vertex's new lobes only where they add no flipped pair against its
    # neighbours, counting all pairs and separated ones: S alone does not hold the lobes (its
    # cubic penalty vanishes for lobes a few tenths of a radian apart), and unguarded the pass
    # adds flips and knots the lobes into arrangements no reordering can undo (docs/method.md)
    nbr = Gaussians(nb.w, nb.mu, nb.lam)
    keep = torch.ones(vidx.numel(), dtype=torch.bool, device=vidx.device)
    for sep in (0.0, SEPARATED):
        keep &= vertex_flips(g, nbr, nb.mask, min_separation=sep) <= vertex_flips(
            old, nbr, nb.mask, min_separation=sep
        )
    out = {
        "w": torch.where(keep[:, None, None, None], g.w, old.w),
        "mu": torch.where(keep[:, None, None, None], g.mu, old.mu),
        "lam": torch.where(keep[:, None, None], g.lam, old.lam),
        "derr": torch.where(keep, terms["D"], inputs.derr),
    }
    return ChunkResult(chunk.index, vidx, out)


def _first_visit(bake: Bake, vidx: torch.Tensor) -> dict[str, torch.Tensor]:
    """A chunk's vertices reached by the flood fill: the state's arrays at them as a chunk's
    result starts them (:meth:`BakeState.empty`'s values), with their diffuse transfer, which
    of them are glossy, zero weights for the others, and the lobe estimate of all of them
    (:func:`lobelight.fit.lobe_estimate`)."""
    tr = bake.transport
    out = BakeState.empty(vidx.numel(), bake.views.shape[0], bake.n, device=vidx.device).arrays()
    del out["bounce"]  # the interreflection's, later
    out["diffuse"] = tr.diffuse(vidx, bake.diffuse_dirs, bake.diffuse_weights)
    out["done"][:] = True
    axis, lam_est, scale = lobe_estimate(tr, vidx, bake.views)
    gl = (lam_est > 0).any(1)
    out["glossy"] = gl
    # no glossy transport: zero weights (as started), means at the lobe axis
    out["mu"][~gl] = axis[~gl][:, :, None].expand(-1, -1, bake.n, -1)
    out["lobe_axis"], out["lobe_lam"], out["lobe_scale"] = axis, lam_est, scale
    return out


def _indirect(bake: Bake, chunk: Chunk, vidx: torch.Tensor, out, gl) -> float:
    """The indirect glossy Gaussian of the chunk's glossy vertices ``vidx`` (rows ``gl`` of
    ``out``); returns the seconds it took."""
    t = time.perf_counter()
    ig = bake.transport.indirect_lobes(
        vidx, bake.views, paths=bake.indirect_paths, generator=chunk.generator(bake.seed)
    )
    out["ind_w"][gl], out["ind_mu"][gl], out["ind_lam"][gl] = ig.w, ig.mu, ig.lam
    return time.perf_counter() - t


def _fit(bake: Bake, data, nbrs: Neighbours | None, init: Gaussians | None, *, iters: int):
    """:func:`lobelight.fit.fit_batch` of a chunk's data in ``iters`` iterations, ``S`` against
    the neighbours ``nbrs`` (with two or more Gaussians per view)."""
    spatial = bake.n > 1 and nbrs is not None
    return fit_batch(
        data,
        bake.n,
        bake.nbr_views,
        weights=bake.weights,
        init=init,
        iters=iters,
        nbr_mu=nbrs.mu if spatial else None,  # (B, Q, J, N, 3)
        nbr_mask=nbrs.mask if spatial else None,
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
