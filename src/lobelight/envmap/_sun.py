"""A compact bright light (a sun, a lamp, a window) taken out of an environment map, for
per-pixel shading with soft shadows.

Why: a real sun carries half of a clear sky's power within 0.5 deg. Order-5 SH diffuse transfer
per vertex (the paper's diffuse term) can only blur its shadow, and on the built-in knot that
blur is the full image's largest error (results.md). Game engines and Filament treat the sun as
a directional light with a shadow map next to image-based lighting; so do we: the diffuse SH
integrates the map without the sun, and the sun's diffuse light is added per pixel,
``albedo / pi * E * max(n.l, 0) * V(x)`` with ``V`` the visible fraction of its disc (shadow
rays over the disc in torch, percentage-closer soft shadows in the shader:
:mod:`lobelight.render`); its glossy light is shaded per pixel too where the renderer can
evaluate the BRDF, with the lobe widened by the disc's spread.

Finding it: the source is looked for where the most power lies within a few degrees (the
map's power pooled over cells of about ``_POOL_DEG``, then summed over 3 x 3 cells), at the
brightest pixel there: a single hot pixel does not outweigh a softbox. A window of
``radius_deg`` about the bright pixels' centre there holds the source; its pixels brighter than
``threshold`` times the peak are the disc. The background under the disc is the mean of a ring
just outside the window (``radius_deg`` to ``2 radius_deg``); what the disc carries above it is
the sun's irradiance ``E`` (RGB, W/m^2-like: radiance x steradian), its direction the
irradiance-weighted mean. In the residual map the disc pixels take the background's value, so
``residual.power() + E`` equals ``env.power()`` up to the ring's estimate of what lay under the
disc.

Whether it is a source is decided by its concentration, not by its share of the whole map (a
sun on the horizon at sunset, a window or a studio light carries little of a map's power and
still casts a shadow): the disc's mean radiance must be at least ``min_contrast`` times the
ring's, and its light at least ``min_share`` of the irradiance a surface facing it receives
from the whole map (a source too weak to darken its shadow by that much is left in the map).
Otherwise there is no sun (``None``): an overcast sky or an evenly lit interior stays whole.
The defaults lie between the sources of the real maps and those maps' brightest regions that
are not sources, with a wide margin on either side (measured in docs/results.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from .._tol import SMALL
from ..errors import InputError
from ._envmap import EnvMap, _LatlongCells

__all__ = ["MIN_CONTRAST", "MIN_SHARE", "RADIUS_DEG", "Sun", "extract_sun"]

#: The window the sun is looked for in, degrees from the bright pixels' centre around the
#: map's peak. Wide enough for an extended source (a studio's softbox): a narrower window
#: leaves the rest of the softbox in the order-5 SH, whose shadows are blurred, and takes a
#: smaller share of the map's power into the sun, which gets sharp ones. A small sun (the
#: park's, 0.4 degrees) is the same at any window: the disc is the pixels above ``threshold``
#: of the peak.
RADIUS_DEG = 10.0
#: The least ratio of the disc's mean radiance to the ring's around it for a source.
MIN_CONTRAST = 30.0
#: The least share of the irradiance on a surface facing the source that the source gives.
MIN_SHARE = 0.1
#: Size of the cells the map's power is pooled over to find the source, degrees.
_POOL_DEG = 3.0


@dataclass(frozen=True)
class Sun:
    """A distant, small light: direction (towards the light), irradiance at normal incidence.

    Attributes
    ----------
    direction : (3,) float32 unit, world frame (the unrotated map's)
    irradiance : (3,) float32 RGB, ``int_disc L dw``
    radius : float, angular radius of the disc in radians (its farthest pixel)
    spread : float, the disc's RMS angle from ``direction`` in radians, weighted by the light
        each pixel carries: the renderers widen a glossy lobe lit by the sun by it, and cast
        its shadow from a uniform disc of the same RMS angle, radius ``sqrt(2) spread``
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
    min_contrast: float = MIN_CONTRAST,
    min_share: float = MIN_SHARE,
) -> tuple[Sun | None, EnvMap]:
    """Split ``env`` into a sun and the rest (module docstring).

    Parameters
    ----------
    env : EnvMap (a cube map is resampled to lat-long first, at 4 R x 8 R)
    threshold : disc pixels are brighter than this fraction of the peak (luminance)
    radius_deg : the disc lies within this angle of the peak; the background ring spans
        ``radius_deg`` to ``2 radius_deg``
    min_contrast : the least ratio of the disc's mean radiance (mean over RGB) to the ring's
    min_share : the least share of the irradiance a surface facing the source receives from
        the whole map that the source gives (mean over RGB)

    Returns
    -------
    sun : Sun or None;  residual : EnvMap (lat-long; ``env`` itself when there is no sun)
    """
    if not 0.0 < threshold < 1.0:
        raise InputError("threshold", f"must be in (0, 1), got {threshold}")
    if not 0.0 < radius_deg <= 30.0:
        raise InputError("radius_deg", f"must be in (0, 30] degrees, got {radius_deg}")
    if not (math.isfinite(min_contrast) and min_contrast >= 1.0):
        raise InputError("min_contrast", f"must be a finite number >= 1, got {min_contrast}")
    if not 0.0 <= min_share < 1.0:
        raise InputError("min_share", f"must be in [0, 1), got {min_share}")
    c = _candidate(env, threshold, radius_deg)
    if c is None or c.contrast < min_contrast or c.facing_share < min_share:
        return None, env
    return c.sun, c.residual(env.name)


@dataclass(frozen=True)
class _Candidate:
    """The brightest compact region of a map and what decides whether it is a source.

    Attributes
    ----------
    sun : Sun, what would be taken out;  data : (H, W, 3) float64 the lat-long map;
    disc : (H, W) bool its pixels;  background : (3,) the ring's mean radiance;
    contrast : the disc's mean radiance over the ring's (means over RGB);
    facing_share : the sun's irradiance over the whole map's on a surface facing it
    """

    sun: Sun
    data: torch.Tensor
    disc: torch.Tensor
    background: torch.Tensor
    contrast: float
    facing_share: float

    def residual(self, name: str) -> EnvMap:
        """The map with the disc's pixels at most the background (lat-long)."""
        data, bg = self.data, self.background.expand_as(self.data)
        res = torch.where(self.disc[..., None], torch.minimum(data, bg), data)
        return EnvMap._trusted(res.float(), "latlong", f"{name}-without-sun")


def _candidate(env: EnvMap, threshold: float, radius_deg: float) -> _Candidate | None:
    """The map's brightest compact region as a sun, with its contrast and facing share (module
    docstring); None where it has no ring or no disc."""
    ll = env if env.layout == "latlong" else env.to_latlong(4 * env.data.shape[1])
    data = ll.data.double()  # (H, W, 3)
    h, w = data.shape[:2]
    # pixel directions and the solid angle each pixel's value stands for (EnvMap.power's)
    cells = _LatlongCells(h, w, device=data.device)
    dirs = cells.frames()[0].double().reshape(h, w, 3)
    omega = cells.measure().reshape(h, w)
    lum = data.mean(-1)  # (H, W)
    d0, peak = _peak(lum, omega, dirs)
    bright = lum >= threshold * peak
    # the window is centred on the bright pixels near the peak, not on the peak itself: a
    # flat-topped source (a clipped or uniform softbox) has its first maximum on an edge
    for _ in range(2):
        near = (dirs @ d0) >= math.cos(math.radians(radius_deg))
        wgt = (lum * omega * (near & bright))[..., None]
        d0 = torch.nn.functional.normalize((dirs * wgt).sum((0, 1)), dim=0)
    cos = dirs @ d0  # (H, W)
    near = cos >= math.cos(math.radians(radius_deg))
    ring = (~near) & (cos >= math.cos(math.radians(2 * radius_deg)))
    disc = near & bright
    if not bool(ring.any()) or not bool(disc.any()):
        return None
    wr = omega[ring]
    background = (data[ring] * wr[:, None]).sum(0) / wr.sum()  # (3,)
    excess = (data - background).clamp_min(0) * disc[..., None]  # (H, W, 3)
    e = (excess * omega[..., None]).sum((0, 1))  # (3,)
    if not float(e.mean()) > 0:
        return None
    wd = omega[disc]
    contrast = float((lum[disc] * wd).sum() / wd.sum()) / max(float(background.mean()), SMALL)
    facing = float((lum * omega * cos.clamp_min(0)).sum())  # the whole map's, facing d0
    weight = (excess.mean(-1) * omega)[..., None]  # (H, W, 1)
    direction = torch.nn.functional.normalize((dirs * weight).sum((0, 1)), dim=0)
    angle = torch.arccos((dirs @ direction).clamp(-1, 1))  # (H, W)
    radius = float(angle[disc].max())
    spread = float(((angle**2 * weight[..., 0]).sum() / weight.sum()).sqrt())
    sun = Sun(direction.float(), e.float(), radius, spread)
    return _Candidate(sun, data, disc, background, contrast, float(e.mean()) / facing)


def _peak(lum: torch.Tensor, omega: torch.Tensor, dirs: torch.Tensor) -> tuple[torch.Tensor, float]:
    """Where the map's power concentrates: the brightest pixel of the 3 x 3 pooled cells that
    hold the most power. ``lum, omega (H, W)``, ``dirs (H, W, 3)``; returns its direction
    ``(3,)`` and luminance."""
    h, w = lum.shape
    k = max(1, round(math.radians(_POOL_DEG) / (math.pi / (h - 1))))  # pixels per cell
    hc, wc = -(-h // k), -(-w // k)
    p = torch.zeros(hc * k, wc * k, dtype=lum.dtype, device=lum.device)
    p[:h, :w] = lum * omega
    cellp = p.reshape(hc, k, wc, k).sum((1, 3))  # (hc, wc) power per cell
    # 3 x 3 sums: the azimuth wraps, the poles do not
    wrap = torch.cat([cellp[:, -1:], cellp, cellp[:, :1]], 1)
    row = wrap[:, :-2] + wrap[:, 1:-1] + wrap[:, 2:]  # (hc, wc)
    pad = torch.nn.functional.pad(row, (0, 0, 1, 1))
    box = pad[:-2] + pad[1:-1] + pad[2:]
    ci, cj = divmod(int(box.argmax()), wc)
    rows = torch.arange(max(0, (ci - 1) * k), min(h, (ci + 2) * k), device=lum.device)
    cols = torch.arange((cj - 1) * k, (cj + 2) * k, device=lum.device) % w
    patch = lum[rows][:, cols]  # (r, c)
    i, j = divmod(int(patch.argmax()), cols.shape[0])
    return dirs[rows[i], cols[j]], float(patch[i, j])
