"""Ground truth that the methods are scored against.

- :mod:`lobelight.reference.paths`    a path tracer for lobelight's scenes (environment light,
  per-vertex materials, shadows and interreflection): :func:`render`, :func:`radiance_at`,
  :class:`EnvSampler`
- :mod:`lobelight.reference.mitsuba`  the same scene as a Mitsuba 3 scene dictionary
- :mod:`lobelight.reference.sgbrdf`   Monte Carlo shading of a BRDF under an environment (the
  SG-BRDF method's reference)
- :mod:`lobelight.reference.cosine`   Monte Carlo direct light from sphere lights (the cosine-lobe
  method's reference)

The path tracer's names are also importable from ``lobelight.reference`` itself.
"""

from .paths import EnvSampler, radiance_at, render

__all__ = ["EnvSampler", "radiance_at", "render"]
