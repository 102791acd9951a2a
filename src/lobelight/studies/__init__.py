"""Studies: what measures the methods, and the command line's long-running entry points.

- :mod:`~lobelight.studies.compare`  a model against the path tracer (``lobelight compare``)
- :mod:`~lobelight.studies.compare_brdf`  the SG-BRDF method against its baselines
  (``lobelight compare-brdf``)
- :mod:`~lobelight.studies.gallery`  real scenes scored against Mitsuba 3 (``lobelight gallery``)
- :mod:`~lobelight.studies.energy`  the energy of each step of the pipeline against quadrature
- :mod:`~lobelight.studies.figure5`  the view-dependent PRT paper's Figure 5 (SG vs Haar)
- :mod:`~lobelight.studies.demo`  the first-run demo (``lobelight demo``)
- :mod:`~lobelight.studies.lobes_demo`, :mod:`~lobelight.studies.lobes_score`,
  :mod:`~lobelight.studies.lobes_calibrate`  the cosine-lobe method's animation, scores and the
  calibration of its weights
- benchmarks (``lobelight bench``): :mod:`~lobelight.studies.bench` (prefilter, transport, fit,
  render), :mod:`~lobelight.studies.bench_lobes` (cosine lobes and their tables),
  :mod:`~lobelight.studies.bench_brdf_fit` (the SG-BRDF fit)

Studies import from every layer below them and nothing imports them but the command line.
"""
