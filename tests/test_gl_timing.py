"""The GL renderer's per-pass timing, its uniform cache and its half-float target."""

from __future__ import annotations

import math
import os

import pytest
import torch

from lobelight import envmap, render
from lobelight.bench import render as bench
from lobelight.errors import InputError
from lobelight.render._gl import PassTimer, gl_available

needs_gl = pytest.mark.skipif(not gl_available(), reason="no headless OpenGL context (EGL)")

CAM = render.Camera.look_at((0.3, 0.9, 3.0), (0.0, 0.0, 0.0), fov=40)
PASSES = (
    "uniforms",
    "shadow",
    "stage",
    "clear",
    "depth",
    "prt",
    "background",
    "resolve",
    "tonemap",
)


@pytest.fixture(scope="module")
def small_env():
    return envmap.builtin(height=64)


@pytest.fixture(scope="module")
def sun_lighting(small_env):
    return render.Lighting(small_env, base_res=32, sun=True)


@needs_gl
def test_bench_render_breaks_a_frame_into_passes(monkeypatch, small_env):
    # every pass of a display frame (sun, two samples, tone-mapping) has its times; they are
    # plain non-negative numbers in ms, and the CPU's shares fit in the frames' wall-clock time
    monkeypatch.setattr(bench, "builtin", lambda: small_env)
    kw = dict(vertices=(600,), lobes=(1,), sizes=(48,), frames=2, min_seconds=0.0, base_res=32)
    out = bench.bench_render(sun=True, samples=2, profile_frames=3, **kw)
    (row,) = out["rows"]
    assert row["target"].startswith("rgba16f") and row["frames_profiled"] == 3
    assert tuple(row["cpu_ms"]) == PASSES
    wall = row["ms_per_frame_profiled"]
    assert all(math.isfinite(t) and t >= 0 for t in row["cpu_ms"].values())
    assert row["cpu_ms"]["prt"] > 0 and 0 < row["cpu_ms_submit"]
    # sequential sections inside the profiled frames (a little slack for the clock's reads)
    assert sum(row["cpu_ms"].values()) <= 1.05 * wall + 0.1
    if "llvmpipe" in out["machine"]["gl_renderer"]:
        assert "gpu_ms" in row  # Mesa's software rasteriser has timer queries
    if "gpu_ms" in row:
        gpu = row["gpu_ms"]
        assert tuple(gpu) == PASSES
        assert all(math.isfinite(t) and t >= 0 for t in gpu.values())
        assert gpu["prt"] > 0 and gpu["shadow"] > 0
        assert row["gpu_ms_total"] == pytest.approx(sum(gpu.values()))
        # a unit check only: a software rasteriser's "GPU" time is its threads' CPU time, which
        # overlaps the frame and other passes, so the sum is not bounded by the frame itself
        assert row["gpu_ms_total"] <= 4 * (os.cpu_count() or 1) * wall + 1.0
    # the float32 target that Renderer.render reads: no tone-mapping, one sample, no sun
    (row,) = bench.bench_render(display=False, profile_frames=2, **kw)["rows"]
    assert row["target"] == "rgba32f"
    assert tuple(row["cpu_ms"]) == (
        "uniforms", "stage", "clear", "depth", "prt", "background"
    )  # fmt: skip


@needs_gl
def test_a_still_frame_writes_no_uniforms(monkeypatch, sun_lighting):
    # the per-frame values are one block, written when they change; a frame with the camera and
    # lighting of the one before writes nothing (uniform or buffer), a turned light one block
    import moderngl

    writes = []
    for cls in (moderngl.Uniform, moderngl.Buffer):
        original = cls.write

        def counted(self, *a, _original=original, _cls=cls, **kw):
            writes.append(_cls.__name__)
            return _original(self, *a, **kw)

        monkeypatch.setattr(cls, "write", counted)
    model = bench.synthetic_model(600, 2)
    with render.Renderer(model, sun_lighting, 40, 30, backend="gl", samples=4) as ren:
        gl = ren._gl
        assert gl.sun_glossy  # the Phong material's sun is shaded per pixel: every input on
        screen = gl.ctx.framebuffer([gl.ctx.texture((40, 30), 4)])
        rot = render.as_rotation(20.0)

        def frame(camera=CAM, r=rot, **parts):
            writes.clear()
            gl.draw(camera, r, **parts)
            gl.present(screen, exposure=0.5)
            return list(writes)

        assert frame()  # the first frame writes its values
        assert frame() == []
        assert frame(r=render.as_rotation(25.0)) == ["Buffer"]
        assert frame(r=render.as_rotation(25.0)) == []
        assert frame(render.orbit(CAM, 10.0), render.as_rotation(25.0)) == ["Buffer"]
        assert frame(render.orbit(CAM, 10.0), render.as_rotation(25.0), glossy=False) == ["Buffer"]
        screen.color_attachments[0].release()
        screen.release()


@needs_gl
@pytest.mark.parametrize("samples", [1, 4])
def test_the_half_float_target_rounds_the_float_image(sun_lighting, samples):
    # RGBA16F keeps 11 significant bits: one sample is within a unit in the last place (2^-10
    # relative: llvmpipe truncates), a sum of S samples within S + 1 units of the total (the
    # samples and the partial sums are all rounded, none exceeds the non-negative total);
    # coverage (multiples of 1/4) is exact; back to float32, the same frame bit for bit
    model = bench.synthetic_model(600, 3)
    rot = render.as_rotation(40.0)
    with render.Renderer(model, sun_lighting, 48, 36, backend="gl", samples=samples) as ren:
        gl = ren._gl
        gl.draw(CAM, rot)
        img, cov = gl.read()
        gl.set_hdr_dtype("f2")
        gl.draw(CAM, rot)
        half, half_cov = gl.read()
        gl.set_hdr_dtype("f4")
        gl.draw(CAM, rot)
        again, _ = gl.read()
        with pytest.raises(InputError, match="hdr_dtype"):
            gl.set_hdr_dtype("f8")
    assert float(img.min()) > 0 and bool((cov == 1).any())
    torch.testing.assert_close(half_cov, cov, rtol=0, atol=0)
    ulps = 1 if samples == 1 else samples + 1
    torch.testing.assert_close(half, img, rtol=ulps * 2.0**-10, atol=0)
    torch.testing.assert_close(again, img, rtol=0, atol=0)


class _Query:
    """A timer query whose result is always zero (a driver with no timer)."""

    def __init__(self):
        self.mglo = self

    def begin(self):
        pass

    def end(self):
        pass

    elapsed = 0


class _Ctx:
    def __init__(self, queries: bool):
        self.queries = queries

    def query(self, time=False):
        if not self.queries:
            raise RuntimeError("no timer queries")
        return _Query()


@pytest.mark.parametrize("queries", [False, True])
def test_without_timer_queries_there_are_no_gpu_times(queries):
    # a query that cannot be made, or results that are all zero: CPU times alone, never zeros
    # passed off as GPU times
    timer = PassTimer(_Ctx(queries), frames=2)
    for _ in range(3):  # the third frame is past the timer's frames: not recorded
        timer.new_frame()
        for name in ("uniforms", "prt"):
            with timer.section(name):
                pass
    out = timer.summary()
    assert out["frames"] == 2 and tuple(out["cpu_ms"]) == ("uniforms", "prt")
    assert "gpu_ms" not in out
