"""Environment maps: distant HDR lighting and its Gaussian-prefiltered chain.

- :class:`EnvMap` radiance arriving from each direction (lat-long in Mitsuba 3's orientation, or
  a cube map in GL layout); ``radiance(dirs)``, ``to_cubemap(res)``, ``rotate(R)``, ``power()``;
  ``to_cubemap(res, cache=True)`` keeps the resampled cube on disk beside the prefiltered chains.
- :func:`load` / :func:`save` ``.hdr`` and ``.exr`` files (lat-long or cross cube maps), checked
  at the door: a bad file is one :class:`lobelight.errors.InputError` naming it.
- :func:`builtin` a procedural sky with a small, very bright sun, so nothing needs a file.
- :func:`extract_sun` a compact bright source (a sun, a lamp, a window) split off a map
  (:class:`Sun`), found by its concentration, for per-pixel shading with soft shadows.
- :func:`prefilter` -> :class:`Prefiltered`, whose ``integrate(mu, lam)`` approximates
  ``int exp(lam (mu.w - 1)) L(w) dw`` with one interpolated lookup per lobe; its sharpest
  level's Gaussian is :data:`TEXELS_PER_SIGMA` texels wide at a base face's centre.
- :class:`ChainBuilder` the same chain rebuilt from one map after another (a dynamic
  environment each frame); on CUDA one graph launch per map.
"""

from ._builtin import builtin
from ._chain_builder import ChainBuilder
from ._envmap import EnvMap
from ._io import load, save
from ._prefilter import TEXELS_PER_SIGMA, Prefiltered, clear_memory_caches, prefilter
from ._sun import Sun, extract_sun

__all__ = [
    "TEXELS_PER_SIGMA",
    "ChainBuilder",
    "EnvMap",
    "Prefiltered",
    "Sun",
    "builtin",
    "clear_memory_caches",
    "extract_sun",
    "load",
    "prefilter",
    "save",
]
