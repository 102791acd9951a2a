"""Benchmark of a whole bake (``lobelight bench fit``): transport, fit and interreflection of a
model, per stage."""

from __future__ import annotations

import sys
import time

try:
    import resource  # Unix only: elsewhere no peak is reported
except ImportError:  # pragma: no cover
    resource = None

from ..fit import MEMORY_GB, fit_model
from ..scene import load
from ..transport import BOUNCES, INDIRECT_PATHS
from ._machine import machine, sync

__all__ = ["bench_fit"]


def _peak_bytes() -> int:
    """The process's peak resident memory so far (``ru_maxrss``: KB on Linux, bytes on macOS)."""
    if resource is None:
        return 0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(peak if sys.platform == "darwin" else peak * 1024)


def bench_fit(
    *,
    scene: str = "knot:2",
    material: str | None = None,
    n_gaussians: int | str = "auto",
    memory_gb: float = MEMORY_GB,
    device: str = "cpu",
    bounces: int | None = None,
    indirect_paths: int | None = None,
    progress=True,
) -> dict:
    """Transport and fit of a whole model, the default bake (92 views, Gaussians per view
    chosen from the material, ``memory_gb`` budget), with a bake's interreflection
    (``bounces``, ``indirect_paths``: default the bake's, :data:`lobelight.transport.BOUNCES`
    and :data:`lobelight.transport.INDIRECT_PATHS`).

    ``scene``: a built-in name or a file, ``material`` a bare mesh's material (as ``bake
    --material``). ``knot:2`` has 11,457 vertices (10,368 of them glossy); ``vertices`` counts
    the scene's, ``fitted_vertices`` the model's after the bake's refinement split edges, and
    ``glossy_vertices`` the model's with glossy light. Seconds are also given per 10K of the
    scene's vertices, and per stage: ``fit`` (transport sampling and fit, with
    ``indirect_glossy`` the path tracing inside it), ``relax``, ``interreflection`` (the
    diffuse bounces), with each stage's peak resident memory (``stage_peak_gb``: the whole
    process's) and the process's peak (``peak_gb``). ``progress`` as
    :func:`lobelight.fit.fit_model`'s (``lobelight bench fit -q``: None).
    """

    bounces = BOUNCES if bounces is None else bounces
    indirect_paths = INDIRECT_PATHS if indirect_paths is None else indirect_paths
    sc = load(scene, material=material)
    t0 = time.perf_counter()
    m = fit_model(
        sc,
        n_gaussians,
        memory_gb=memory_gb,
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
        # the bake's refinement splits edges whose ends see the map differently: the model
        # fits more vertices than the scene brings
        "fitted_vertices": m.mesh.n_vertices,
        "glossy_vertices": int((m.gaussians.w.amax((1, 2, 3)) > 0).sum()),
        "views": int(m.views.shape[0]),
        "material": material if material is not None else sc.materials.model,
        "n_gaussians": m.provenance["n_gaussians"],
        "n_gaussians_choice": m.provenance["n_gaussians_choice"],
        "bounces": bounces,
        "indirect_paths": indirect_paths,
        "seconds": total,
        "seconds_per_10k_vertices": total * 1e4 / v,
        "stage_seconds": {k: t for k, t in m.provenance["seconds"].items() if k != "total"},
        "memory_budget_gb": m.provenance["memory"]["budget_gb"],
        "batch": m.provenance["memory"]["batch"],
        "chunks_at_once": m.provenance["memory"]["chunks_at_once"],
        "stage_peak_gb": m.provenance["memory"]["peak_gb"],
        "peak_gb": round(_peak_bytes() / 2**30, 3),
        "relative_l2_error_mean": m.provenance["relative_l2_error_mean"],
        "goal_seconds": 600.0 if device == "cpu" else 10.0,
        "machine": machine(device),
    }
