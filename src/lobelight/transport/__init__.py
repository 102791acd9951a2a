"""Light-transport sampling per vertex and view: the data the Gaussian fit consumes.

- :func:`sample` tabulates a batch of vertices for every view: direct glossy ``f_s V cos`` on a
  cube map of directions, indirect glossy by path tracing (binned on a cube map), and the
  self-shadowed diffuse transfer as order-5 SH (:class:`TransportBatch`).
- :class:`Transport` evaluates each part where a caller needs it (e.g. visibility and direct
  glossy on a dense local grid around a sharp lobe), and the indirect glossy transport as one
  Gaussian per vertex and view from the paths' moments, each vertex's paths shared across its
  views and no sharper than the lobe that gathers them (:meth:`Transport.indirect_lobes`,
  :func:`gathering_sharpness`).
- :func:`diffuse_interreflection` adds bounces of diffuse interreflection to the SH transfer,
  with the light the hit points' glossy lobes send (from their fitted Gaussians).
- :func:`vertex_origins` where each vertex's rays start: moved off the other side of a hard
  edge, and, for a vertex covered by a surface just over it, to the nearest clearly more
  exposed point of its own faces, whose transport it takes (:class:`VertexOrigins`).
- :data:`BOUNCES` and :data:`INDIRECT_PATHS` are a bake's defaults (docs/method.md).
"""

from ._interreflection import diffuse_interreflection
from ._origins import (
    EXPOSED_FLOOR,
    EXPOSED_GAIN,
    EXPOSED_STEPS,
    VertexOrigins,
    vertex_origins,
)
from ._transport import (
    BOUNCES,
    DIFFUSE_ORDER,
    INDIRECT_LAM_RANGE,
    INDIRECT_PATHS,
    LONE_PATH_LAM,
    SHARED_LAM_MAX,
    Transport,
    TransportBatch,
    gathering_sharpness,
    sample,
)

__all__ = [
    "BOUNCES",
    "DIFFUSE_ORDER",
    "EXPOSED_FLOOR",
    "EXPOSED_GAIN",
    "EXPOSED_STEPS",
    "INDIRECT_LAM_RANGE",
    "INDIRECT_PATHS",
    "LONE_PATH_LAM",
    "SHARED_LAM_MAX",
    "Transport",
    "TransportBatch",
    "VertexOrigins",
    "diffuse_interreflection",
    "gathering_sharpness",
    "sample",
    "vertex_origins",
]
