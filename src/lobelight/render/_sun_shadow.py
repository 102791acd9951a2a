"""The sun's soft shadow: the visible fraction of its disc, the same way in both renderers.

A sun (:class:`lobelight.envmap.Sun`) is shadowed as a uniform disc of angular radius
``sqrt(2) spread`` (:func:`disc_radius`: the uniform disc with the sun's RMS angle), seen through
``SHADOW_SAMPLES`` fixed directions over it: point ``i`` of a Vogel (Fibonacci) spiral, at
``sqrt((i + 1/2) / N)`` of the disc's radius and ``i`` golden angles round, in the tangent frame
of :func:`sun_frame` (the shadow map's). Stratified and deterministic: every frame and both
renderers see the same points. A pixel's samples share them out (:func:`sample_taps`): sample
``i`` of ``S`` takes every ``S``-th direction from the ``i``-th, so the pixel, the mean of its
samples, still sees every direction once (for ``S`` up to ``SHADOW_SAMPLES``) at a
``S``-th of the cost per sample: the samples already average the shadow over the pixel.

- torch (:func:`disc_visibility`): one shadow ray along each direction, ``l + tan(r) (x u + y v)``
  normalised; the visibility is the fraction that escape.
- shader (``shaders/prt.glsl``, ``sun_visibility``): percentage-closer soft shadows in the
  orthographic shadow map. A ray towards direction ``i`` passes a blocker at height ``h`` above
  the point (along the sun) at ``h tan(r) (x_i, y_i)`` across the map: a blocker search over the
  disc that the farthest possible blocker (the mesh's bounding sphere) spans, with
  ``BLOCKER_SAMPLES`` points, gives the mean height of the blockers; each of the spiral's
  ``SHADOW_SAMPLES`` directions is then placed at that height, moved to the height of the
  blocker found there (one step of the ray's own crossing), and its depth comparison taken
  with the hardware's 2 x 2 filter. Every tap compares against the receiver's plane at the tap
  (the triangle's plane, from the position's screen derivatives), so a tilted surface does not
  shadow itself. For blockers at one height the shader tests the rays the torch path casts;
  where they lie at several heights the one step approximates each ray's crossing.

A disc narrower than a shadow-map texel at the farthest blocker keeps the single hardware-filtered
comparison (and torch its single ray to the centre): a hard shadow.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ..envmap import Sun

__all__ = [
    "ALL_TAPS",
    "BLOCKER_SAMPLES",
    "SHADOW_SAMPLES",
    "disc_points",
    "disc_radius",
    "disc_visibility",
    "sample_taps",
    "sun_frame",
]

#: Directions over the sun's disc: shadow rays per point (torch), filter taps (shader).
SHADOW_SAMPLES = 32
#: Taps of the shader's blocker search.
BLOCKER_SAMPLES = 16
#: Every direction: the share of a pixel's only sample.
ALL_TAPS = slice(0, None, 1)
#: The golden angle, radians: the spiral's turn from one point to the next.
_GOLDEN = math.pi * (3.0 - math.sqrt(5.0))
#: A disc narrower than this (radians) is shadowed by one ray to its centre in torch.
_HARD_RADIUS = 1e-5


def disc_radius(sun: Sun) -> float:
    """The angular radius (radians) of the uniform disc with the sun's RMS angle, ``sqrt(2)
    spread``: what its shadow is cast from."""
    return math.sqrt(2.0) * float(sun.spread)


def disc_points(n: int, *, dtype=torch.float64, device=None) -> torch.Tensor:
    """``(n, 2)`` points of the Vogel spiral over the unit disc (module docstring): point ``i``
    at radius ``sqrt((i + 1/2) / n)`` and angle ``i`` golden angles."""
    i = torch.arange(n, dtype=dtype, device=device)
    r = ((i + 0.5) / n).sqrt()
    a = i * _GOLDEN
    return torch.stack([r * a.cos(), r * a.sin()], -1)


def sample_taps(i: int, n: int) -> slice:
    """The directions over the disc that sample ``i`` of a pixel's ``n`` takes, as a slice of
    the spiral's ``SHADOW_SAMPLES`` points: every ``min(n, SHADOW_SAMPLES)``-th from
    ``i mod`` that (the shader's ``tap_first``, ``tap_step``). Together a pixel's samples take
    each direction once where ``n`` divides ``SHADOW_SAMPLES``, and each at least once for
    any ``n``."""
    if not 0 <= i < n:
        raise ValueError(f"sample {i} of {n}")
    step = min(n, SHADOW_SAMPLES)
    return slice(i % step, None, step)


def sun_frame(l) -> np.ndarray:
    """``(3, 3)`` float64 rows ``u, v, l``: two tangents and the direction towards the sun
    (normalised), the frame of the shadow map and of the disc's points."""
    l = np.asarray(l, np.float64)
    l = l / np.linalg.norm(l)
    a = np.array([1.0, 0.0, 0.0]) if abs(l[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(l, a)
    u /= np.linalg.norm(u)
    v = np.cross(l, u)
    return np.stack([u, v, l])


def disc_directions(l: torch.Tensor, radius: float, n: int = SHADOW_SAMPLES) -> torch.Tensor:
    """``(n, 3)`` unit directions over a disc of angular ``radius`` about ``l (3,)``: the
    spiral's points at ``l + tan(radius) (x u + y v)`` (:func:`sun_frame`), normalised; on
    ``l``'s device and dtype."""
    f = torch.as_tensor(sun_frame(l.detach().cpu().double().numpy()))  # (3, 3)
    p = disc_points(n) * math.tan(radius)  # (n, 2)
    d = f[2] + p[:, :1] * f[0] + p[:, 1:] * f[1]  # (n, 3)
    return torch.nn.functional.normalize(d, dim=-1).to(l.device, l.dtype)


def disc_visibility(
    caster,
    pos: torch.Tensor,
    ng: torch.Tensor,
    l: torch.Tensor,
    radius: float,
    *,
    offset: float,
    taps: slice = ALL_TAPS,
) -> torch.Tensor:
    """The visible fraction of a disc of angular ``radius`` about ``l (3,)`` at points ``pos
    (P, 3)`` on triangles of geometric normals ``ng (P, 3)``: ``(P,)`` float32 on ``pos``'s
    device, one shadow ray per direction of :func:`disc_directions` in ``taps`` (a sample's
    share, :func:`sample_taps`) from the point lifted off its triangle by ``offset`` (the
    caster's :meth:`~lobelight.geometry.raycast.RayCaster.spawn`); one ray to the centre for a
    disc under ``_HARD_RADIUS``."""
    dirs = l[None] if radius < _HARD_RADIUS else disc_directions(l, radius)[taps]  # (n, 3)
    vis = torch.zeros(pos.shape[0], device=pos.device)
    for d in dirs:  # one batch of P rays per direction: the memory of one ray per point
        ray = d.expand_as(ng)
        origin = caster.spawn(pos, ng, ray, offset=offset)
        vis += (~caster.occluded(origin, ray)).to(vis.dtype)
    return vis / dirs.shape[0]
