"""Benchmarks (``lobelight bench ...``): timings with the machine they ran on, as JSON.

Speed is measured here, never in unit tests. Each benchmark returns a dict that the CLI prints
(``--json``) and that ``docs/benchmarks.md`` records by hand with the machine description.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import torch
import trimesh
from torch.utils._python_dispatch import TorchDispatchMode

from .. import scene as _scene
from .. import transport
from .._machine import machine
from .._machine import sync as _sync
from ..envmap import ChainBuilder, builtin, clear_memory_caches, prefilter
from ..errors import one_line
from ..fit import Gaussians, fit_model
from ..geometry import cubemap
from ..geometry import sphere as sph
from ..geometry.camera import Camera
from ..model import Model
from ..render import Lighting, Renderer, as_rotation, create_context
from ..scene import load, mesh_from_arrays, uniform
from ..transport import BOUNCES, INDIRECT_PATHS

__all__ = [
    "bench_fit",
    "bench_prefilter",
    "bench_render",
    "bench_transport",
    "machine",
    "synthetic_model",
]


def bench_prefilter(
    *, base_res: int = 512, repeats: int = 3, device: str = "cpu", phases: int = 4
) -> dict:
    """Time building the full Gaussian-prefiltered chain from a ``(6, base_res, base_res, 3)`` cube.

    The input is the built-in sky converted to a cube map once, outside the timing. Three kinds
    of time, in seconds:

    - ``seconds_cold``: the first build, with the in-memory index plans and SH bases forgotten
      and no disk cache: what a process pays for a map it has not seen;
    - ``seconds_best`` / ``seconds_median`` of ``repeats`` builds after it (plans in memory, no
      disk cache);
    - ``seconds_cached``: median of ``repeats`` reads of the chain from a disk cache in a
      temporary folder (written once, outside the timing), what a later process pays;
    - ``seconds_dynamic_best`` / ``seconds_dynamic_median``: a dynamic environment, a different
      map each build (two maps in turn) through one :class:`lobelight.envmap.ChainBuilder`, from
      the map on the device to the chain ready (its finiteness check included); on CUDA each is
      one CUDA graph launch. ``dynamic_repeats`` builds (at least 20 on CUDA) after the first,
      which is ``seconds_dynamic_first`` (on CUDA: warm-up and capture). Should the capture
      fail, ``cuda_graph_error`` says why and the figures are of eager builds.

    ``ops_per_build`` counts the operators of one eager build on ``device`` that compute (views
    and allocations left out): on CUDA, the kernels a build launches without a graph.
    ``bytes`` is the chain in memory, ``bytes_on_disk`` its cache entry.
    """
    cube = builtin().to(device).to_cubemap(base_res)
    clear_memory_caches()
    _sync(device)
    t0 = time.perf_counter()
    prefilter(cube, base_res=base_res, phases=phases, cache=False)
    _sync(device)
    cold = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        pf = prefilter(cube, base_res=base_res, phases=phases, cache=False)
        _sync(device)
        times.append(time.perf_counter() - t0)
    times.sort()
    with tempfile.TemporaryDirectory(prefix="lobelight-bench-") as folder:
        prefilter(cube, base_res=base_res, phases=phases, cache=folder)  # writes the entry
        on_disk = sum(p.stat().st_size for p in Path(folder).iterdir())
        cached = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            prefilter(cube, base_res=base_res, phases=phases, cache=folder)
            _sync(device)
            cached.append(time.perf_counter() - t0)
    cached.sort()
    ops = _count_ops(lambda: prefilter(cube, base_res=base_res, phases=phases, cache=False))
    maps = [cube, cube.flip(2).contiguous()]  # the sky mirrored: another map, the same shape
    graph_error = None
    try:
        dynamic, dyn_first, graph = _time_builder(maps, base_res, phases, device, None, repeats)
    except RuntimeError as exc:  # a graph that cannot be captured: the eager path's figures
        graph_error = one_line(f"{type(exc).__name__}: {exc}")
        dynamic, dyn_first, graph = _time_builder(maps, base_res, phases, device, False, repeats)
    return {
        "benchmark": "prefilter",
        "base_res": base_res,
        "phases": phases,
        "levels": len(pf.levels),
        "lam_max": pf.lam_max,
        "seconds_cold": cold,
        "seconds_best": times[0],
        "seconds_median": times[len(times) // 2],
        "seconds_cached": cached[len(cached) // 2],
        "repeats": repeats,
        "seconds_dynamic_first": dyn_first,
        "seconds_dynamic_best": dynamic[0],
        "seconds_dynamic_median": dynamic[len(dynamic) // 2],
        "dynamic_repeats": len(dynamic),
        "cuda_graph": graph,
        "cuda_graph_error": graph_error,
        "ops_per_build": ops,
        "bytes": pf.nbytes(),
        "bytes_on_disk": on_disk,
        "goal_seconds": 0.005 if device.startswith("cuda") else 0.5,
        "machine": machine(device),
    }


def _time_builder(maps, base_res, phases, device, graph, repeats) -> tuple[list, float, bool]:
    """Sorted times of builds from ``maps`` in turn through one ChainBuilder (at least 20 with a
    CUDA graph), the first build's time apart, and whether it used a graph."""
    builder = ChainBuilder(base_res=base_res, phases=phases, device=device, graph=graph)
    t0 = time.perf_counter()
    builder(maps[1])
    _sync(device)
    first = time.perf_counter() - t0
    times = []
    for i in range(max(repeats, 20) if builder.graph else repeats):
        t0 = time.perf_counter()
        builder(maps[i % 2])
        _sync(device)
        times.append(time.perf_counter() - t0)
    return sorted(times), first, builder.graph


class _OpCounter(TorchDispatchMode):
    """Counts the operators that compute: not views, not bare allocations."""

    IDLE = frozenset({"empty", "new_empty", "empty_strided", "lift_fresh", "detach", "alias"})

    def __init__(self) -> None:
        super().__init__()
        self.count = 0

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        if not func.is_view and func.__name__.split(".")[0] not in self.IDLE:
            self.count += 1
        return func(*args, **(kwargs or {}))


def _count_ops(fn) -> int:
    """Operators that compute in one call of ``fn``."""
    counter = _OpCounter()
    with counter:
        fn()
    return counter.count


def bench_transport(
    *,
    scene: str = "knot:2",
    vertices: int = 10000,
    res: int = 32,
    sample_vertices: int = 64,
    paths: int = 32,
    device: str = "cpu",
) -> dict:
    """Time transport sampling on a ~10K-vertex built-in mesh.

    - visibility: every vertex (up to ``vertices``) against the ``6 res^2`` texel directions of
      a cube map (rays only above each vertex's horizon are cast), timed in full;
    - direct glossy, indirect glossy (``paths`` per vertex and view) and diffuse SH: the whole
      :func:`lobelight.transport.sample` on ``sample_vertices`` vertices x 92 views, reported
      per transport function (one vertex and view).
    """

    sc = _scene.load(scene)
    tr = transport.Transport(sc, device=device)
    n = min(vertices, sc.mesh.n_vertices)
    dirs = cubemap.texel_directions(res, device=device).reshape(-1, 3)
    vidx = torch.arange(n, device=device)
    up = int(((tr.mesh.normals[vidx] @ dirs.T) > 0).sum())
    t0 = time.perf_counter()
    for s in range(0, n, 2048):
        tr.visibility(vidx[s : s + 2048], dirs)
    _sync(device)
    t_vis = time.perf_counter() - t0
    sv = torch.linspace(0, sc.mesh.n_vertices - 1, sample_vertices).long()
    t0 = time.perf_counter()
    tb = transport.sample(sc, sv, res=res, paths=paths, transport=tr)
    _sync(device)
    t_direct = time.perf_counter() - t0
    functions = sample_vertices * tb.views.shape[0]
    return {
        "benchmark": "transport",
        "scene": scene,
        "mesh_vertices": sc.mesh.n_vertices,
        "visibility_vertices": n,
        "directions": int(dirs.shape[0]),
        "rays_cast": up,
        "visibility_seconds": t_vis,
        "rays_per_second": up / t_vis,
        "visibility_seconds_per_10k_vertices": t_vis * 10000 / n,
        "goal_visibility_seconds_per_10k_vertices": 60.0,
        "sample_vertices": sample_vertices,
        "views": int(tb.views.shape[0]),
        "paths_per_function": paths,
        "sample_seconds": t_direct,
        "transport_functions_per_second": functions / t_direct,
        "machine": machine(device),
    }


def bench_fit(
    *,
    scene: str = "knot:2",
    n_gaussians: int = 1,
    device: str = "cpu",
    bounces: int | None = None,
    indirect_paths: int | None = None,
    progress=True,
) -> dict:
    """Transport and fit of a whole model (a 10K-vertex, 92-view, N = 1 model), with a bake's
    interreflection (``bounces``, ``indirect_paths``: default the bake's,
    :data:`lobelight.transport.BOUNCES` and :data:`lobelight.transport.INDIRECT_PATHS`).

    ``knot:2`` has 11,457 vertices (10,368 of them glossy); seconds are also given per 10K
    vertices, and per stage: ``fit`` (transport sampling and fit, with ``indirect_glossy`` the
    path tracing inside it), ``relax``, ``interreflection`` (the diffuse bounces).
    ``progress`` as :func:`lobelight.fit.fit_model`'s (``lobelight bench fit -q``: None).
    """

    bounces = BOUNCES if bounces is None else bounces
    indirect_paths = INDIRECT_PATHS if indirect_paths is None else indirect_paths
    sc = load(scene)
    t0 = time.perf_counter()
    m = fit_model(
        sc,
        n_gaussians,
        device=device,
        bounces=bounces,
        indirect_paths=indirect_paths,
        progress=progress,
    )
    _sync(device)
    total = time.perf_counter() - t0
    v = sc.mesh.n_vertices
    return {
        "benchmark": "fit",
        "scene": scene,
        "vertices": v,
        "glossy_vertices": int((m.gaussians.w.amax((1, 2, 3)) > 0).sum()),
        "views": int(m.views.shape[0]),
        "n_gaussians": n_gaussians,
        "bounces": bounces,
        "indirect_paths": indirect_paths,
        "seconds": total,
        "seconds_per_10k_vertices": total * 1e4 / v,
        "stage_seconds": {k: t for k, t in m.provenance["seconds"].items() if k != "total"},
        "relative_l2_error_mean": m.provenance["relative_l2_error_mean"],
        "goal_seconds": 600.0 if device == "cpu" else 10.0,
        "machine": machine(device),
    }


def synthetic_model(vertices: int, n_gaussians: int):
    """A sphere of about ``vertices`` vertices with analytic Gaussians (a mirror-direction lobe
    and broad ones about the normal): rendering cost does not depend on fitted values."""

    # trimesh's UV sphere has about 4 rows^2 vertices for count = (rows + 2, 2 rows)
    rows = max(3, round((vertices / 4) ** 0.5))
    tm = trimesh.creation.uv_sphere(radius=1.0, count=[rows + 2, 2 * rows])
    mesh = mesh_from_arrays(tm.vertices, tm.faces, name=f"sphere{len(tm.vertices)}")
    n = mesh.normals
    views = sph.geodesic_views()
    cos = n @ views.T
    refl = torch.nn.functional.normalize(2 * cos[..., None] * n[:, None] - views[None], dim=-1)
    mus = [refl] + [n[:, None].expand_as(refl)] * (n_gaussians - 1)
    mu = torch.stack(mus, 2)
    lam = torch.tensor([300.0, 5.0, 2.0][:n_gaussians]).expand(*cos.shape, n_gaussians).clone()
    w = (
        (cos > 0).float()[..., None, None]
        * torch.full((n_gaussians, 3), 0.3)
        * lam[..., None]
        / 6.3
    )
    diffuse = torch.zeros(n.shape[0], 25, 3)
    diffuse[:, 0] = 0.2
    # a Phong material as sharp as the mirror lobe, so that ``--sun`` shades the sun's glossy
    # reflection per pixel too (render/_sun_glossy.py), as for a real glossy model
    mats = uniform(
        {"diffuse": [0.5, 0.5, 0.5], "model": "phong", "specular": 0.3, "exponent": 600.0},
        mesh.n_vertices,
    )
    return Model(mesh, views, Gaussians(w.contiguous(), mu, lam), diffuse, mats, {})


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
    throughput frames (:class:`lobelight.render._gl.PassTimer`), each pass's mean per frame in
    ms: ``gpu_ms`` (GL timer queries, read after the frames; absent without timer queries;
    on llvmpipe the rasteriser threads' time), ``gpu_ms_total`` their sum, ``cpu_ms`` (time
    in the pass's calls). Passes: ``uniforms`` (the per-frame block), ``shadow`` (with
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
                    draw = _time_gl(ren._gl, cam, frames, min_seconds, display, profile_frames)
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
    """A row's per-pass fields from a :meth:`PassTimer.summary` (ms), the profiled frames'
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
