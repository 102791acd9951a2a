"""Benchmark of a whole bake (``lobelight bench fit``): transport, fit and interreflection of a
model, per stage."""

from __future__ import annotations

import time

from ..fit import fit_model
from ..scene import load
from ..transport import BOUNCES, INDIRECT_PATHS
from ._machine import machine, sync

__all__ = ["bench_fit"]


def bench_fit(
    *,
    scene: str = "knot:2",
    n_gaussians: int = 1,
    device: str = "cpu",
    bounces: int | None = None,
    indirect_paths: int | None = None,
    progress=True,
) -> dict:
    """Transport and fit of a whole model (a 10K-vertex, 92-view, N = 1 model), with a bake's
    interreflection (``bounces``, ``indirect_paths``: default the bake's,
    :data:`lobelight.transport.BOUNCES` and :data:`lobelight.transport.INDIRECT_PATHS`).

    ``knot:2`` has 11,457 vertices (10,368 of them glossy); seconds are also given per 10K
    vertices, and per stage: ``fit`` (transport sampling and fit, with ``indirect_glossy`` the
    path tracing inside it), ``relax``, ``interreflection`` (the diffuse bounces).
    ``progress`` as :func:`lobelight.fit.fit_model`'s (``lobelight bench fit -q``: None).
    """

    bounces = BOUNCES if bounces is None else bounces
    indirect_paths = INDIRECT_PATHS if indirect_paths is None else indirect_paths
    sc = load(scene)
    t0 = time.perf_counter()
    m = fit_model(
        sc,
        n_gaussians,
        device=device,
        bounces=bounces,
        indirect_paths=indirect_paths,
        progress=progress,
    )
    sync(device)
    total = time.perf_counter() - t0
    v = sc.mesh.n_vertices
    return {
        "benchmark": "fit",
        "scene": scene,
        "vertices": v,
        "glossy_vertices": int((m.gaussians.w.amax((1, 2, 3)) > 0).sum()),
        "views": int(m.views.shape[0]),
        "n_gaussians": n_gaussians,
        "bounces": bounces,
        "indirect_paths": indirect_paths,
        "seconds": total,
        "seconds_per_10k_vertices": total * 1e4 / v,
        "stage_seconds": {k: t for k, t in m.provenance["seconds"].items() if k != "total"},
        "relative_l2_error_mean": m.provenance["relative_l2_error_mean"],
        "goal_seconds": 600.0 if device == "cpu" else 10.0,
        "machine": machine(device),
    }
