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
- :func:`machine` where a benchmark ran; :func:`sync` waits for a device's queued work

Benchmarks import the library's packages below them and no study; the studies' comparison of
the SG-BRDF method (:mod:`lobelight.studies.compare_brdf`) times its GLSL rows with
:func:`time_frames` and records :func:`machine`.
"""

from ._machine import machine, sync
from .brdf_fit import bench_brdf_fit
from .cosine import bench_lobes, bench_tables
from .fit import bench_fit
from .prefilter import bench_prefilter
from .rays import bench_rays
from .render import bench_render
from .sgbrdf_gl import bench_sgbrdf_gl, time_frames
from .suite import BENCHMARKS, GOALS, bench_all, table
from .synthetic import synthetic_model
from .transport import bench_transport

__all__ = [
    "BENCHMARKS",
    "GOALS",
    "bench_all",
    "bench_brdf_fit",
    "bench_fit",
    "bench_lobes",
    "bench_prefilter",
    "bench_rays",
    "bench_render",
    "bench_sgbrdf_gl",
    "bench_tables",
    "bench_transport",
    "machine",
    "sync",
    "synthetic_model",
    "table",
    "time_frames",
]
