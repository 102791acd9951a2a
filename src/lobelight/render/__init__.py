"""Real-time rendering of fitted models (Green et al. 2006, section 5).

- :class:`Renderer` ``(model, env, width, height, *, backend="gl"|"torch", base_res, device)``;
  :meth:`Renderer.render` ``(camera, light_rotation=None, *, diffuse, glossy, background,
  return_mask) -> (H, W, 3)`` linear radiance, float32 (a torch tensor on the CPU for
  ``"gl"``, on ``device`` for ``"torch"``).
- Backends: ``"gl"`` runs ``shaders/prt.glsl`` through moderngl (EGL headless; Mesa llvmpipe on
  a CPU, the NVIDIA driver on a GPU); ``"torch"`` does the same stages in torch on any device
  (``_torch.py``, by ray casting), and is what the shaders are tested against.
- :class:`Lighting` an environment ready to render: prefiltered chain, SH projection, rotation.
- :func:`tonemap` exposure, ``"srgb"`` or ``"aces"``, to 8-bit; :func:`auto_exposure`;
  :func:`save_image` (``.png`` tone-mapped, ``.exr``/``.hdr`` linear), atomically.
- :class:`GLSGBRDFRenderer` the SG-mixture BRDF method (and FIS-40) in GLSL
  (``_gl_sgbrdf.py``, ``shaders/sgbrdf.glsl``); :func:`bench_gl` times the two.
- :class:`Camera` Mitsuba 3's perspective sensor (re-exported from :mod:`lobelight.camera`).
"""

from ..camera import Camera
from ._gl_sgbrdf import GLSGBRDFRenderer, bench_gl
from ._lighting import Lighting, as_rotation
from ._renderer import Renderer
from ._tonemap import auto_exposure, save_image, tonemap

__all__ = [
    "Camera",
    "GLSGBRDFRenderer",
    "Lighting",
    "Renderer",
    "as_rotation",
    "auto_exposure",
    "bench_gl",
    "save_image",
    "tonemap",
]
