"""Benchmark of the renderer (``lobelight bench render``): frames per second for each model size,
Gaussian count and image size, and where a GL frame's time goes."""

from __future__ import annotations

import time

from ..envmap import builtin
from ..geometry.camera import Camera
from ..render import Lighting, Renderer, as_rotation, create_context
from ._machine import machine
from .synthetic import synthetic_model

__all__ = ["bench_render"]


def bench_render(
    *,
    vertices: tuple[int, ...] = (10_000, 50_000),
    lobes: tuple[int, ...] = (1, 3),
    sizes: tuple[int, ...] = (512, 1024),
    backend: str = "gl",
    frames: int = 10,
    base_res: int = 256,
    min_seconds: float = 1.0,
    sun: bool = False,
    samples: int = 1,
    display: bool = True,
    profile_frames: int = 32,
) -> dict:
    """Frames per second of the renderer for each model size, lobe count and square image size.

    ``samples``: anti-aliasing samples per pixel (each a full shading pass; 1 times one pass).

    With ``sun`` the sky's sun is shaded per pixel with a shadow map; every timed frame turns
    the light, so the map is redrawn every frame (a still light reuses it for free).

    GL: a frame is what ``lobelight view`` does per frame with ``display`` (the default): draw
    into a half-float (RGBA16F) target and tone-map it into an 8-bit one (the window's
    framebuffer; no swap); without ``display``, a draw into the float32 target
    :meth:`Renderer.render` reads. ``target`` in each row says which. ``fps`` is throughput,
    frames submitted back to back (each with its own camera-free rotation upload) and one
    ``finish`` at the end, as a real-time loop runs; at least ``frames`` frames and
    ``min_seconds`` seconds, so that a fast GPU is timed over hundreds of frames.
    ``fps_finish_each_frame`` waits for every frame (latency bound), and
    ``fps_with_readback`` adds the float32 read-back of :meth:`Renderer.render`.

    Where a frame's time goes (GL), from ``profile_frames`` further frames timed apart from the
    throughput frames (the GL renderer's pass timer), each pass's mean per frame in ms:
    ``gpu_ms`` (GL timer queries, read after the frames; absent without timer queries; on
    llvmpipe the rasteriser threads' time), ``gpu_ms_total`` their sum, ``cpu_ms`` (time in
    the pass's calls). Passes: ``uniforms`` (the per-frame block), ``shadow`` (with
    ``sun``), ``clear``, ``depth`` (the object's depth pre-pass), ``prt`` (the object's
    shading), ``background``, ``resolve`` (with several samples), ``tonemap`` (with
    ``display``). ``ms_per_frame_profiled`` is those frames' wall-clock time per frame,
    ``cpu_ms_submit`` the median time of one frame's calls, each frame started with the GPU
    idle (the latency frames): with a GPU driver, the CPU's share of a frame (llvmpipe
    rasterises inside some of the calls)."""

    light = Lighting(builtin(), base_res=base_res, sun=sun)
    cam = Camera.look_at((0.0, 0.8, 3.2), (0.0, 0.0, 0.0), fov=45.0)
    rows = []
    for v in vertices:
        for n in lobes:
            model = synthetic_model(v, n)
            for s in sizes:
                ren = Renderer(model, light, s, s, backend=backend, samples=samples)
                ren.render(cam, 10.0)  # warm-up: shader compilation, uploads
                if backend == "gl":
                    draw = _time_gl(ren.gl, cam, frames, min_seconds, display, profile_frames)
                else:
                    t = time.perf_counter()
                    for i in range(frames):
                        ren.render(cam, float(i))
                    draw = {"throughput": (time.perf_counter() - t) / frames}
                t = time.perf_counter()
                for i in range(max(1, frames // 2)):
                    ren.render(cam, float(i))
                full = (time.perf_counter() - t) / max(1, frames // 2)
                ren.close()
                row = {
                    "vertices": model.mesh.n_vertices,
                    "n_gaussians": n,
                    "size": s,
                    "samples": samples,
                    "fps": 1 / draw["throughput"],
                    "ms_per_frame": 1e3 * draw["throughput"],
                    "fps_with_readback": 1 / full,
                }
                if "latency" in draw:
                    row["fps_finish_each_frame"] = 1 / draw["latency"]
                    row["frames_timed"] = draw["frames"]
                    row.update(draw["breakdown"])
                rows.append(row)
    info = {}
    if backend == "gl":
        ctx = create_context()
        info = {"gl_renderer": ctx.info["GL_RENDERER"], "gl_version": ctx.info["GL_VERSION"]}
        ctx.release()
    return {
        "benchmark": "render",
        "backend": backend,
        "sun": sun,
        "rows": rows,
        "goals": {"cpu_512_fps": 5.0, "h100_50k_1024_fps": 1000.0},
        "machine": {**machine("cpu"), **info},
    }


def _time_gl(gl, cam, frames: int, min_seconds: float, display: bool, profile_frames: int) -> dict:
    """Seconds per frame of ``gl.draw`` (with ``display``: into the half-float target, then
    ``gl.present`` into an 8-bit one): throughput, latency (finish after each frame), and the
    per-pass breakdown of :func:`bench_render` (``breakdown``: the row's fields)."""
    rots = [_rot(i) for i in range(16)]  # rotation matrices built off the clock
    screen = None
    if display:
        gl.set_hdr_dtype("f2")
        screen = gl.ctx.framebuffer([gl.ctx.texture((gl.width, gl.height), 4)])
    count = 0  # frames drawn: the next rotation's index, the throughput's frame count

    def frame():  # a new rotation every frame, as the light turns
        nonlocal count
        gl.draw(cam, rots[count % 16])
        if screen is not None:
            gl.present(screen)
        count += 1

    try:
        frame()  # the new targets' first use, off the clock
        gl.ctx.finish()
        count = 0
        t = time.perf_counter()
        while count < frames or time.perf_counter() - t < min_seconds:
            for _ in range(frames):
                frame()
            gl.ctx.finish()
        throughput = (time.perf_counter() - t) / count
        timed = count
        submit = []
        t = time.perf_counter()
        for _ in range(frames):
            t0 = time.perf_counter()
            frame()
            submit.append(time.perf_counter() - t0)
            gl.ctx.finish()
        latency = (time.perf_counter() - t) / frames
        timer = gl.time_passes(profile_frames)
        t = time.perf_counter()
        for _ in range(profile_frames):
            frame()
        gl.ctx.finish()
        profiled = (time.perf_counter() - t) / max(profile_frames, 1)
        gl.timer = None
        breakdown = _breakdown(timer.summary(), profiled, sorted(submit), display)
    finally:
        gl.timer = None
        if screen is not None:
            screen.color_attachments[0].release()
            screen.release()
            gl.set_hdr_dtype("f4")
    return {
        "throughput": throughput,
        "latency": latency,
        "frames": timed,
        "breakdown": breakdown,
    }


def _breakdown(summary: dict, profiled: float, submit: list[float], display: bool) -> dict:
    """A row's per-pass fields from the pass timer's summary (ms), the profiled frames'
    seconds per frame and the sorted submit times (s)."""
    out = {
        "target": "rgba16f, tone-mapped to rgba8" if display else "rgba32f",
        "frames_profiled": summary["frames"],
        "ms_per_frame_profiled": 1e3 * profiled,
        "cpu_ms_submit": 1e3 * submit[len(submit) // 2],
        "cpu_ms": summary["cpu_ms"],
    }
    if "gpu_ms" in summary:
        out["gpu_ms"] = summary["gpu_ms"]
        out["gpu_ms_total"] = sum(summary["gpu_ms"].values())
    return out


def _rot(i: int):
    return as_rotation(float(i))
