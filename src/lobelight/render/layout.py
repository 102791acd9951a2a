"""The data the shaders read, laid out as the desktop renderer uploads it: for other front ends
of the same shader files (the web viewer, :mod:`lobelight.web`), so that their layouts cannot
drift from the desktop's.

- Textures: :func:`gaussian_records` (two texels per Gaussian record), :func:`stage_texels`,
  :func:`stage_layout` and :func:`stage_varyings` (the vertex stage's results per vertex,
  captured once per frame by transform feedback: ``prt.glsl``'s ``STAGE_PASS``,
  ``stage.glsl``), :func:`atlas_image` and
  :func:`atlas_uniforms` (the prefiltered chain's atlas, ``prefiltered.glsl``),
  :func:`geodesic_tables` (``geodesic.glsl``'s planes and candidate cube), :data:`TEX_WIDTH`
  (the width long arrays wrap at), :data:`CAND_RES`, :data:`SHADOW_RES`,
  :data:`BACKGROUND_RES`; :func:`albedo_array` and :func:`albedo_uniforms` (``albedo.glsl``),
  :data:`MAX_ALBEDO_SIZE`, :data:`MAX_ALBEDO_LAYERS`; :func:`specular_f0` and :data:`F0_MIN`
  (the specular colour per texel: the bake's per-vertex F0 the texture is measured against).
- Uniform blocks: :data:`FRAME_LAYOUT` (``frame.glsl``'s per-frame block, offsets in floats).
- The sun: :func:`disc_radius`, :data:`SHADOW_SAMPLES`, :data:`BLOCKER_SAMPLES`
  (``shadow.glsl``, the percentage-closer soft shadow), :func:`sun_glossy_supported`,
  :func:`sun_glossy_uniforms`, :func:`sun_glossy_vertex_params`, :func:`sun_widened`,
  :func:`tail_scale` (the sun's glossy reflection per pixel).
- Records: :func:`kept_records` (the records some rendering sees: live at the view or at a
  geodesic neighbour).
- The sharp reflection's constants, :data:`SHARP_DEFINES` (``reflection.glsl``'s defines:
  ``OCCLUDED_FLOOR``, ``SHARP_NV_MIN``, ``SUN_RESOLVED``, ``INDIRECT_SCALE_MAX``,
  ``SPREAD_GAUSSIAN``) and :func:`sharp_shader_defines` (them as shader text, with a glTF
  lobe's that varies per vertex), and :func:`varying_lobe_arrays` (what the shaders read of
  such a lobe).
- The lobe visibility correction (``lobe_visibility.glsl``): :func:`lobe_visibility_applies`
  (whether a model's direct Gaussians are corrected), :func:`lobe_visibility_defines` (its
  constants as shader defines), :data:`LOBE_VISIBILITY_SAMPLES` and
  :data:`LOBE_VISIBILITY_MOVING_SAMPLES` (its directions for a still and a moving frame) and
  :data:`LOBE_VISIBILITY_INCLUDE` (the files its vertex stage includes).
- Shader text: :func:`stage_sources` (a file's two stages in a dialect), :func:`load_shader`.
"""

from ._albedo import F0_MIN, specular_f0
from ._gl import (
    BACKGROUND_RES,
    CAND_RES,
    FRAME_LAYOUT,
    LOBE_VISIBILITY_INCLUDE,
    SHADOW_RES,
    TEX_WIDTH,
    atlas_image,
    atlas_uniforms,
    gaussian_records,
    geodesic_tables,
    load_shader,
    stage_layout,
    stage_sources,
    stage_texels,
    stage_varyings,
)
from ._gl_albedo import MAX_ALBEDO_LAYERS, MAX_ALBEDO_SIZE, albedo_array, albedo_uniforms
from ._gltf_out import kept_records
from ._lobe_visibility import MOVING_SAMPLES as LOBE_VISIBILITY_MOVING_SAMPLES
from ._lobe_visibility import SAMPLES as LOBE_VISIBILITY_SAMPLES
from ._lobe_visibility import lobe_visibility_applies
from ._lobe_visibility import shader_defines as lobe_visibility_defines
from ._reflection import (
    SHARP_DEFINES,
    sharp_shader_defines,
    sun_shape_resolved,
    varying_lobe_arrays,
)
from ._sun_glossy import (
    sun_glossy_supported,
    sun_glossy_uniforms,
    sun_glossy_vertex_params,
    sun_widened,
    tail_scale,
)
from ._sun_shadow import BLOCKER_SAMPLES, SHADOW_SAMPLES, disc_radius

__all__ = [
    "BACKGROUND_RES",
    "BLOCKER_SAMPLES",
    "CAND_RES",
    "F0_MIN",
    "FRAME_LAYOUT",
    "LOBE_VISIBILITY_INCLUDE",
    "LOBE_VISIBILITY_MOVING_SAMPLES",
    "LOBE_VISIBILITY_SAMPLES",
    "MAX_ALBEDO_LAYERS",
    "MAX_ALBEDO_SIZE",
    "SHADOW_RES",
    "SHADOW_SAMPLES",
    "SHARP_DEFINES",
    "TEX_WIDTH",
    "albedo_array",
    "albedo_uniforms",
    "atlas_image",
    "atlas_uniforms",
    "disc_radius",
    "gaussian_records",
    "geodesic_tables",
    "kept_records",
    "load_shader",
    "lobe_visibility_applies",
    "lobe_visibility_defines",
    "sharp_shader_defines",
    "specular_f0",
    "stage_layout",
    "stage_sources",
    "stage_texels",
    "stage_varyings",
    "sun_glossy_supported",
    "sun_glossy_uniforms",
    "sun_glossy_vertex_params",
    "sun_shape_resolved",
    "sun_widened",
    "tail_scale",
    "varying_lobe_arrays",
]
