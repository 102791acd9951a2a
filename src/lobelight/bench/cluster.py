"""Benchmark of a bake on a Dask cluster (``lobelight bench cluster``): chunks per second in one
process and on local workers, the cluster path's cost per chunk, and a projection of a large
bake across machines.

A small bake (``sphere:1``) runs first, untimed, so that the first timed bake does not pay the
process's one-time costs (imports, caches, the allocator's first growth). The same bake (one
Gaussian per view: independent chunks) runs on local clusters of 1, 2, ...
worker processes of one thread each (:func:`lobelight.fit.cluster`), and, for each of them, in
this process with as many torch threads as the cluster has worker threads (at most this
machine's cores; the bake then runs as many chunks side by side, one torch thread each:
:mod:`lobelight.fit._runner`), so that each cluster run is set against a single-process bake
on the same cores. The chunks' stage (``fit`` in the bake's provenance: transport sampling and
the fit, what the workers run) is timed apart from the interreflection, which stays on the
client. From them:

- ``chunks_per_second``: chunks over the chunks' stage's seconds, per run;
- ``overhead_seconds_per_chunk``: the 1-worker run's chunk stage less the one-thread local
  one's, per chunk (scheduling, shipping the chunk's inputs and result, the worker's plugin
  set-up);
- ``overhead``: at the largest worker count, the cluster's chunk stage over the local one's on
  the same number of threads, less 1 (0 when the cluster path costs nothing beyond the bake's
  own work; negative where worker processes outrun one process's threads);
- ``projection``: a bake of ``projected_vertices`` on ``machines`` machines of this one's cores,
  one worker per core: the local per-vertex chunk time divided over the workers, plus the
  client's interreflection at the local per-vertex rate (it does not shrink with workers).
"""

from __future__ import annotations

import math
import os
import time

import torch

from ..fit import cluster, fit_model
from ..scene import load
from ._machine import machine

__all__ = ["WARM_UP", "bench_cluster"]

#: The untimed bake run first (module docstring).
WARM_UP = "sphere:1"


def _bake(sc, *, client, indirect_paths: int, bounces: int) -> tuple[float, dict]:
    """One bake of ``sc`` (one Gaussian per view): its wall seconds and its provenance."""
    t0 = time.perf_counter()
    m = fit_model(
        sc, 1, indirect_paths=indirect_paths, bounces=bounces, progress=None, client=client
    )
    return time.perf_counter() - t0, m.provenance


def _local(sc, threads: int, *, indirect_paths: int, bounces: int) -> tuple[float, dict]:
    """:func:`_bake` in this process on ``threads`` torch threads (restored after)."""
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        return _bake(sc, client=None, indirect_paths=indirect_paths, bounces=bounces)
    finally:
        torch.set_num_threads(before)


def _row(label: str, workers: int, threads: int, wall: float, prov: dict, chunks: int) -> dict:
    stage = float(prov["seconds"]["fit"])
    return {
        "run": label,
        "workers": workers,
        "threads": threads,
        "seconds": wall,
        "chunk_stage_seconds": stage,
        "interreflection_seconds": float(prov["seconds"].get("interreflection", 0.0)),
        "chunks_per_second": chunks / stage if stage > 0 else None,
    }


def bench_cluster(
    *,
    scene: str = "sphere:3",
    workers: tuple[int, ...] = (1, 2),
    indirect_paths: int = 4,
    bounces: int = 1,
    projected_vertices: int = 1_000_000,
    machines: int = 20,
) -> dict:
    """The bake of ``scene`` in this process and on local clusters of each of ``workers``
    worker processes (module docstring); ``indirect_paths`` and ``bounces`` as the bake's."""
    sc = load(scene)
    v = sc.mesh.n_vertices
    cores = os.cpu_count() or 1
    kw = {"indirect_paths": indirect_paths, "bounces": bounces}
    _bake(load(WARM_UP), client=None, **kw)  # untimed: the process's one-time costs
    locals_ = {}  # threads -> row of the local bake on that many threads
    rows = []
    starts = {}
    chunks = batch = None
    for w in sorted(set(workers)):
        threads = min(w, cores)
        if threads not in locals_:
            wall, prov = _local(sc, threads, **kw)
            batch = int(prov["memory"]["batch"])
            chunks = math.ceil(v / batch)
            locals_[threads] = _row(f"local, {threads} thread(s)", 0, threads, wall, prov, chunks)
            rows.append(locals_[threads])
        t0 = time.perf_counter()
        with cluster(workers=w) as client:
            starts[w] = time.perf_counter() - t0
            wall, prov = _bake(sc, client=client, **kw)
        rows.append(_row(f"{w} worker(s)", w, w, wall, prov, chunks))
    clusters = [r for r in rows if r["workers"] > 0]
    one = next((r for r in clusters if r["workers"] == 1), None)
    most = max(clusters, key=lambda r: r["workers"]) if clusters else None
    fastest = min(locals_.values(), key=lambda r: r["chunk_stage_seconds"])
    per_vertex = fastest["chunk_stage_seconds"] / v
    client_per_vertex = fastest["interreflection_seconds"] / v
    total_workers = machines * cores
    return {
        "benchmark": "cluster",
        "scene": scene,
        "vertices": v,
        "chunks": chunks,
        "batch": batch,
        "indirect_paths": indirect_paths,
        "bounces": bounces,
        "runs": rows,
        "cluster_start_seconds": starts,
        "overhead_seconds_per_chunk": None
        if one is None
        else (one["chunk_stage_seconds"] - locals_[1]["chunk_stage_seconds"]) / chunks,
        "overhead": None
        if most is None
        else most["chunk_stage_seconds"]
        / locals_[min(most["workers"], cores)]["chunk_stage_seconds"]
        - 1,
        "projection": {
            "vertices": projected_vertices,
            "machines": machines,
            "workers": total_workers,
            "chunk_seconds": per_vertex * projected_vertices / total_workers,
            "client_interreflection_seconds": client_per_vertex * projected_vertices,
            "hours": (per_vertex / total_workers + client_per_vertex) * projected_vertices / 3600,
            "gpu_workers": None,  # no GPU benchmark's per-vertex rate measured on this machine
        },
        "goal_overhead": 0.10,
        "machine": machine("cpu"),
    }
