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
- :data:`BOUNCES` and :data:`INDIRECT_PATHS` are a bake's defaults (docs/method.md).
"""

from ._interreflection import diffuse_interreflection
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
    "INDIRECT_LAM_RANGE",
    "INDIRECT_PATHS",
    "LONE_PATH_LAM",
    "SHARED_LAM_MAX",
    "Transport",
    "TransportBatch",
    "diffuse_interreflection",
    "gathering_sharpness",
    "sample",
]
