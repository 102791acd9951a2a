"""The fitted model: what a bake produces and every renderer draws.

- :class:`Model` ``(mesh, views (J, 3), gaussians (V, J, N), diffuse (V, n, 3), materials,
  provenance, bounce, indirect_gaussians)``: per vertex and stored view, ``N`` Gaussians of
  glossy transport (the last ``indirect_gaussians`` of them indirect), and the SH diffuse
  transfer. :meth:`Model.transport` blends a vertex's Gaussians at any view direction,
  :meth:`Model.evaluate` evaluates them, :meth:`Model.save` writes the file.
- :func:`load`, :func:`save` the model file (:mod:`lobelight.model._format`: the layout, the
  checks on read, the atomic write; ``docs/model-format.md``)
- :func:`blend_lobes`, :func:`horizon_scale` the view blend (:mod:`lobelight.model._blend`)
- :func:`visibility_tiles` each vertex's visibility of the environment by direction, on an
  octahedral tile (:meth:`Model.visibility`): where a sharp reflection is occluded, per pixel;
  :func:`hit_tiles` what it sees of the object there (:meth:`Model.hits`), and
  :class:`HitTexels` those tiles as the texels that hit, as a file stores them
  (:meth:`Model.hit_texels`; :mod:`lobelight.model._stored`, with the Gaussians as a file
  stores them)

The model knows nothing of how it was fitted (:mod:`lobelight.fit` builds it).
"""

from ._blend import LIVE_FLOOR, MIN_SAY, blend_lobes, horizon_scale
from ._format import FORMAT, MAX_LIGHT, MAX_READ_BYTES, SIGMA_MAX, SIGMA_MIN, VERSION
from ._model import ALBEDO_MIN, Model, load, per_unit_albedo, save
from ._stored import HitTexels
from ._visibility import VISIBILITY_RES, hit_tiles, visibility_tiles

__all__ = [
    "ALBEDO_MIN",
    "FORMAT",
    "LIVE_FLOOR",
    "MAX_LIGHT",
    "MAX_READ_BYTES",
    "MIN_SAY",
    "SIGMA_MAX",
    "SIGMA_MIN",
    "VERSION",
    "VISIBILITY_RES",
    "HitTexels",
    "Model",
    "blend_lobes",
    "hit_tiles",
    "horizon_scale",
    "load",
    "per_unit_albedo",
    "save",
    "visibility_tiles",
]
