"""``base_res="auto"``: the prefiltered chain's base resolution from the model's sharpest lobes
and the map's own resolution (``lobelight.render.auto_base_res``)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest
import torch

from lobelight import brdf
from lobelight.envmap import TEXELS_PER_SIGMA, EnvMap
from lobelight.render import (
    AUTO_BASE_BLUR,
    AUTO_BASE_RES_MAX,
    AUTO_BASE_RES_MIN,
    Renderer,
    auto_base_res,
)
from lobelight.scene import Materials


def _model(spec, v: int = 16):
    # auto_base_res reads the materials alone
    return SimpleNamespace(materials=Materials(torch.full((v, 3), 0.2), spec))


def _map(width: int) -> EnvMap:
    return EnvMap(torch.ones(width // 2, width, 3), layout="latlong")


def _base_sigma(res: int) -> float:
    # the base level's Gaussian: TEXELS_PER_SIGMA texels of 2 / res radians at a face's centre
    return 2 * TEXELS_PER_SIGMA / res


@pytest.mark.parametrize(
    ("alpha", "expected"), [(0.002, 1024), (0.0116, 1024), (0.02, 512), (0.05, 256)]
)
def test_a_sharper_ggx_lobe_gets_a_finer_chain(alpha, expected):
    # GGX at normal incidence peaks at D(n) / 4 = 1 / (4 pi alpha^2) per steradian over its
    # albedo: the Gaussian of that peak has sigma = sqrt(2) alpha. The chosen base level's
    # Gaussian is at most AUTO_BASE_BLUR of it and half the resolution's is not (alpha 0.05 is
    # resolved at the smallest; alpha 0.002 would need 4096 and takes the largest by default)
    res = auto_base_res(_model(brdf.GGX(alpha=alpha, specular=0.9)), _map(1024))
    assert res == expected
    sigma = math.sqrt(2) * alpha
    if res < AUTO_BASE_RES_MAX:
        assert _base_sigma(res) <= AUTO_BASE_BLUR * sigma
    if res > AUTO_BASE_RES_MIN:
        assert _base_sigma(res // 2) > AUTO_BASE_BLUR * sigma


def test_a_round_lobe_is_its_own_gaussian():
    # a Phong lobe cos^e about the mirror direction is a Gaussian of sigma 1 / sqrt(e): e 600
    # (sigma 0.041, half of it above 256's 0.0195) keeps 256, e 20,000 (0.0071) needs 1024
    assert auto_base_res(_model(brdf.Phong(specular=0.3, exponent=600.0)), _map(1024)) == 256
    assert auto_base_res(_model(brdf.Phong(specular=0.3, exponent=2e4)), _map(1024)) == 1024


def test_a_material_without_a_glossy_lobe_takes_the_smallest():
    assert auto_base_res(_model(None), _map(1024)) == AUTO_BASE_RES_MIN


def test_the_map_caps_the_resolution():
    # four texels per map texel at most: a 256-wide lat-long map has 64 per cube face
    mirror = _model(brdf.GGX(alpha=0.002, specular=0.9))
    assert auto_base_res(mirror, _map(256)) == 256
    assert auto_base_res(mirror, _map(64)) == 64  # below the smallest: the map's cap
    assert auto_base_res(mirror, _map(4096)) == AUTO_BASE_RES_MAX
    cube = EnvMap(torch.ones(6, 32, 32, 3), layout="cubemap")
    assert auto_base_res(mirror, cube) == 128


def test_the_sharpest_tenth_of_the_vertices_decides():
    # one vertex in five mirror-like (alpha 0.004), the rest rough: the sharpest tenth is
    # mirror-like; one in twenty is not enough
    for every, expected in ((5, 1024), (20, AUTO_BASE_RES_MIN)):
        alpha = torch.full((100,), 0.3)
        alpha[::every] = 0.004
        spec = brdf.GGX(alpha=alpha, specular=0.9)
        assert auto_base_res(_model(spec, v=100), _map(1024)) == expected


def test_the_renderer_chooses_the_chain_for_its_model(model_sharp_small):
    model, env = model_sharp_small
    with Renderer(model, env, 8, 8, backend="torch", samples=1) as ren:
        assert ren.lighting.base_res == auto_base_res(model, env)
    with Renderer(model, env, 8, 8, backend="torch", samples=1, base_res=64) as ren:
        assert ren.lighting.base_res == 64


@pytest.fixture(scope="module")
def model_sharp_small():
    from lobelight.bench.synthetic import synthetic_model

    model = synthetic_model(200, 1)
    model.materials = Materials(model.materials.diffuse, brdf.GGX(alpha=0.004, specular=0.9))
    # a 128-wide map: the cap (128) is below the smallest, so the chain stays small
    return model, _map(128)


def test_the_machine_s_memory_caps_the_resolution(monkeypatch):
    # a machine whose memory share holds no chain above 256 gets 256 for a mirror, as the
    # command line's --base-res maximum says
    from lobelight import _memory

    budget = 6 * 256**2 * _memory.PREFILTER_BYTES_PER_TEXEL / _memory.MEMORY_SHARE
    monkeypatch.setattr(_memory, "memory_bytes", lambda: int(budget * 1.5))
    assert _memory.max_base_res() == 256
    assert auto_base_res(_model(brdf.GGX(alpha=0.002, specular=0.9)), _map(1024)) == 256
