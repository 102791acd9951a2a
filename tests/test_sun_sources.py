"""A compact bright source is found by its concentration wherever it stands: a sun on the horizon,
low or high over a sky gradient, the bundled maps' sun and softbox; an overcast sky has none."""

from __future__ import annotations

import math

import pytest
import torch

from conftest import REAL_ENVMAPS
from lobelight import envmap
from lobelight.envmap._envmap import _LatlongCells


def _direction(elevation_deg: float, azimuth_deg: float) -> torch.Tensor:
    """Mitsuba's lat-long direction of an elevation and azimuth (phi = atan2(x, -z))."""
    e, a = math.radians(elevation_deg), math.radians(azimuth_deg)
    return torch.tensor(
        [math.sin(a) * math.cos(e), math.sin(e), -math.cos(a) * math.cos(e)], dtype=torch.float64
    )


def _sky(
    sun_elevation: float | None, *, radius: float = 0.5, h: int = 256, w: int = 512
) -> envmap.EnvMap:
    """A clear sky's gradient (bright at the horizon, bluer and darker at the zenith) over a dim
    ground, with a sun disc of ``radius`` degrees at azimuth 60 degrees, or none (overcast).

    The sun carries 5-8 % of the map's power: a low sun's share, under the 20 % a rule by the
    whole map's power would ask for, and it is still what casts the scene's shadows."""
    dirs = _LatlongCells(h, w).frames()[0].double().reshape(h, w, 3)
    y = dirs[..., 1]
    sky = (
        torch.tensor([0.9, 1.0, 1.2], dtype=torch.float64)
        * (0.6 + 1.4 * (1 - y.clamp_min(0)) ** 3)[..., None]
    )
    ground = torch.tensor([0.25, 0.2, 0.15], dtype=torch.float64).expand(h, w, 3)
    data = torch.where((y >= 0)[..., None], sky, ground).clone()
    if sun_elevation is not None:
        inside = (dirs @ _direction(sun_elevation, 60.0)) >= math.cos(math.radians(radius))
        data[inside] += 2000.0
    return envmap.EnvMap(data.float(), layout="latlong", name=f"sky-{sun_elevation}")


@pytest.mark.parametrize("elevation", [0.0, 10.0, 45.0])
def test_a_sun_is_found_at_any_elevation(elevation):
    env = _sky(elevation)
    sun, rest = envmap.extract_sun(env)
    assert sun is not None
    # its share of the whole map is under what a share rule (0.2) would need: found by its
    # concentration alone
    share = float(sun.irradiance.mean() / env.power().mean())
    assert 0.03 < share < 0.1
    # the direction to a fraction of a pixel (0.7 degrees): on the horizon, half of the disc
    # lies under the horizon's row and the pixels' centres pull it by up to half a pixel
    want = _direction(elevation, 60.0).float()
    assert math.degrees(math.acos(min(1.0, float(sun.direction @ want)))) < 0.5
    # the disc's RMS angle is under a pixel (it is 0.35 deg for a uniform 0.5 deg disc)
    assert math.degrees(sun.spread) < 0.7
    # nothing lost or made (float32 sums), and no second source left behind
    torch.testing.assert_close(rest.power() + sun.irradiance, env.power(), rtol=1e-4, atol=0)
    assert envmap.extract_sun(rest)[0] is None


def test_an_overcast_sky_has_no_sun():
    env = _sky(None)
    sun, rest = envmap.extract_sun(env)
    assert sun is None and rest is env
    # a smooth sky's brightest region (the horizon) is only about 1.5 times its ring: the rule
    # would take it at a contrast of 1.5, but not at the default
    assert envmap.extract_sun(env, min_contrast=1.2, min_share=0.0)[0] is not None


def test_a_weak_or_diffuse_bright_region_is_no_source():
    env = _sky(10.0)
    # a source that gives a surface facing it less than the asked share is left in the map
    assert envmap.extract_sun(env, min_share=0.5)[0] is None
    # and one with less contrast than asked
    assert envmap.extract_sun(env, min_contrast=1e5)[0] is None
    with pytest.raises(Exception, match="min_contrast"):
        envmap.extract_sun(env, min_contrast=0.5)
    with pytest.raises(Exception, match="min_share"):
        envmap.extract_sun(env, min_share=1.0)


def test_a_hot_pixel_does_not_hide_the_sun():
    # a disc of 2 degrees (about 25 pixels) and one pixel of the sky ten times as bright as the
    # disc, carrying a quarter of its power: the source is where the power concentrates, not at
    # the brightest pixel
    env = _sky(30.0, radius=2.0)
    data = env.data.clone()
    data[60, 40] = 2e4
    sun, _ = envmap.extract_sun(envmap.EnvMap(data, layout="latlong"))
    assert sun is not None
    want = _direction(30.0, 60.0).float()
    assert math.degrees(math.acos(min(1.0, float(sun.direction @ want)))) < 0.5


@pytest.mark.parametrize("path", REAL_ENVMAPS, ids=[p.stem for p in REAL_ENVMAPS])
def test_the_bundled_maps_sources_are_found(path):
    """The park's sun (10.6 deg high, 0.5 deg across) and the studio's softbox (about 7 deg
    across, 42 deg high) are found where they are."""
    env = envmap.load(path)
    sun, rest = envmap.extract_sun(env)
    assert sun is not None
    elevation = math.degrees(math.asin(float(sun.direction[1])))
    want = {"rooitou_park_512": 10.6, "studio_small_03_512": 41.6}[path.stem]
    # within a pixel (0.7 degrees) of where the full-resolution maps place them
    assert abs(elevation - want) < 0.7
    torch.testing.assert_close(rest.power() + sun.irradiance, env.power(), rtol=1e-4, atol=0)
