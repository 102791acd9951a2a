"""A procedural HDR environment, so that nothing needs a file: :func:`builtin`.

The map is designed as a test light: all-frequency and asymmetric, so that blur, aliasing,
power and orientation bugs show.

- Sky (upper hemisphere): white-ish near the horizon, blue at the zenith, with a soft warm glow
  around the sun.
- Sun: a disc of angular radius 0.6 degrees at elevation 35 degrees and azimuth 120 degrees
  (``phi = atan2(x, -z)``, so it stands towards +X and a little +Z), slightly warm. Its
  radiance is set so that it carries half of the map's total power (mean over RGB), which
  makes it ~1.7e4 — the scale of a real unclipped sun in a 1k map.
- Three thin bright strips in the sky like studio light panels, at different azimuths,
  elevations and colours (red-ish, green-ish, white), with hard edges.
- Ground (lower hemisphere): dark and warm, a checkerboard of 0.5-unit tiles on the plane one
  unit below the viewer (offset so that it is not symmetric about any axis), fading out near
  the horizon where tiles become smaller than a pixel.

Every pixel is the average of the analytic radiance over its cell (the lat-long cells of
:mod:`lobelight.envmap._envmap`), from a 3 x 3 grid of equal-area sub-samples; the sun's disc
is spread over the pixels it touches by 16384 stratified samples of the disc, so its power is
exact at any resolution. Anti-aliased and deterministic.
"""

from __future__ import annotations

import math

import torch

from ..errors import InputError
from ._envmap import EnvMap, _cell_average, _latlong_row_weights, _LatlongCells

__all__ = ["SUN_DIRECTION", "SUN_RADIUS", "builtin"]

_DEG = math.pi / 180
SUN_ELEVATION = 35 * _DEG
SUN_AZIMUTH = 120 * _DEG  # Mitsuba's phi: 0 = -Z, 90 deg = +X
SUN_RADIUS = 0.6 * _DEG
# (sin phi cos e, sin e, -cos phi cos e): Mitsuba's lat-long direction of (phi, elevation e)
SUN_DIRECTION = (
    math.sin(SUN_AZIMUTH) * math.cos(SUN_ELEVATION),
    math.sin(SUN_ELEVATION),
    -math.cos(SUN_AZIMUTH) * math.cos(SUN_ELEVATION),
)
_SUN_COLOUR = (1.0, 0.93, 0.82)
_SUN_FRACTION = 0.5  # share of total power (mean over RGB) carried by the sun

# strips: (azimuth from, azimuth to, elevation centre, half height) in degrees, RGB radiance
_STRIPS = (
    ((200.0, 230.0, 20.0, 0.7), (40.0, 12.0, 10.0)),
    ((300.0, 315.0, 50.0, 0.5), (10.0, 35.0, 12.0)),
    ((30.0, 70.0, 8.0, 0.4), (28.0, 28.0, 30.0)),
)
_ZENITH = (0.12, 0.25, 0.75)
_HORIZON = (0.95, 0.97, 1.0)
_GROUND = (0.30, 0.21, 0.14)

_SKY_SUBSAMPLES = 3  # per pixel along each axis
_SUN_SAMPLES = (64, 256)  # rings x azimuths of the disc's samples


def _sky(d: torch.Tensor) -> torch.Tensor:
    """Radiance of everything but the sun, ``(N, 3)`` unit directions -> ``(N, 3)``."""
    x, y, z = d.unbind(-1)
    rgb = lambda c: torch.tensor(c, dtype=d.dtype, device=d.device)  # noqa: E731
    up = y.clamp_min(0)
    # sky: horizon colour blending to the zenith's with the square root of the elevation sine
    t = up.sqrt().unsqueeze(-1)
    sky = rgb(_HORIZON) * (1 - t) + rgb(_ZENITH) * t
    cos_sun = d @ rgb(SUN_DIRECTION)
    glow = 1.5 * torch.exp((cos_sun - 1) / 0.02).unsqueeze(-1) * rgb((1.0, 0.8, 0.55))
    sky = sky + glow
    phi = torch.remainder(torch.atan2(x, -z), 2 * math.pi) / _DEG
    elev = torch.asin(y.clamp(-1, 1)) / _DEG
    for (a0, a1, e0, hh), colour in _STRIPS:
        inside = (phi >= a0) & (phi <= a1) & ((elev - e0).abs() <= hh)
        sky = torch.where(inside.unsqueeze(-1), rgb(colour), sky)
    # ground: checkerboard on the plane y = -1, faded to its mean towards the horizon
    down = (-y).clamp_min(1e-6)
    px, pz = x / down + 0.23, z / down - 0.11
    tile = (torch.floor(px / 0.5) + torch.floor(pz / 0.5)).remainder(2)
    fade = ((-y - 0.02) / 0.15).clamp(0, 1)
    albedo = 0.65 + fade * (tile - 0.5) * 0.7  # 0.3 / 1.0 where resolved, 0.65 at the horizon
    ground = rgb(_GROUND) * albedo.unsqueeze(-1) * (1 + 0.6 * (1 - fade)).unsqueeze(-1)
    return torch.where((y >= 0).unsqueeze(-1), sky, ground)


def builtin(*, height: int = 512) -> EnvMap:
    """The built-in sky as a ``(height, 2 height, 3)`` lat-long :class:`EnvMap`, "builtin-sky".

    Parameters
    ----------
    height : rows H (>= 8); the width is 2 H

    Returns
    -------
    EnvMap on the CPU (module docstring for the content).
    """
    if isinstance(height, bool) or int(height) != height or height < 8:
        raise InputError("height", f"must be an integer >= 8, got {height!r}")
    h, w = int(height), 2 * int(height)
    # the sky: each pixel the mean of a 3 x 3 grid of equal-area samples of its cell
    cells = _LatlongCells(h, w)
    img = _cell_average(cells, _sky, supersample=_SKY_SUBSAMPLES).reshape(h, w, 3)

    # The sun, splatted: equal-solid-angle stratified samples of its disc (a polar grid,
    # uniform in cos(angle from the centre) and in azimuth), each adding its share of the disc's
    # power to the pixel it falls in. Exact in power at any resolution, anti-aliased to
    # 1/_SUN_SAMPLES of a pixel's coverage.
    n_ring, n_az = _SUN_SAMPLES
    cos_r = math.cos(SUN_RADIUS)
    ka = (torch.arange(n_ring, dtype=torch.float64) + 0.5) / n_ring
    kb = (torch.arange(n_az, dtype=torch.float64) + 0.5) / n_az
    cos_rho = (1 - ka * (1 - cos_r))[:, None]  # (n_ring, 1)
    sin_rho = (1 - cos_rho**2).sqrt()
    psi = 2 * math.pi * kb[None, :]  # (1, n_az)
    centre = torch.tensor(SUN_DIRECTION, dtype=torch.float64)
    e1 = torch.nn.functional.normalize(
        torch.linalg.cross(centre, torch.tensor([0.0, 1, 0]).double()), dim=0
    )
    e2 = torch.linalg.cross(centre, e1)
    d = (
        cos_rho[..., None] * centre
        + sin_rho[..., None] * (torch.cos(psi)[..., None] * e1 + torch.sin(psi)[..., None] * e2)
    ).reshape(-1, 3)  # (n_ring n_az, 3)
    omega_disc = 2 * math.pi * (1 - cos_r)
    hits = torch.zeros(cells.n, dtype=torch.float64)
    hits.index_add_(
        0,
        cells.locate(d.float()),
        torch.full((d.shape[0],), omega_disc / d.shape[0], dtype=torch.float64),
    )
    # a pixel's value times its power weight must give its share of the disc's solid angle
    coverage = (hits / cells.measure()).float().reshape(h, w, 1)

    # Scale the sun so that it carries _SUN_FRACTION of the power (mean over RGB).
    wrow = _latlong_row_weights(h) * (2 * math.pi / w)  # (H,) power weight of each pixel
    sky_power = float((img.double().sum(1) * wrow[:, None]).sum() / 3)
    colour = torch.tensor(_SUN_COLOUR)
    radiance = _SUN_FRACTION / (1 - _SUN_FRACTION) * sky_power / (omega_disc * float(colour.mean()))
    img = img + coverage * (radiance * colour)
    return EnvMap(img, layout="latlong", name="builtin-sky")
