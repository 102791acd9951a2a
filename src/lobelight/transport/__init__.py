"""Light-transport sampling per vertex and view: the data the Gaussian fit consumes.

- :func:`sample` tabulates a batch of vertices for every view: direct glossy ``f_s V cos`` on a
  cube map of directions, indirect glossy by path tracing (binned on a cube map), and the
  self-shadowed diffuse transfer as order-5 SH (:class:`TransportBatch`).
- :class:`Transport` evaluates each part where a caller needs it (e.g. visibility and direct
  glossy on a dense local grid around a sharp lobe).
- :func:`diffuse_interreflection` adds bounces of diffuse interreflection to the SH transfer.
"""

from ._transport import (
    DIFFUSE_ORDER,
    Transport,
    TransportBatch,
    diffuse_interreflection,
    sample,
)

__all__ = ["DIFFUSE_ORDER", "Transport", "TransportBatch", "diffuse_interreflection", "sample"]
