"""The self-contained WebGL 2 viewer of a fitted model (``docs/web-viewer.md``).

- :func:`export_web` ``(model, out, envs, *, base_res, sun, device, inputs, float16)`` writes
  a folder that a browser opens from ``file://`` or any static server, with no network and no
  build step: the page (``index.html``, ``viewer.js``), the shared shader files in the page's GLSL
  ES 3.00 dialect (``shaders.js``, assembled by :func:`lobelight.render.stage_sources` with
  :func:`dialect`), and the model and each map as data files of half floats.
- :func:`read_web` loads such a folder back and checks it (:class:`WebFolder`).
- :func:`serve` serves a folder on localhost with the standard library's HTTP server.
"""

from ._export import (
    MAX_BACKGROUND_RES,
    WEB_VERSION,
    WebFolder,
    dialect,
    export_web,
    read_web,
)
from ._serve import serve, tunnel_hint

__all__ = [
    "MAX_BACKGROUND_RES",
    "WEB_VERSION",
    "WebFolder",
    "dialect",
    "export_web",
    "read_web",
    "serve",
    "tunnel_hint",
]
