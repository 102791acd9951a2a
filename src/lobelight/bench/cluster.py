"""Benchmark of a bake on a Dask cluster (``lobelight bench cluster``): chunks per second in one
process and on local workers, the cluster path's cost per chunk, and a projection of a large
bake across machines.

The same bake (one Gaussian per view: independent chunks) runs in this process, then on local
clusters of 1, 2, ... worker processes of one thread each (:func:`lobelight.fit.cluster`). The
chunks' stage (``fit`` in the bake's provenance: transport sampling and the fit, what the
workers run) is timed apart from the interreflection, which stays on the client. From them:

- ``chunks_per_second``: chunks over the chunks' stage's seconds, per run;
- ``overhead_seconds_per_chunk``: the 1-worker run's chunk stage less the local one's, per chunk
  (scheduling, shipping the chunk's inputs and result, the worker's plugin set-up);
- ``overhead``: the cluster path's share beyond the local bake's work at the largest worker
  count: ``workers x cluster seconds / local seconds - 1`` of the chunks' stage (0 when the
  workers divide the local work perfectly; on a machine with fewer free cores than workers it
  also holds the cores' contention);
- ``projection``: a bake of ``projected_vertices`` on ``machines`` machines of this one's cores,
  one worker per core: the local per-vertex chunk time divided over the workers, plus the
  client's interreflection at the local per-vertex rate (it does not shrink with workers).
"""

from __future__ import annotations

import math
import os
import time

from ..fit import cluster, fit_model
from ..scene import load
from ._machine import machine

__all__ = ["bench_cluster"]


def _bake(sc, *, client, indirect_paths: int, bounces: int) -> tuple[float, dict]:
    """One bake of ``sc`` (one Gaussian per view): its wall seconds and its provenance."""
    t0 = time.perf_counter()
    m = fit_model(
        sc, 1, indirect_paths=indirect_paths, bounces=bounces, progress=None, client=client
    )
    return time.perf_counter() - t0, m.provenance


def _row(label: str, workers: int, wall: float, prov: dict, chunks: int) -> dict:
    stage = float(prov["seconds"]["fit"])
    return {
        "run": label,
        "workers": workers,
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
    wall, prov = _bake(sc, client=None, indirect_paths=indirect_paths, bounces=bounces)
    batch = int(prov["memory"]["batch"])
    chunks = math.ceil(v / batch)
    rows = [_row("local", 0, wall, prov, chunks)]
    starts = {}
    for w in workers:
        t0 = time.perf_counter()
        with cluster(workers=w) as client:
            starts[w] = time.perf_counter() - t0
            wall, prov = _bake(sc, client=client, indirect_paths=indirect_paths, bounces=bounces)
        rows.append(_row(f"{w} worker(s)", w, wall, prov, chunks))
    local = rows[0]
    one = next((r for r in rows if r["workers"] == 1), None)
    most = max(rows[1:], key=lambda r: r["workers"]) if len(rows) > 1 else None
    per_vertex = local["chunk_stage_seconds"] / v
    client_per_vertex = local["interreflection_seconds"] / v
    cores = os.cpu_count() or 1
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
        else (one["chunk_stage_seconds"] - local["chunk_stage_seconds"]) / chunks,
        "overhead": None
        if most is None
        else most["workers"] * most["chunk_stage_seconds"] / local["chunk_stage_seconds"] - 1,
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
