"""lobelight: real-time, all-frequency relighting with spherical lobes.

The package is layered, lowest first (``DEVELOPERS.md``; conventions: ``docs/conventions.md``):

- foundations: :mod:`~lobelight.errors`, :mod:`~lobelight.progress`, :mod:`~lobelight.data`,
  and the private ``_io``, ``_backend``, ``_checks``, ``_tol``, ``_cache``
- :mod:`lobelight.geometry` directions, cube maps, the camera, ray queries
- :mod:`lobelight.lobes` spherical Gaussians, spherical harmonics, Haar wavelets
- :mod:`lobelight.brdf` the BRDF models
- :mod:`lobelight.envmap`, :mod:`lobelight.scene` the inputs: environment maps, meshes and
  materials
- :mod:`lobelight.transport` light transport per vertex and view
- :mod:`lobelight.model` the fitted model: file format and view blending
- :mod:`lobelight.fit` the fit of the view-dependent PRT method
- :mod:`lobelight.sgbrdf`, :mod:`lobelight.cosine` the two companion methods
- :mod:`lobelight.render` the renderers (OpenGL and torch)
- :mod:`lobelight.reference` ground truth: the path tracer, Mitsuba 3 export
- :mod:`lobelight.studies` comparisons, scores, the gallery, paper figures, demos
- :mod:`lobelight.bench` the benchmarks (``lobelight bench``)
- :mod:`lobelight.cli` the command line
"""

__version__ = "0.1.0"
