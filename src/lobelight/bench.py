"""Benchmarks (``lobelight bench ...``): timings with the machine they ran on, as JSON.

Speed is measured here, never in unit tests. Each benchmark returns a dict that the CLI prints
(``--json``) and that ``docs/benchmarks.md`` records by hand with the machine description.
"""

from __future__ import annotations

import os
import platform
import time

import torch

__all__ = ["bench_prefilter", "bench_transport", "machine"]


def machine(device: str) -> dict:
    """Where a benchmark ran: CPU model and cores, torch version, GPU name if any."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    info = {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "device": device,
    }
    if device.startswith("cuda") and torch.cuda.is_available():
        info["gpu"] = torch.cuda.get_device_name(device)
    return info


def _sync(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize(device)


def bench_prefilter(
    *, base_res: int = 512, repeats: int = 3, device: str = "cpu", phases: int = 4
) -> dict:
    """Time building the full Gaussian-prefiltered chain from a ``(6, base_res, base_res, 3)`` cube.

    The input is the built-in sky converted to a cube map once, outside the timing.
    Returns seconds per build (best and median of ``repeats``) and the chain's size.
    """
    from .envmap import builtin, prefilter

    cube = builtin().to(device).to_cubemap(base_res)
    prefilter(cube, base_res=base_res, phases=phases)  # warm-up (allocations, kernels)
    _sync(device)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        pf = prefilter(cube, base_res=base_res, phases=phases)
        _sync(device)
        times.append(time.perf_counter() - t0)
    times.sort()
    return {
        "benchmark": "prefilter",
        "base_res": base_res,
        "phases": phases,
        "levels": len(pf.levels),
        "lam_max": pf.lam_max,
        "seconds_best": times[0],
        "seconds_median": times[len(times) // 2],
        "repeats": repeats,
        "bytes": pf.nbytes(),
        "goal_seconds": 0.005 if device.startswith("cuda") else 0.5,
        "machine": machine(device),
    }


def bench_transport(
    *,
    scene: str = "knot:3",
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
    from . import cubemap, transport
    from . import scene as _scene

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
