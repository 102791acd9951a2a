"""A dominant small light (a sun) taken out of an environment map, for per-pixel shadows.

Why: a real sun carries half of a clear sky's power within 0.5 deg. Order-5 SH diffuse transfer
per vertex (the paper's diffuse term) can only blur its shadow, and on the built-in knot that
blur is the full image's largest error (results.md). Game engines and Filament treat the sun as
a directional light with a shadow map next to image-based lighting; so do we: the diffuse SH
integrates the map without the sun, and the sun's diffuse light is added per pixel,
``albedo / pi * E * max(n.l, 0) * V(x, l)`` with ``V`` from a shadow map (GL) or a shadow ray
(torch); its glossy light is shaded per pixel too where the renderer can evaluate the BRDF
(:mod:`lobelight.render`), with the lobe widened by the disc's spread.

Extraction: the neighbourhood of the peak pixel (within ``radius_deg`` of the bright pixels'
centre there) holds the sun; its pixels brighter than ``threshold`` times the peak are the
disc. The background under the disc is the mean of a ring just outside the neighbourhood;
what the disc carries above it is the sun's irradiance ``E`` (RGB, W/m^2-like: radiance x
steradian), its direction the irradiance-weighted mean. In the residual map the disc pixels
take the background's value, so ``residual.power() + E`` equals ``env.power()`` up to the
ring's estimate of what lay under the disc. A map whose brightest spot carries less than
``min_share`` of the power has no sun (``None``): an overcast sky or an interior map then stays
whole.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..errors import InputError
from ._envmap import EnvMap, _LatlongCells

__all__ = ["RADIUS_DEG", "Sun", "extract_sun"]

#: The window the sun is looked for in, degrees from the bright pixels' centre around the
#: map's peak. Wide enough for an extended source (a studio's softbox): a narrower window
#: leaves the rest of the softbox in the order-5 SH, whose shadows are blurred, and takes a
#: smaller share of the map's power into the sun, which gets sharp ones. A small sun (the
#: park's, 0.4 degrees) is the same at any window: the disc is the pixels above ``threshold``
#: of the peak.
RADIUS_DEG = 10.0


@dataclass(frozen=True)
class Sun:
    """A distant, small light: direction (towards the light), irradiance at normal incidence.

    Attributes
    ----------
    direction : (3,) float32 unit, world frame (the unrotated map's)
    irradiance : (3,) float32 RGB, ``int_disc L dw``
    radius : float, angular radius of the disc in radians (its farthest pixel)
    spread : float, the disc's RMS angle from ``direction`` in radians, weighted by the light
        each pixel carries: the renderers widen a glossy lobe lit by the sun by it; the
        shadow treats the sun as a direction
    """

    direction: torch.Tensor
    irradiance: torch.Tensor
    radius: float
    spread: float = 0.0


def extract_sun(
    env: EnvMap,
    *,
    threshold: float = 0.02,
    radius_deg: float = RADIUS_DEG,
    min_share: float = 0.2,
) -> tuple[Sun | None, EnvMap]:
    """Split ``env`` into a sun and the rest (module docstring).

    Parameters
    ----------
    env : EnvMap (a cube map is resampled to lat-long first, at 4 R x 8 R)
    threshold : disc pixels are brighter than this fraction of the peak (luminance)
    radius_deg : the disc lies within this angle of the peak; the background ring spans
        ``radius_deg`` to ``2 radius_deg``
    min_share : the least share of the map's power (mean over RGB) the sun must carry

    Returns
    -------
    sun : Sun or None;  residual : EnvMap (lat-long; ``env`` itself when there is no sun)
    """
    if not 0.0 < threshold < 1.0:
        raise InputError("threshold", f"must be in (0, 1), got {threshold}")
    if not 0.0 < radius_deg <= 30.0:
        raise InputError("radius_deg", f"must be in (0, 30] degrees, got {radius_deg}")
    if not 0.0 <= min_share < 1.0:
        raise InputError("min_share", f"must be in [0, 1), got {min_share}")
    ll = env if env.layout == "latlong" else env.to_latlong(4 * env.data.shape[1])
    data = ll.data.double()  # (H, W, 3)
    h, w = data.shape[:2]
    # pixel directions and the solid angle each pixel's value stands for (EnvMap.power's)
    cells = _LatlongCells(h, w, device=data.device)
    dirs = cells.frames()[0].double().reshape(h, w, 3)
    omega = cells.measure().reshape(h, w)
    lum = data.mean(-1)  # (H, W)
    peak = int(lum.argmax())
    bright = lum >= threshold * lum.reshape(-1)[peak]
    d0 = dirs.reshape(-1, 3)[peak]
    # the window is centred on the bright pixels near the peak, not on the peak itself: a
    # flat-topped source (a clipped or uniform softbox) has its first maximum on an edge
    for _ in range(2):
        near = (dirs @ d0) >= math.cos(math.radians(radius_deg))
        wgt = (lum * omega * (near & bright))[..., None]
        d0 = torch.nn.functional.normalize((dirs * wgt).sum((0, 1)), dim=0)
    cos = dirs @ d0  # (H, W)
    near = cos >= math.cos(math.radians(radius_deg))
    ring = (~near) & (cos >= math.cos(math.radians(2 * radius_deg)))
    if not bool(ring.any()):
        return None, env
    wr = omega[ring]
    background = (data[ring] * wr[:, None]).sum(0) / wr.sum()  # (3,)
    disc = near & bright
    excess = (data - background).clamp_min(0) * disc[..., None]  # (H, W, 3)
    e = (excess * omega[..., None]).sum((0, 1))  # (3,)
    total = (data * omega[..., None]).sum((0, 1))
    if float(e.mean()) < min_share * float(total.mean()):
        return None, env
    weight = (excess.mean(-1) * omega)[..., None]  # (H, W, 1)
    direction = torch.nn.functional.normalize((dirs * weight).sum((0, 1)), dim=0)
    angle = torch.arccos((dirs @ direction).clamp(-1, 1))  # (H, W)
    radius = float(angle[disc].max())
    spread = float(((angle**2 * weight[..., 0]).sum() / weight.sum()).sqrt())
    residual = torch.where(disc[..., None], torch.minimum(data, background.expand_as(data)), data)
    sun = Sun(direction.float(), e.float(), radius, spread)
    return sun, EnvMap._trusted(residual.float(), "latlong", f"{env.name}-without-sun")
