"""Fitting a whole mesh: the flood fill of Green et al. 2006 (section 4.2), by wavefronts.

The paper fits one vertex at a time, starting from a seed and moving to neighbours, so that the
spatial term ``S`` always compares with vertices already fitted. Here the fill proceeds by
breadth-first *wavefronts*: wavefront ``k`` holds the vertices at graph distance ``k`` from their
component's seed. Their ``S`` terms read the vertices of earlier wavefronts, so a wavefront is
fitted in a few large batches, chunks of bounded memory (:mod:`._chunk`), each at once on any
device, and a wavefront's chunks side by side on the threads of this process or the workers of
a cluster (:mod:`._runner`). The bake's state is saved to a checkpoint between chunks
(:mod:`._checkpoint`).

Beyond the paper, a relaxation pass revisits every vertex once all are fitted, this time with
``S`` against all its neighbours (the paper's own proposal against "Gaussian flipping"), then
reorders the Gaussians of every (vertex, view) over the whole mesh where that lowers the
flipped neighbour pairs and the view coherence together (:mod:`._relax`); the number of
flipped neighbour pairs is reported before and after.
"""

from __future__ import annotations

import numbers
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import torch

from ..errors import InputError
from ..geometry import sphere
from ..scene import Mesh, Scene
from ..transport import BOUNCES, INDIRECT_PATHS, Transport, diffuse_interreflection
from ._checkpoint import Checkpoint, Position, settings_key
from ._chunk import Bake, Chunk, plan_chunks
from ._cluster import ClusterRun
from ._memory import MEMORY_GB, PeakMeter, plan_memory
from ._objective import Weights, flip_count
from ._optimize import Gaussians
from ._relax import SEPARATED, live_gaussians, reorder_mesh, separated_pairs
from ._runner import ChunkRun, ThreadRun

__all__ = ["MeshFit", "count_flips", "fit_mesh", "wavefronts"]


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
    peak_bytes : peak resident memory of the process per stage (``setup``: the transport and
        the plan, then ``fit``, ``relax``, ``interreflection``)
    batch : vertices fitted at once (chunks), from the memory budget
    chunks_at_once : chunks that ran side by side in this process (0 on a cluster)
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
    peak_bytes: dict[str, int] = field(default_factory=dict)
    batch: int = 0
    chunks_at_once: int = 0


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
    memory_gb: float = MEMORY_GB,
    client=None,
    threads: int | None = None,
) -> MeshFit:
    """Fit N Gaussians per view to every vertex's direct glossy transport, one more to its
    indirect glossy transport, and its SH diffuse transfer with interreflection.

    The indirect glossy Gaussian comes from the paths' light, mean direction and median angle
    (:meth:`lobelight.transport.Transport.indirect_lobes`), kept apart from the fitted ones: it
    integrates the whole lighting, the sun included, where a renderer shades the sun's direct
    glossy light per pixel and the fitted lobes see the map without it (the light a mirror
    shows of the sun in another mirror); folded into a fitted lobe, that light would light the
    direct reflection's place instead.

    The work runs in stages (:data:`lobelight.fit._checkpoint.STAGES`): the flood fill and the
    relaxation by chunks of vertices (:class:`lobelight.fit._chunk.Chunk`), then the diffuse
    interreflection.

    Parameters
    ----------
    scene : Scene;  n : Gaussians per view (1-3);  views : (J, 3), default the 92 geodesic views
    batch : vertices fitted at once (default: from ``memory_gb``: 64 on the CPU, as many as
        half the free memory holds on a GPU, fewer where the budget is smaller); memory about
        ``batch x J x 672 x (130 + 100 n)`` bytes (:func:`lobelight.fit._memory.chunk_bytes`).
        With ``n = 1`` there is no spatial term, vertices do not depend on each other and
        chunks run across wavefronts; with ``n >= 2`` a chunk stays inside one wavefront
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
    memory_gb : the bake's memory budget, resident memory of the whole process in GB: the
        batch sizes of every stage are derived from it before anything is allocated, so that
        the peak does not grow with the mesh beyond its state (a few tens of KB per vertex);
        an error where even one vertex per batch would not fit
    client : a ``distributed.Client`` (the optional ``[cluster]`` extra; :func:`cluster`
        makes one): the chunks of the flood fill and the relaxation run on its workers
        (:mod:`lobelight.fit._cluster`, which says what crosses and where each stage runs),
        each worker computing on ``device`` (None: its CUDA device where it has one); the
        result is the bake's in one process, bit for bit, and the two resume each other's
        checkpoints
    threads : chunks run at once in this process without a ``client`` (:mod:`._runner`: each
        on one torch thread, so the model does not depend on it); default torch's thread
        count on the CPU, 1 on a GPU; fewer where the memory budget holds fewer chunks
        (on a GPU the budget is the host's: more than one there may not fit its memory); with
        a ``client`` the cluster's workers run them

    Returns
    -------
    MeshFit
    """
    weights = Weights() if weights is None else weights
    if threads is not None and (
        isinstance(threads, bool) or not isinstance(threads, numbers.Integral) or threads < 1
    ):
        raise InputError("threads", f"must be a positive number of threads, got {threads!r}")
    meter = PeakMeter()
    meter.stage("setup")
    try:
        tr = Transport(scene, device=device, shadows=shadows)
        dev = tr.device
        views = sphere.geodesic_views(device=dev) if views is None else views.to(dev)
        if batch is not None and batch < 1:
            raise InputError("batch", f"must be a positive number of vertices, got {batch}")
        plan = plan_memory(
            memory_gb, tr.mesh.n_vertices, views.shape[0], n, device=dev, batch=batch
        )
        indirect_paths, bounces = _counts(plan.batch, indirect_paths, bounces)
        bake = Bake.start(tr, views, n=n, weights=weights, indirect_paths=indirect_paths, seed=seed)
        chunks = plan_chunks(wavefronts(tr.mesh), n=n, batch=plan.batch, device=dev)
        # with two or more Gaussians a wavefront's chunks run at once (._runner): checkpoints
        # of a bake that ran them one after another are of another result
        order = ("wavefronts at once",) if n > 1 else ()
        key = settings_key(
            scene,
            n,
            views,
            weights,
            plan.batch,
            (indirect_paths, "indirect-gaussian", bounces, shadows, *order),
            relax,
            seed,
        )
        ckpt = Checkpoint(checkpoint, key, every=checkpoint_every)
        start = ckpt.resume(bake.state.arrays())
        bake.flips_before, bake.flips_after = start.flips_before, start.flips_after
        if client is not None:
            runner: ChunkRun = _cluster_run(client, scene, bake, device, shadows, progress)
        else:
            runner = ThreadRun(bake, _threads(threads, dev, plan.chunks_at_once))
        try:
            seconds = _stages(bake, chunks, start, ckpt, progress, meter, relax=relax,
                              bounces=bounces, memory=plan.interreflection,
                              run=runner.run)  # fmt: skip
        finally:
            runner.close()
    finally:
        peaks = meter.stop()
    out = _result(bake, bounces, seconds)
    out.peak_bytes, out.batch = peaks, plan.batch
    out.chunks_at_once = runner.threads if isinstance(runner, ThreadRun) else 0
    return out


def _threads(threads: int | None, device: torch.device, most: int) -> int:
    """How many chunks run at once in this process: ``threads`` (default torch's thread count
    on the CPU, 1 on a GPU, whose kernels a second chunk would only queue behind the first's),
    at most ``most`` (what the memory budget holds)."""
    if threads is None:
        threads = torch.get_num_threads() if device.type == "cpu" else 1
    return max(1, min(int(threads), most))


def _cluster_run(client, scene: Scene, bake: Bake, device, shadows: bool, progress) -> ClusterRun:
    """The :class:`lobelight.fit._cluster.ClusterRun` of ``bake`` on ``client``'s workers."""
    spec = _spec(scene, bake, device, shadows)
    run = ClusterRun(client, spec)
    note = getattr(progress, "note", None)
    if note is not None:
        note(
            f"the chunks run on the Dask cluster at {client.scheduler.address} "
            f"({run.workers()} workers now); the interreflection here"
        )
    return run


def _spec(scene: Scene, bake: Bake, device, shadows: bool):
    """The :class:`lobelight.fit._worker.BakeSpec` of ``bake``."""
    from ._worker import BakeSpec  # optional: needs distributed (the [cluster] extra)

    return BakeSpec(
        scene=scene,
        views=bake.views.cpu(),
        n=bake.n,
        weights=bake.weights,
        indirect_paths=bake.indirect_paths,
        seed=bake.seed,
        shadows=shadows,
        device=None if device is None else str(device),
    )


def _stages(bake: Bake, chunks, start, ckpt, progress, meter, *, relax, bounces, memory, run):
    """The bake's stages from ``start``: flood fill, relaxation, interreflection, the chunks
    run by ``run`` (:meth:`lobelight.fit._runner.ChunkRun.run`). Returns the seconds of each."""
    t0 = time.perf_counter()
    meter.stage("fit")
    if start.todo("fit"):
        run("fit", bake, chunks, start, ckpt, progress, force_last=True)
    t1 = time.perf_counter()
    meter.stage("relax")
    if start.todo("fit"):  # counted on the relaxation's clock, which compares against it
        bake.flips_before = bake.flips_after = _flips(bake.mesh, bake.state.gaussians())
    if start.todo("relax"):
        if relax and bake.n > 1:
            _relaxation(bake, chunks, start, ckpt, progress, run)
        ckpt.save(_at(bake, "interreflection", 0), bake.state.arrays(), force=True)
    t2 = time.perf_counter()
    meter.stage("interreflection")
    if start.todo("interreflection") and bounces > 0:
        _interreflection(bake, bounces, progress, memory)
        ckpt.save(_at(bake, "done", 0), bake.state.arrays(), force=True)
    t3 = time.perf_counter()
    return {
        "fit": t1 - t0,
        "indirect_glossy": bake.indirect_seconds,
        "relax": t2 - t1,
        "interreflection": t3 - t2,
    }


def _counts(batch: int, indirect_paths, bounces) -> tuple[int, int]:
    """Checks :func:`fit_mesh`'s counts; returns ``indirect_paths`` and ``bounces`` as ints."""
    if batch < 1:
        raise InputError("batch", f"must be a positive number of vertices, got {batch}")
    for name, value in (("indirect_paths", indirect_paths), ("bounces", bounces)):
        if isinstance(value, bool) or int(value) != value or value < 0:
            raise InputError(name, f"must be a whole number >= 0 (0: off), got {value!r}")
    return int(indirect_paths), int(bounces)


def _at(bake: Bake, stage: str, next_chunk: int) -> Position:
    """The bake's position at the start of chunk ``next_chunk`` of ``stage``."""
    return Position(stage, next_chunk, bake.flips_before, bake.flips_after)


def _relaxation(bake: Bake, chunks: list[Chunk], start, ckpt, progress, run) -> None:
    """The relaxation ("relax"): every chunk refitted against all its neighbours (by
    ``run``), then the order of each vertex's Gaussians over the whole mesh, now that every
    neighbour is final (the refit moves lobes, and adds flips on its own)."""
    run("relax", bake, chunks, start, ckpt, progress, force_last=False)
    st = bake.state
    g = reorder_mesh(
        bake.mesh, st.gaussians(), bake.nbr_views, weights=bake.weights, progress=progress
    )
    st.w.copy_(g.w), st.mu.copy_(g.mu), st.lam.copy_(g.lam)
    bake.flips_after = _flips(bake.mesh, g)


def _interreflection(bake: Bake, bounces: int, progress, memory: int) -> None:
    """The diffuse interreflection ("interreflection"), in one step: it needs every vertex's
    self-shadowed transfer and final Gaussians; its batches hold at most ``memory`` bytes."""
    st = bake.state
    # the hit points' glossy light comes from their Gaussians (direct and indirect glossy):
    # without it a diffuse floor by a metal wall loses much of its light
    g = _with_indirect(st.gaussians(), st.ind_w, st.ind_mu, st.ind_lam)
    lobes = (bake.views, g.w, g.mu, g.lam) if bool(st.glossy.any()) else None
    total = diffuse_interreflection(
        bake.transport,
        st.diffuse,
        bounces=bounces,
        glossy=lobes,
        progress=progress,
        memory=memory,
    )
    st.bounce.copy_(total - st.diffuse)
    st.diffuse.copy_(total)


def _result(bake: Bake, bounces: int, seconds: dict[str, float]) -> MeshFit:
    st = bake.state
    return MeshFit(
        gaussians=_with_indirect(st.gaussians(), st.ind_w, st.ind_mu, st.ind_lam),
        indirect_gaussians=1 if bool((st.ind_w > 0).any()) else 0,
        diffuse=st.diffuse,
        views=bake.views,
        data_error=st.derr,
        bounce=st.bounce if bounces > 0 else None,
        flips_before=bake.flips_before[0],
        flips_after=bake.flips_after[0],
        separated_flips_before=bake.flips_before[1],
        separated_flips_after=bake.flips_after[1],
        seconds=seconds,
    )


def _with_indirect(g: Gaussians, w, mu, lam) -> Gaussians:
    """The fitted Gaussians with the indirect glossy one after them, where any path bounced
    off the object (a convex object, or a bake without indirect paths, has none)."""
    if not bool((w > 0).any()):
        return g
    return Gaussians(torch.cat([g.w, w], 2), torch.cat([g.mu, mu], 2), torch.cat([g.lam, lam], 2))
