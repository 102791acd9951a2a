"""Benchmark of transport sampling (``lobelight bench transport``): visibility rays and the
transport functions of a bake, on a built-in mesh."""

from __future__ import annotations

import time

import torch

from .. import scene as _scene
from .. import transport
from ..geometry import cubemap
from ._machine import machine, sync

__all__ = ["bench_transport"]


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
    sync(device)
    t_vis = time.perf_counter() - t0
    sv = torch.linspace(0, sc.mesh.n_vertices - 1, sample_vertices).long()
    t0 = time.perf_counter()
    tb = transport.sample(sc, sv, res=res, paths=paths, transport=tr)
    sync(device)
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
