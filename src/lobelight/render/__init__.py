"""Real-time rendering of fitted models (Green et al. 2006, section 5).

- :class:`Renderer` ``(model, env, width, height, *, backend="gl"|"torch", base_res, device,
  sun, samples=4)``; :meth:`Renderer.render` ``(camera, light_rotation=None, *, diffuse,
  glossy, background, return_mask) -> (H, W, 3)`` linear radiance, float32, non-negative (a
  torch tensor on the CPU for ``"gl"``, on ``device`` for ``"torch"``); ``return_mask=True``
  adds the bool mask of pixels entirely on the object, ``"coverage"`` its float fraction.
- Anti-aliasing: ``samples`` per pixel at :func:`sample_offsets` (a stratified n-rooks
  pattern), averaged; both backends shade the same points (the shader path one pass per
  sample with the image shifted, the torch path one ray per sample).
- Backends: ``"gl"`` runs ``shaders/prt.glsl`` through moderngl (EGL headless; Mesa llvmpipe on
  a CPU, the NVIDIA driver on a GPU); ``"torch"`` does the same stages in torch on any device
  (``_torch.py``, by ray casting), and is what the shaders are tested against.
- :class:`Lighting` an environment ready to render: prefiltered chain, SH projection, rotation;
  :func:`auto_base_res` the chain's base resolution a model's sharpest lobes need.
- :func:`tonemap` exposure, ``"neutral"`` (Khronos PBR Neutral, :func:`neutral`, the default),
  ``"srgb"`` or ``"aces"``, to 8-bit; :func:`auto_exposure` (with a curve: the highlights' rule);
  :func:`save_image` (``.png``/``.jpg`` tone-mapped, ``.exr``/``.hdr`` linear), atomically;
  :func:`check_output_path` the checks it makes first, for callers to make before rendering.
- :func:`turntable` frames over a full turn of the camera (or the light), one exposure, and a
  GIF or WebP animation of them; :func:`orbit` one camera of it.
- :class:`GLSGBRDFRenderer` the SG-mixture BRDF method (and FIS-40) in GLSL
  (``_gl_sgbrdf.py``, ``shaders/sgbrdf.glsl``); :func:`create_context` the headless context
  both OpenGL renderers use.
- :func:`stage_sources` a shader file's two stages in a GLSL dialect (desktop 3.30, or the
  web viewer's OpenGL ES 3.00), :func:`load_shader` a shader file's text.
- :func:`gl_available` whether OpenGL works here; :func:`view` an interactive window
  (:func:`require_display` checks for a display first).
- :func:`export_gltf` a model as a glTF 2.0 binary (mesh, fallback material, the lobe data as
  application-specific accessors of the ``LOBELIGHT_prt`` extension, a map as an
  ``EXT_lights_image_based`` light), :func:`import_gltf` such a file back as a model
  (``_gltf_out.py``, ``docs/gltf-export.md``).
- :class:`Camera` Mitsuba 3's perspective sensor (re-exported from
  :mod:`lobelight.geometry.camera`).
"""

from ..geometry.camera import Camera
from ._gl import create_context, gl_available, load_shader, stage_sources
from ._gl_sgbrdf import GLSGBRDFRenderer
from ._gltf_out import GLTF_EXTENSION, export_gltf, fallback_material, import_gltf
from ._lighting import (
    AUTO_BASE_BLUR,
    AUTO_BASE_RES_MAX,
    AUTO_BASE_RES_MIN,
    AUTO_SHARP_QUANTILE,
    Lighting,
    as_rotation,
    auto_base_res,
)
from ._renderer import Renderer, sample_offsets
from ._tonemap import (
    CURVES,
    DEFAULT_CURVE,
    auto_exposure,
    check_output_path,
    neutral,
    save_image,
    tonemap,
)
from ._turntable import frame_names, orbit, turntable
from ._window import Orbit, model_camera, require_display, stored_camera, view

__all__ = [
    "AUTO_BASE_BLUR",
    "AUTO_BASE_RES_MAX",
    "AUTO_BASE_RES_MIN",
    "AUTO_SHARP_QUANTILE",
    "CURVES",
    "DEFAULT_CURVE",
    "GLTF_EXTENSION",
    "Camera",
    "GLSGBRDFRenderer",
    "Lighting",
    "Orbit",
    "Renderer",
    "as_rotation",
    "auto_base_res",
    "auto_exposure",
    "check_output_path",
    "create_context",
    "export_gltf",
    "fallback_material",
    "frame_names",
    "gl_available",
    "import_gltf",
    "load_shader",
    "model_camera",
    "neutral",
    "orbit",
    "require_display",
    "sample_offsets",
    "save_image",
    "stage_sources",
    "stored_camera",
    "tonemap",
    "turntable",
    "view",
]
