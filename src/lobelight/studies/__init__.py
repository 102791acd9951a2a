"""Studies: what measures the methods, and the command line's long-running entry points.

- :mod:`~lobelight.studies.compare`  a model against the path tracer (``lobelight compare``)
- :mod:`~lobelight.studies.compare_brdf`  the SG-BRDF method against its baselines
  (``lobelight compare-brdf``)
- :mod:`~lobelight.studies.gallery`  real scenes scored against Mitsuba 3 (``lobelight gallery``)
- :mod:`~lobelight.studies.energy`  the energy of each step of the pipeline against quadrature
- :mod:`~lobelight.studies.figure5`  the view-dependent PRT paper's Figure 5 (SG vs Haar)
- :mod:`~lobelight.studies.demo`  the first-run demo (``lobelight demo``)
- :mod:`~lobelight.studies.lobes_demo`, :mod:`~lobelight.studies.lobes_score`  the cosine-lobe
  method's animation and its scores

Studies import from every layer below them, and from the benchmarks (:mod:`lobelight.bench`)
the machine record and the GLSL frame timing of :mod:`~lobelight.studies.compare_brdf`; nothing
imports them but the command line.
"""
