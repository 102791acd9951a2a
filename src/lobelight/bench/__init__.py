"""Benchmarks (``lobelight bench ...``): timings with the machine they ran on, as JSON.

Speed is measured here, never in unit tests. Each benchmark returns a JSON-serialisable dict
that the command line prints (``--json``) and that ``docs/benchmarks.md`` records with the
machine description (:func:`machine`).

- :func:`bench_prefilter` the Gaussian-prefiltered chain: cold, warm, cached and dynamic builds
  (:mod:`~lobelight.bench.prefilter`)
- :func:`bench_transport` visibility rays and transport sampling
  (:mod:`~lobelight.bench.transport`)
- :func:`bench_fit` a whole bake, per stage (:mod:`~lobelight.bench.fit`)
- :func:`bench_render` the renderer's frames per second and a GL frame's passes
  (:mod:`~lobelight.bench.render`), on :func:`synthetic_model` (:mod:`~lobelight.bench.synthetic`)
- :func:`bench_rays` the ray engines, Embree and NVIDIA Warp, side by side
  (:mod:`~lobelight.bench.rays`)
- :func:`bench_lobes` and :func:`bench_tables` cosine-lobe shading and the build of its
  tables (:mod:`~lobelight.bench.cosine`)
- :func:`bench_brdf_fit` the SG-BRDF fit (:mod:`~lobelight.bench.brdf_fit`);
  :func:`bench_sgbrdf_gl` and :func:`time_frames` the SG-BRDF method against filtered importance
  sampling in GLSL (:mod:`~lobelight.bench.sgbrdf_gl`)
- :func:`bench_all` every benchmark with a goal in one run, and :func:`table` the Markdown rows
  made from its record (:mod:`~lobelight.bench.suite`; ``python -m lobelight.bench table
  RESULT.json`` prints them)
- :func:`bench_start` a render's start: ``lobelight render`` in a fresh process, cold and warm,
  and where its time goes (:mod:`~lobelight.bench.start`)
- :func:`bench_cluster` a bake on local Dask clusters against one process, with a projection
  across machines (:mod:`~lobelight.bench.cluster`)
- :func:`bench_web` the WebGL 2 viewer's frames per second in headless chromium
  (:mod:`~lobelight.bench.web`)
- :func:`machine` where a benchmark ran; :func:`sync` waits for a device's queued work

Each name is imported from its module when first used (the modules import what they measure:
the fit, the cosine lobes, the ray engines), so that importing this package, as the command
line does, costs nothing until a benchmark runs.

Benchmarks import the library's packages below them and no study; the studies' comparison of
the SG-BRDF method (:mod:`lobelight.studies.compare_brdf`) times its GLSL rows with
:func:`time_frames` and records :func:`machine`.
"""

from .._lazy import lazy_names

#: Where each public name lives (module of this package).
_HOMES = {
    "BENCHMARKS": ".suite",
    "GOALS": ".suite",
    "bench_all": ".suite",
    "bench_brdf_fit": ".brdf_fit",
    "bench_cluster": ".cluster",
    "bench_fit": ".fit",
    "bench_lobes": ".cosine",
    "bench_prefilter": ".prefilter",
    "bench_rays": ".rays",
    "bench_render": ".render",
    "bench_sgbrdf_gl": ".sgbrdf_gl",
    "bench_start": ".start",
    "bench_tables": ".cosine",
    "bench_transport": ".transport",
    "bench_web": ".web",
    "machine": "._machine",
    "sync": "._machine",
    "synthetic_model": ".synthetic",
    "table": ".suite",
    "time_frames": ".sgbrdf_gl",
}


__getattr__, __dir__ = lazy_names(__name__, _HOMES)


__all__ = sorted(_HOMES)
