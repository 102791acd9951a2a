"""Spherical lights as cosine lobes (paper 5.2), and the cap lobe with the right scale.

A light of centre ``p``, radius ``r`` and radiance ``Le`` is seen from ``x`` as the cap of
half-angle ``theta = asin(r / |p - x|)`` around ``h = (p - x) / |p - x|``. The paper's lobe is
``max(h . w, 0)^e_cap`` with scale 1 and ``e_cap`` the L2-best exponent (its eq. 31-34, the cap
table). With scale 1 that lobe's integral ``2 pi / (e + 1)`` misses the cap's solid angle
``Omega = 2 pi (1 - cos theta)`` by -6.9 % to +4.0 % (depending on ``theta``; :mod:`._tables`,
tested in ``tests/test_cosine_tables.py``), an error in every light's power. Here the exponent
is the paper's and the scale makes the integrals equal: ``scale = Omega (e + 1) / (2 pi)``
(:func:`cap_lobe`), so an unoccluded light delivers exactly its power up to the shape of the
lobe. The same lobe, with unit radiance, stands for occluder and shadow-leaf caps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from .._tol import DIVISOR_F32
from ..errors import InputError
from ._lobeset import Lobes
from ._tables import LobeTables

__all__ = ["SphereLight", "cap_lobe", "cap_lobes", "light_lobes"]

_TWO_PI = 2 * math.pi


def cap_scale(theta: torch.Tensor, exponent: torch.Tensor) -> torch.Tensor:
    """``Omega (e + 1) / (2 pi) = (1 - cos theta)(e + 1)``, with ``1 - cos`` as ``2 sin^2(theta/2)``
    (no cancellation for small caps, where ``e ~ 0.96 / (1 - cos)`` and the product is ~1.96)."""
    return 2 * torch.sin(theta / 2) ** 2 * (exponent + 1)


def cap_lobe(axis: torch.Tensor, theta: torch.Tensor, *, tables: LobeTables):
    """The lobe of the cap of half-angle ``theta`` around ``axis``, integral = solid angle.

    Parameters
    ----------
    axis : (..., 3) unit;  theta : (...) radians in ``(0, pi/2]``
    tables : the lobe tables (cap exponent)

    Returns
    -------
    exponent : (...);  scale : (...) such that ``2 pi scale / (e + 1) = 2 pi (1 - cos theta)``
    """
    e = tables.cap_exponent(theta)
    return e, cap_scale(theta, e)


@dataclass(frozen=True)
class SphereLight:
    """A spherical light: ``centre`` (3,), ``radius`` > 0, RGB ``radiance`` (3,) >= 0."""

    centre: tuple[float, float, float]
    radius: float
    radiance: tuple[float, float, float]

    def __post_init__(self) -> None:
        c = torch.as_tensor(self.centre, dtype=torch.float64).reshape(-1)
        if c.numel() != 3 or not bool(torch.isfinite(c).all()):
            raise InputError("light.centre", f"must be 3 finite numbers, got {self.centre!r}")
        r = float(self.radius)
        if not math.isfinite(r) or r <= 0:
            raise InputError("light.radius", f"must be finite and > 0, got {self.radius!r}")
        le = torch.as_tensor(self.radiance, dtype=torch.float64).reshape(-1)
        if le.numel() == 1:
            le = le.expand(3)
        if le.numel() != 3 or not bool(torch.isfinite(le).all()) or bool((le < 0).any()):
            raise InputError(
                "light.radiance", f"must be 1 or 3 finite numbers >= 0, got {self.radiance!r}"
            )
        object.__setattr__(self, "centre", tuple(float(v) for v in c))
        object.__setattr__(self, "radius", r)
        object.__setattr__(self, "radiance", tuple(float(v) for v in le))


def _light_tensors(lights, like: torch.Tensor):
    """(J, 3) centres, (J,) radii, (J, 3) radiances on ``like``'s device."""
    kw = {"dtype": like.dtype, "device": like.device}
    centres = torch.tensor([lt.centre for lt in lights], **kw)
    radii = torch.tensor([lt.radius for lt in lights], **kw)
    radiance = torch.tensor([lt.radiance for lt in lights], **kw)
    return centres, radii, radiance


def light_geometry(points: torch.Tensor, lights):
    """Per point and light: unit axis (P, J, 3), distance (P, J), cap half-angle (P, J).

    A point inside a light (``distance <= radius``) sees a hemisphere of light: ``theta`` is
    clamped to ``pi/2`` (the cap lobe is then the cosine-0 hemisphere).
    """
    centres, radii, _ = _light_tensors(lights, points)
    return _geometry(points, centres, radii)


def _geometry(points, centres, radii):
    """:func:`light_geometry` from (J, 3) centres and (J,) radii."""
    d = centres.unsqueeze(0) - points.unsqueeze(1)  # (P, J, 3)
    dist = torch.linalg.vector_norm(d, dim=-1)
    axis = d / dist.clamp_min(DIVISOR_F32).unsqueeze(-1)
    theta = torch.asin((radii / dist.clamp_min(DIVISOR_F32)).clamp(max=1.0))
    return axis, dist, theta


def light_lobes(points: torch.Tensor, lights, *, tables: LobeTables) -> Lobes:
    """Incident radiance of the spherical lights as one cap lobe each.

    Parameters
    ----------
    points : (P, 3)
    lights : sequence of :class:`SphereLight`

    Returns
    -------
    :class:`~._lobeset.Lobes`: axis (P, J, 3), exponent (P, J), scale (P, J, 3) =
    ``Le * Omega (e + 1) / (2 pi)``
    """
    return cap_lobes(points, *_light_tensors(lights, points), tables=tables)


def cap_lobes(points, centres, radii, radiance, *, tables: LobeTables) -> Lobes:
    """:func:`light_lobes` from light tensors: centres (J, 3), radii (J,), radiance (J, 3).

    Tensors rather than :class:`SphereLight` objects, so that a compiled caller
    (:mod:`._fused`) sees a moving light as new data, not as new constants.
    """
    axis, _, theta = _geometry(points, centres, radii)
    e, s = cap_lobe(axis, theta, tables=tables)
    return Lobes(axis, e, s.unsqueeze(-1) * radiance.unsqueeze(0))
