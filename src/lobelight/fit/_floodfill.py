"""Fitting a whole mesh: the flood fill of Green et al. 2006 (section 4.2), by wavefronts.

The paper fits one vertex at a time, starting from a seed and moving to neighbours, so that the
spatial term ``S`` always compares with vertices already fitted. Here the fill proceeds by
breadth-first *wavefronts*: wavefront ``k`` holds the vertices at graph distance ``k`` from their
component's seed. Their ``S`` terms only read earlier wavefronts, so a wavefront is one batch
(split into chunks of bounded memory), fitted at once on any device.

Beyond the paper, a relaxation pass revisits every vertex once all are fitted, this time with
``S`` against all its neighbours (the paper's own proposal against "Gaussian flipping"), then
reorders the Gaussians of every (vertex, view) over the whole mesh where that lowers the
flipped neighbour pairs and the view coherence together (:mod:`._relax`); the number of
flipped neighbour pairs is reported before and after.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from .._cache import UNREADABLE
from .._io import atomic_writer
from ..errors import InputError
from ..geometry import cubemap, sphere
from ..scene import Mesh, Scene
from ..transport import BOUNCES, DIFFUSE_ORDER, INDIRECT_PATHS, Transport, diffuse_interreflection
from ._data import gather, lobe_estimate
from ._objective import Weights, flip_count, mixture, solve_weights
from ._optimize import Gaussians, fit_batch, initial_guess
from ._relax import live_gaussians, reorder_mesh, separated_pairs, vertex_flips

__all__ = ["MeshFit", "count_flips", "fit_mesh", "wavefronts"]

logger = logging.getLogger(__name__)

#: Face resolution of the cube map the indirect glossy paths are binned on: at 16 paths per view,
#: 8^2 halves the light's error per (vertex, view) against 16^2 bins (docs/method.md).
INDIRECT_RES = 8
#: Processed neighbours a vertex's S term reads (the rest of a high-valence fan is dropped).
MAX_NEIGHBOURS = 8
#: Lobes this many widths apart or more have an arrangement that a flip visibly breaks; closer
#: ones (a sharp core on a broad skirt) are ordered by width, and the direction between them is
#: noise (:func:`count_flips`).
SEPARATED = 0.5


def wavefronts(mesh: Mesh) -> list[torch.Tensor]:
    """Breadth-first layers of the vertex graph, one seed per connected component.

    The seed of a component is its lowest-numbered vertex (deterministic). Isolated vertices
    (in no triangle) cannot occur: meshes are cleaned of unreferenced vertices.

    Returns
    -------
    list of (n_k,) int64 vertex ids; every vertex appears exactly once
    """
    off, nb = mesh.adjacency
    off, nb = off.cpu(), nb.cpu()
    v = mesh.n_vertices
    layer = torch.full((v,), -1, dtype=torch.int64)
    counts = off[1:] - off[:-1]
    out: list[torch.Tensor] = []
    k = 0
    while True:
        todo = (layer < 0).nonzero()
        if todo.numel() == 0:
            break
        seed = todo[0]
        # new component: its layers are appended after the previous component's
        frontier = seed
        layer[frontier] = k
        while frontier.numel():
            out.append(frontier)
            # all neighbours of the frontier, vectorised through the CSR arrays
            starts = off[frontier]
            lens = counts[frontier]
            idx = torch.repeat_interleave(starts - torch.cumsum(lens, 0) + lens, lens)
            idx = idx + torch.arange(int(lens.sum()))
            cand = torch.unique(nb[idx])
            cand = cand[layer[cand] < 0]
            k += 1
            layer[cand] = k
            frontier = cand
    return out


@dataclass(eq=False)
class MeshFit:
    """The fitted model of every vertex, and how the fit went.

    Attributes
    ----------
    gaussians : Gaussians of all V vertices (w (V, J, N, 3), mu (V, J, N, 3), lam (V, J, N)):
        the fitted direct glossy lobes, then ``indirect_gaussians`` of indirect glossy
    indirect_gaussians : trailing Gaussians per view that hold the indirect glossy transport
        (:meth:`lobelight.transport.Transport.indirect_lobes`; 0 without indirect paths, or
        where none bounced off the object: a convex object)
    diffuse : (V, 25, 3) diffuse SH transfer, self-shadowed plus ``bounces`` bounces of
        interreflection
    views : (J, 3) view directions
    data_error : (V,) relative L2 error squared of the direct glossy fit (D)
    bounce : (V, 25, 3) the interreflected part of ``diffuse`` (None without bounces): the
        renderer lights it with the sun too, which the self-shadowed part sees per pixel
    flips_before, flips_after : flipped (edge, view) pairs before and after relaxation
    separated_flips_before, separated_flips_after : the same among lobes at least
        ``SEPARATED`` widths apart (:func:`count_flips`)
    seconds : wall time per stage: ``fit`` (including ``indirect_glossy``, the path tracing of
        indirect glossy inside it), ``relax``, ``interreflection``
    """

    gaussians: Gaussians
    diffuse: torch.Tensor
    views: torch.Tensor
    data_error: torch.Tensor
    bounce: torch.Tensor | None = None
    flips_before: int = 0
    flips_after: int = 0
    separated_flips_before: int = 0
    separated_flips_after: int = 0
    seconds: dict[str, float] = field(default_factory=dict)
    indirect_gaussians: int = 0


def _edges(mesh: Mesh) -> torch.Tensor:
    off, nb = mesh.adjacency
    ids = torch.arange(mesh.n_vertices, device=nb.device)
    src = torch.repeat_interleave(ids, off[1:] - off[:-1])
    e = torch.stack([src, nb], 1)
    return e[e[:, 0] < e[:, 1]]  # (E, 2) each undirected edge once


def _flips(mesh: Mesh, g: Gaussians) -> tuple[int, int]:
    """Flipped pairs, all and among separated lobes."""
    return count_flips(mesh, g), count_flips(mesh, g, min_separation=SEPARATED)


def count_flips(
    mesh: Mesh, g: Gaussians, *, live_fraction: float = 0.05, min_separation: float = 0.0
) -> int:
    """Flipped (edge, view) pairs: adjacent vertices whose Gaussians swap arrangement in a view
    (see :func:`lobelight.fit.flip_count`), among Gaussians that carry light: at least
    ``live_fraction`` of the light of the view's brightest Gaussian (``w int G``, summed over
    channels).

    ``min_separation`` > 0 counts only pairs of Gaussians whose means lie at least that many
    widths (``sigma`` of the wider) apart at both vertices: closer lobes have no arrangement to
    speak of, the direction between them being set by noise in the data.
    """
    if g.mu.shape[2] < 2:
        return 0
    e = _edges(mesh).to(g.mu.device)
    live = live_gaussians(g, live_fraction)  # (V, J, N)
    apart = separated_pairs(g, min_separation) if min_separation > 0 else None  # (V, J, P)
    total = 0
    for s in range(0, e.shape[0], 4096):  # bounded memory
        es = e[s : s + 4096]
        a, b = es[:, 0], es[:, 1]
        active = live[a].any(-1) & live[b].any(-1)
        ok = None if apart is None else apart[a] & apart[b]
        total += int(flip_count(g.mu[a], g.mu[b], active, live[a], live[b], ok).sum())
    return total


def default_batch(device, n: int) -> int:
    """Vertices per chunk: 64 on the CPU (larger chunks gain nothing there); on a GPU as many
    as fit in half its free memory (about 61.8K samples per vertex, each ~90 bytes plus ~100 per
    Gaussian, with 1.5x for temporaries), 64 to 2048 in steps of 64."""
    dev = torch.device(device)
    if dev.type != "cuda":
        return 64
    free, _ = torch.cuda.mem_get_info(dev)
    per_vertex = 1.5 * 92 * 672 * (90 + 100 * n)
    return int(min(2048, max(64, (0.5 * free / per_vertex) // 64 * 64)))


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
    neighbouring vertices' mirror directions differ by tens of degrees (60 on the default knot),
    so a sharp lobe taken over from a neighbour can miss this vertex's data altogether; with no
    overlap the fit has no gradient and stays there. Measured on the knot with two Gaussians:
    always starting from the neighbour ends at mean relative error 0.178 (one Gaussian: 0.173),
    never starting from it at 0.156.
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


def fit_mesh(
    scene: Scene,
    *,
    n: int = 1,
    views: torch.Tensor | None = None,
    weights: Weights | None = None,
    batch: int | None = None,
    indirect_paths: int = INDIRECT_PATHS,
    bounces: int = BOUNCES,
    relax: bool = True,
    device=None,
    progress: Callable[[str, int, int], None] | None = None,
    seed: int = 0,
    checkpoint: str | os.PathLike | None = None,
    checkpoint_every: float = 30.0,
    shadows: bool = True,
) -> MeshFit:
    """Fit N Gaussians per view to every vertex's direct glossy transport, one more to its
    indirect glossy transport, and its SH diffuse transfer with interreflection.

    The indirect glossy Gaussian comes from the paths' light, mean direction and median angle
    (:meth:`lobelight.transport.Transport.indirect_lobes`), kept apart from the fitted ones: it
    integrates the whole lighting, the sun included, where a renderer shades the sun's direct
    glossy light per pixel and the fitted lobes see the map without it (the light a mirror
    shows of the sun in another mirror); folded into a fitted lobe, that light would light the
    direct reflection's place instead.

    Parameters
    ----------
    scene : Scene;  n : Gaussians per view (1-3);  views : (J, 3), default the 92 geodesic views
    batch : vertices fitted at once (default :func:`default_batch`: 64 on the CPU, as many as
        half the free memory holds on a GPU); memory about ``batch x J x 700 x (90 + 100 n)``
        bytes. With ``n = 1`` there is no spatial term, vertices do not depend on each other
        and chunks run across wavefronts; with ``n >= 2`` a chunk stays inside one wavefront
    indirect_paths : paths per vertex and view for indirect glossy (0: direct glossy only,
        no indirect Gaussian)
    bounces : bounces of diffuse interreflection added to the SH transfer once the glossy fit
        is done (:func:`lobelight.transport.diffuse_interreflection`, carrying the light of
        the hit points' diffuse and fitted glossy parts; 0: self-shadowed only)
    relax : run the relaxation pass (for n >= 2; nothing to relax for n = 1)
    progress : called as ``progress(stage, done, total)`` after each chunk
    checkpoint : a file to save the state to (atomically, at most every ``checkpoint_every``
        seconds and at the end of each stage); a run that finds a checkpoint of the same scene
        and settings resumes from it and gives the same result as an uninterrupted run (the
        indirect paths of each chunk are seeded by the chunk, not by the order of the run);
        the caller removes it once the finished model is written
    shadows : False fits transport without visibility (a baseline: prefiltered environment
        mapping)

    Returns
    -------
    MeshFit
    """
    weights = Weights() if weights is None else weights
    tr = Transport(scene, device=device, shadows=shadows)
    dev = tr.device
    batch = default_batch(dev, n) if batch is None else int(batch)
    if batch < 1:
        raise InputError("batch", f"must be a positive number of vertices, got {batch}")
    for name, value in (("indirect_paths", indirect_paths), ("bounces", bounces)):
        if isinstance(value, bool) or int(value) != value or value < 0:
            raise InputError(name, f"must be a whole number >= 0 (0: off), got {value!r}")
    indirect_paths, bounces = int(indirect_paths), int(bounces)
    mesh = tr.mesh
    views = sphere.geodesic_views(device=dev) if views is None else views.to(dev)
    nbr_views = sphere.geodesic_neighbor_table(device=dev)
    v, j = mesh.n_vertices, views.shape[0]
    mu = torch.zeros(v, j, n, 3, device=dev)
    lam = torch.ones(v, j, n, device=dev)
    w = torch.zeros(v, j, n, 3, device=dev)
    # the indirect glossy Gaussian of each (vertex, view)
    ind_w = torch.zeros(v, j, 1, 3, device=dev)
    ind_mu = torch.tensor([0.0, 1.0, 0.0], device=dev).expand(v, j, 1, 3).clone()
    ind_lam = torch.ones(v, j, 1, device=dev)
    derr = torch.zeros(v, device=dev)
    diffuse = torch.zeros(v, DIFFUSE_ORDER**2, 3, device=dev)
    bounce = torch.zeros(v, DIFFUSE_ORDER**2, 3, device=dev)
    done = torch.zeros(v, dtype=torch.bool, device=dev)
    # vertices whose material has a glossy lobe (BRDF samples carry weight; known once a
    # vertex is processed): the others have no glossy transport at all, are given zero weights
    # without a fit, and are nobody's neighbour in the spatial term (their means are arbitrary)
    glossy = torch.zeros(v, dtype=torch.bool, device=dev)
    ddirs = cubemap.texel_directions(16, device=dev).reshape(-1, 3)
    dom = cubemap.texel_solid_angles(16, device=dev).reshape(-1)
    t0 = time.perf_counter()
    layers = wavefronts(mesh)
    if n == 1:  # no spatial term: any vertices may share a chunk
        order = torch.cat(layers)
        chunks = [order[s : s + batch].to(dev) for s in range(0, v, batch)]
    else:
        chunks = [f[s : s + batch].to(dev) for f in layers for s in range(0, f.numel(), batch)]
    state = {
        "mu": mu,
        "lam": lam,
        "w": w,
        "derr": derr,
        "diffuse": diffuse,
        "bounce": bounce,
        "done": done,
        "glossy": glossy,
        "ind_w": ind_w,
        "ind_mu": ind_mu,
        "ind_lam": ind_lam,
    }
    key = _settings_key(
        scene,
        n,
        views,
        weights,
        batch,
        (indirect_paths, "indirect-gaussian", bounces, shadows),
        relax,
        seed,
    )
    ckpt = Path(checkpoint) if checkpoint is not None else None
    start = _resume(ckpt, key, state) if ckpt is not None else _FRESH
    stage0 = _STAGES.index(start[0])  # the stage the run (re)starts in
    last_save = time.perf_counter()
    before = start[2]  # (all flipped pairs, those of separated lobes), after the flood fill
    after = start[3]  # the same after the relaxation
    t_indirect = 0.0

    def save_state(stage: str, nxt: int, *, force: bool = False) -> None:
        nonlocal last_save
        if ckpt is None or (not force and time.perf_counter() - last_save < checkpoint_every):
            return
        _save_checkpoint(ckpt, key, stage, nxt, state, before, after)
        last_save = time.perf_counter()

    def fit_chunk(i: int, vidx: torch.Tensor, *, all_neighbours: bool) -> None:
        nonlocal t_indirect
        lobe = None
        if not all_neighbours:
            diffuse[vidx] = tr.diffuse(vidx, ddirs, dom)
            done[vidx] = True
            axis, lam_est, scale = lobe_estimate(tr, vidx, views)
            gl = (lam_est > 0).any(1)
            glossy[vidx] = gl
            rest = ~gl
            if bool(rest.any()):  # no glossy transport: zero weights, means at the lobe axis
                mu[vidx[rest]] = axis[rest][:, :, None].expand(-1, -1, n, -1)
                lam[vidx[rest]], w[vidx[rest]], derr[vidx[rest]] = 1.0, 0.0, 0.0
            lobe = (axis[gl], lam_est[gl], scale[gl])
        vidx = vidx[glossy[vidx]]
        if vidx.numel() == 0:
            return
        if indirect_paths > 0 and not all_neighbours:
            # seeded by chunk, so a resumed run draws the same paths
            gen = torch.Generator().manual_seed(seed * 1_000_003 + 2 * i)
            t = time.perf_counter()
            ig = tr.indirect_lobes(vidx, views, paths=indirect_paths, generator=gen)
            ind_w[vidx], ind_mu[vidx], ind_lam[vidx] = ig.w, ig.mu, ig.lam
            t_indirect += time.perf_counter() - t
        # the relaxation pass samples the transport again rather than keeping it: all of it
        # (V x J x ~700 samples x 7 floats, 17 GB for 10K vertices) would not fit in memory
        data = gather(tr, vidx, views, lobe=lobe)
        if all_neighbours:
            avail = glossy
        else:
            # the chunk's own vertices are fitted together, now: none may read another's
            # unfitted state (zero means) as a processed neighbour, for S or as a start
            avail = done & glossy
            avail[vidx] = False
        ids, mask = _processed_neighbours(mesh, vidx, avail)
        nbr_mu = mu[ids] if n > 1 else None  # (B, Q, J, N, 3)
        init = None
        if all_neighbours:  # relaxation starts from the current fit
            init = Gaussians(w[vidx], mu[vidx], lam[vidx])
        elif n > 1 and bool(mask[:, 0].all()):
            # start from a processed neighbour's Gaussians (the same correspondence of lobes)
            # where they fit this vertex's data, from the data's own guess where they do not
            first = ids[:, 0]
            init = _better_start(data, n, nbr_views, Gaussians(w[first], mu[first], lam[first]))
        g, terms = fit_batch(
            data,
            n,
            nbr_views,
            weights=weights,
            init=init,
            nbr_mu=nbr_mu,
            nbr_mask=mask if n > 1 else None,
        )
        if all_neighbours:
            # The refit keeps a vertex's new lobes only where they add no flipped pair against
            # its neighbours, counting all pairs and separated ones: S alone does not hold the
            # lobes (its cubic penalty vanishes for lobes a few tenths of a radian apart), and
            # unguarded the pass adds flips (sphere:2: 292 -> 339) and knots the lobes into
            # arrangements no reordering can undo (docs/method.md)
            old = Gaussians(w[vidx], mu[vidx], lam[vidx])
            nbr = Gaussians(w[ids], mu[ids], lam[ids])
            keep = torch.ones(vidx.numel(), dtype=torch.bool, device=dev)
            for sep in (0.0, SEPARATED):
                keep &= vertex_flips(g, nbr, mask, min_separation=sep) <= vertex_flips(
                    old, nbr, mask, min_separation=sep
                )
            g = Gaussians(
                torch.where(keep[:, None, None, None], g.w, old.w),
                torch.where(keep[:, None, None, None], g.mu, old.mu),
                torch.where(keep[:, None, None], g.lam, old.lam),
            )
            terms["D"] = torch.where(keep, terms["D"], derr[vidx])
        mu[vidx], lam[vidx], w[vidx] = g.mu, g.lam, g.w
        derr[vidx] = terms["D"]

    # stages: the flood fill ("fit", by chunks), the relaxation ("relax", by chunks, then the
    # reordering), the diffuse interreflection ("interreflection", one step: it needs every
    # vertex's self-shadowed transfer and final Gaussians), then "done"
    begin = start[1] if stage0 == 0 else len(chunks)
    for i in range(begin, len(chunks)):
        fit_chunk(i, chunks[i], all_neighbours=False)
        save_state("fit", i + 1, force=i + 1 == len(chunks))
        if progress is not None:
            progress("fit", i + 1, len(chunks))
    t1 = time.perf_counter()
    if stage0 == 0:
        before = _flips(mesh, Gaussians(w, mu, lam))
        after = before
    if relax and n > 1 and stage0 <= 1:
        begin = start[1] if stage0 == 1 else 0
        for i in range(begin, len(chunks)):
            fit_chunk(i, chunks[i], all_neighbours=True)
            save_state("relax", i + 1, force=False)
            if progress is not None:
                progress("relax", i + 1, len(chunks))
        # then the order of each vertex's Gaussians over the whole mesh, now that every
        # neighbour is final (the refit above moves lobes, and adds flips on its own)
        g = reorder_mesh(mesh, Gaussians(w, mu, lam), nbr_views, weights=weights)
        w.copy_(g.w), mu.copy_(g.mu), lam.copy_(g.lam)
        after = _flips(mesh, g)
    if stage0 <= 1:
        save_state("interreflection", 0, force=True)
    t2 = time.perf_counter()
    if stage0 <= 2 and bounces > 0:
        # the hit points' glossy light comes from their Gaussians (direct and indirect
        # glossy): without it a diffuse floor by a metal wall lost 32-63 % of its light
        g = _with_indirect(Gaussians(w, mu, lam), ind_w, ind_mu, ind_lam)
        lobes = (views, g.w, g.mu, g.lam) if bool(glossy.any()) else None
        total = diffuse_interreflection(
            tr, diffuse, bounces=bounces, glossy=lobes, progress=progress
        )
        bounce.copy_(total - diffuse)
        diffuse.copy_(total)
        save_state("done", 0, force=True)
    t3 = time.perf_counter()
    return MeshFit(
        gaussians=_with_indirect(Gaussians(w, mu, lam), ind_w, ind_mu, ind_lam),
        indirect_gaussians=1 if bool((ind_w > 0).any()) else 0,
        diffuse=diffuse,
        views=views,
        data_error=derr,
        bounce=bounce if bounces > 0 else None,
        flips_before=before[0],
        flips_after=after[0],
        separated_flips_before=before[1],
        separated_flips_after=after[1],
        seconds={
            "fit": t1 - t0,
            "indirect_glossy": t_indirect,
            "relax": t2 - t1,
            "interreflection": t3 - t2,
        },
    )


# --------------------------------------------------------------------------------------------
# checkpoints: plain arrays in an npz (no pickle), written to a temporary name and renamed


def _with_indirect(g: Gaussians, w, mu, lam) -> Gaussians:
    """The fitted Gaussians with the indirect glossy one after them, where any path bounced
    off the object (a convex object, or a bake without indirect paths, has none)."""
    if not bool((w > 0).any()):
        return g
    return Gaussians(torch.cat([g.w, w], 2), torch.cat([g.mu, mu], 2), torch.cat([g.lam, lam], 2))


def _settings_key(scene, n, views, weights, batch, indirect_paths, relax, seed) -> str:
    """A digest of everything the fit's result depends on: geometry, materials and settings."""
    h = hashlib.sha256()
    for t in (scene.mesh.vertices, scene.mesh.faces, views):
        h.update(t.detach().cpu().contiguous().numpy().tobytes())
    h.update(json.dumps(scene.materials.to_dict(), sort_keys=True).encode())
    h.update(repr((n, weights, batch, indirect_paths, relax, seed)).encode())
    return h.hexdigest()


#: The stages of a fit, in order, as checkpoints name them.
_STAGES = ("fit", "relax", "interreflection", "done")
#: Where a run without a usable checkpoint starts: stage, next chunk, flips before and after.
_FRESH = ("fit", 0, (0, 0), (0, 0))


def _save_checkpoint(
    path: Path,
    key: str,
    stage: str,
    nxt: int,
    state: dict,
    flips_before: tuple[int, int],
    flips_after: tuple[int, int],
) -> None:
    arrays = {k: v.detach().cpu().numpy() for k, v in state.items()}
    meta = {
        "key": key,
        "stage": stage,
        "next": nxt,
        "flips_before": list(flips_before),
        "flips_after": list(flips_after),
    }
    arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)
    with atomic_writer(path) as f:
        np.savez(f, **arrays)


def _resume(path: Path, key: str, state: dict) -> tuple:
    """Load a matching checkpoint into ``state``; returns ``(stage, next chunk, flips before,
    flips after)``.

    A checkpoint of another scene or other settings is left alone and the bake starts over; a
    damaged one (cut short, bits flipped, fields of the wrong type, arrays of the wrong kind
    or not finite) is moved aside as ``NAME.corrupt`` with one warning, and the bake starts
    afresh: it never stands in the way of a bake.
    """
    fresh = _FRESH
    if not path.is_file():
        return fresh
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(bytes(z["meta"]).decode())
            if (
                not isinstance(meta, dict)
                or meta.get("key") != key
                or meta.get("stage") not in _STAGES
            ):
                return fresh  # another scene or other settings: start over
            position = _position(meta)
            loaded = {k: torch.from_numpy(z[k]) for k in state}
        for k, v in loaded.items():
            if v.shape != state[k].shape:
                return fresh
            if v.dtype != state[k].dtype or (v.is_floating_point() and not v.isfinite().all()):
                raise ValueError(f"{k}: {v.dtype} values, not finite {state[k].dtype} ones")
    except (*UNREADABLE, TypeError) as e:
        # damaged: kept aside for a look, never in the way of a bake
        aside = path.with_name(path.name + ".corrupt")
        os.replace(path, aside)
        logger.warning(
            "%s: unreadable checkpoint (%s), moved to %s; the bake starts afresh",
            path, type(e).__name__, aside.name,
        )  # fmt: skip
        return fresh
    for k, v in loaded.items():
        state[k].copy_(v.to(state[k].device))
    return position


def _position(meta: dict) -> tuple:
    """``(stage, next chunk, flips before, flips after)`` of a checkpoint's metadata; raises
    ValueError or TypeError where a field is not what a bake writes."""

    def count(x) -> int:
        if isinstance(x, bool) or not isinstance(x, int) or x < 0:
            raise ValueError(f"{x!r} is not a count")
        return x

    def pair(x) -> tuple[int, int]:
        if isinstance(x, int) and not isinstance(x, bool):  # a single count
            return count(x), 0
        a, b = x  # TypeError / ValueError for anything but a pair
        return count(a), count(b)

    return (
        str(meta["stage"]),
        count(meta["next"]),
        pair(meta.get("flips_before", [0, 0])),
        pair(meta.get("flips_after", [0, 0])),
    )
