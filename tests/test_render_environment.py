"""Relighting a renderer with another environment (``Renderer.set_environment``).

A renderer switched to a map must draw what a renderer made for that map draws: the same
chain (built by a ChainBuilder instead of prefilter: equal to the bit on one device), the same
background, SH and sun, written into the textures and uniforms in place. Both backends, with
and without the sun shaded per pixel, and across a switch that makes the sun appear or
disappear, where the shader path compiles its programs again.
"""

from __future__ import annotations

import pytest
import torch

from conftest import smooth_env
from lobelight import envmap, render
from lobelight.bench import synthetic_model
from lobelight.envmap import ChainBuilder, EnvMap
from lobelight.errors import InputError
from lobelight.render import _lighting
from lobelight.render._gl import gl_available

needs_gl = pytest.mark.skipif(not gl_available(), reason="no headless OpenGL context (EGL)")

CAM = render.Camera.look_at((0.4, 1.6, 3.0), (0.0, 0.0, 0.0), fov=40)
W, H, BASE = 48, 40, 32


@pytest.fixture(scope="module")
def model():
    # a Phong material sharp enough that a sun's glossy reflection is shaded per pixel too
    return synthetic_model(300, 2)


@pytest.fixture(scope="module")
def maps() -> dict[str, EnvMap]:
    sky = envmap.builtin(height=64)
    # the same kind of sky turned 90 degrees about the vertical and tinted: another sun place
    turned = EnvMap(
        sky.data.roll(32, dims=1) * torch.tensor([1.2, 0.9, 0.7]), layout="latlong", name="turned"
    )
    return {"sky": sky, "turned": turned, "smooth": smooth_env()}


def _frame(r: render.Renderer) -> torch.Tensor:
    return r.render(CAM, 30.0)


def _fresh(model, env, backend, sun) -> torch.Tensor:
    r = render.Renderer(model, env, W, H, backend=backend, base_res=BASE, sun=sun, samples=1)
    try:
        return _frame(r)
    finally:
        r.close()


def _backends():
    return ["torch", pytest.param("gl", marks=needs_gl)]


@pytest.mark.parametrize("backend", _backends())
@pytest.mark.parametrize("sun", [False, True])
def test_a_switched_renderer_draws_what_one_made_for_the_map_draws(model, maps, backend, sun):
    r = render.Renderer(
        model, maps["sky"], W, H, backend=backend, base_res=BASE, sun=sun, samples=1
    )
    try:
        first = _frame(r)
        gl = r._gl
        r.set_environment(maps["turned"])
        assert r._gl is gl  # the same programs and textures, written in place
        assert (r.lighting.sun is not None) == sun
        got = _frame(r)
        want = _fresh(model, maps["turned"], backend, sun)
        assert float((got - first).abs().max()) > 0.05 * float(first.max())  # it changed
        torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-6)
        r.set_environment(maps["sky"])  # and back
        torch.testing.assert_close(_frame(r), first, rtol=1e-5, atol=1e-6)
    finally:
        r.close()


@pytest.mark.parametrize("backend", _backends())
def test_a_sun_that_appears_or_disappears_recompiles_the_programs(model, maps, backend):
    r = render.Renderer(
        model, maps["sky"], W, H, backend=backend, base_res=BASE, sun=True, samples=1
    )
    try:
        _frame(r)
        gl = r._gl
        r.set_environment(maps["smooth"])  # a map without a sun
        assert r.lighting.sun is None and r.lighting.sun_split
        if backend == "gl":
            assert r._gl is not gl and not r._gl.has_sun
        torch.testing.assert_close(
            _frame(r), _fresh(model, maps["smooth"], backend, True), rtol=1e-5, atol=1e-6
        )
        r.set_environment(maps["sky"])
        assert r.lighting.sun is not None
        torch.testing.assert_close(
            _frame(r), _fresh(model, maps["sky"], backend, True), rtol=1e-5, atol=1e-6
        )
    finally:
        r.close()


def test_switched_chains_come_from_the_builders_not_the_disk_cache(model, maps, monkeypatch):
    r = render.Renderer(model, maps["sky"], W, H, backend="torch", base_res=BASE, samples=1)
    _frame(r)

    def no_cache(*a, **k):
        raise AssertionError("prefilter (and its disk cache) was called")

    monkeypatch.setattr(_lighting, "prefilter", no_cache)
    for name in ("turned", "smooth", "sky"):
        r.set_environment(maps[name])
        _frame(r)
    builders = r._builders
    assert all(isinstance(b, ChainBuilder) and b.base_res == BASE for b in builders)
    assert r.lighting.prefiltered is builders[0]._chain  # the builder's one chain


def test_bad_environments_are_refused_and_the_lighting_kept(model, maps):
    r = render.Renderer(model, maps["sky"], W, H, backend="torch", base_res=BASE, samples=1)
    kept = r.lighting
    with pytest.raises(InputError, match=r"env.*EnvMap or Lighting"):
        r.set_environment("sky.hdr")
    with pytest.raises(InputError, match="9 SH coefficients"):
        r.set_environment(render.Lighting(maps["turned"], base_res=BASE, sh_order=3))
    assert r.lighting is kept
    with pytest.raises(InputError, match="builders"):
        render.Lighting(
            maps["sky"], base_res=BASE, builders=(ChainBuilder(base_res=16), ChainBuilder())
        )


@needs_gl
def test_renderers_alive_together_each_draw_in_their_own_context(model, maps):
    # each headless renderer has its own GL context; GL commands go to the current one, which
    # making or releasing another context changes
    a = render.Renderer(model, maps["sky"], W, H, base_res=BASE, samples=1)
    try:
        alone = _frame(a)
        b = render.Renderer(model, maps["smooth"], W, H, base_res=BASE, samples=1)
        other = _frame(b)
        assert float((other - alone).abs().max()) > 0.05 * float(alone.max())
        torch.testing.assert_close(_frame(a), alone, rtol=0, atol=0)  # b's context was current
        b.close()  # releasing b's context leaves none current
        torch.testing.assert_close(_frame(a), alone, rtol=0, atol=0)
        assert gl_available()  # makes and releases a context of its own
        torch.testing.assert_close(_frame(a), alone, rtol=0, atol=0)
    finally:
        a.close()


def test_a_lighting_of_another_base_resolution_then_a_map(model, maps):
    # the renderer takes the given Lighting's base resolution, and the next map is prepared at
    # it (its chain builders made again for it)
    r = render.Renderer(model, maps["sky"], W, H, backend="torch", base_res=BASE, samples=1)
    r.set_environment(maps["turned"])
    r.set_environment(render.Lighting(maps["turned"], base_res=16))
    r.set_environment(maps["smooth"])
    assert r.lighting.base_res == 16 and r._builders[0].base_res == 16
    torch.testing.assert_close(
        _frame(r), _fresh_at(model, maps["smooth"], 16), rtol=1e-5, atol=1e-6
    )


def _fresh_at(model, env, base_res) -> torch.Tensor:
    r = render.Renderer(model, env, W, H, backend="torch", base_res=base_res, samples=1)
    return _frame(r)
