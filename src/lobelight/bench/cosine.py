"""Benchmark of cosine-lobe shading (``lobelight bench lobes``): the paper's two timed
configurations (its Figs. 14, 17); and of the build of its tables (``lobelight bench
lobe-tables``).

* ``unoccluded``: 65,536 points (a 256 x 256 grid on the plane), one spherical light, no
  occluder, a spatially varying material (``Lambert + Phong``, albedo and exponent varying per
  point; the paper's Figure 14 uses a spatially varying Lafortune model): 13.73 fps in the
  paper.
* ``occluded``: 16,384 points (a 128 x 128 grid on the plane around the occluder's shadow),
  64 occluder spheres (a torus), one light, a diffuse material, visibility depth 5,
  aggressive masks, threshold 1e-3: 4.75-15.9 fps in the paper (depending on the shadow's
  size). The light is the default scene's: the plane's direct radiance is dim enough that the
  threshold culls the products of the deepest leaves, and with them the construction of those
  cells (the threshold of :func:`lobelight.cosine.shade_points`). The same frame without a
  threshold is reported too (``threshold_0``).

* ``large`` (with ``fused``): the scale of the paper's Figure 18 (480,000 points, 1024
  occluders, two reflectance lobes, depth 5: 6.25 s per image there): the 800 x 600 G-buffer
  of the default scene (plane and torus), the torus as 1024 spheres, the scene's Lambert +
  Phong materials, fused, three frames at ``t = 1e-3`` and at ``t = 0``.

A frame is everything that depends on the scene's state: reflectance, light and visibility
lobes, masks, products and integration (``shade_points``), not the G-buffer. Reported: best
and median milliseconds per frame over ``repeats`` after one warm-up frame, fps from the best,
products and leaves per point, for 1 torch thread and for the process's thread count.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Any

import torch

from .. import brdf as _brdf
from ..cosine import (
    build_tables,
    default_scene,
    gbuffer,
    get_tables,
    load_tables,
    save_tables,
    shade_points,
    sphere_set,
)
from ._machine import machine, sync

__all__ = ["bench_lobes", "bench_tables"]

GOALS_FPS = {"unoccluded": 60.0, "occluded": 30.0}
PAPER_FPS = {"unoccluded": 13.73, "occluded": [4.75, 15.9]}


def _grid(n: int, half: float, centre=(0.0, 0.0)) -> torch.Tensor:
    s = torch.linspace(-half, half, n)
    x, z = torch.meshgrid(s + centre[0], s + centre[1], indexing="ij")
    return torch.stack([x, torch.zeros_like(x), z], -1).reshape(-1, 3)


def _configs(device: Any):
    scene = default_scene()
    cam = torch.tensor(scene.camera.origin)
    light = scene.lights[0]
    # 65,536 points, spatially varying Lambert + Phong
    p1 = _grid(256, 3.5)
    u = (p1[:, 0] + 3.5) / 7
    v = (p1[:, 2] + 3.5) / 7
    albedo = torch.stack([0.2 + 0.6 * u, 0.3 + 0.4 * v, 0.6 - 0.4 * u], -1)
    m1 = _brdf.Sum(
        _brdf.Lambert(albedo),
        _brdf.Phong((0.1 + 0.3 * v).unsqueeze(-1).expand(-1, 3).contiguous(), 5.0 + 200.0 * u),
    )
    # 16,384 points around the torus's shadow (the light is up and to the side)
    lc = torch.tensor(light.centre)
    foot = -lc[[0, 2]] * 0.75 / (lc[1] - 0.75)  # shadow centre of the torus's centre
    p2 = _grid(128, 1.9, (float(foot[0]), float(foot[1])))
    m2 = _brdf.Lambert(torch.tensor([0.75, 0.75, 0.72]))
    up = torch.tensor([0.0, 1.0, 0.0])
    out = {}
    for name, pts, model, spheres in (
        ("unoccluded", p1, m1, None),
        ("occluded", p2, m2, scene.world_spheres()),
    ):
        wo = torch.nn.functional.normalize(cam - pts, dim=-1)
        out[name] = {
            "points": pts.to(device),
            "normals": up.expand_as(pts).contiguous().to(device),
            "wo": wo.to(device),
            "brdf": model.to(device),
            "spheres": None if spheres is None else spheres.to(device),
        }
    return out, [light]


def _frames(c: dict, lights, kw: dict, repeats: int, device: Any):
    """One warm-up frame, then ``repeats`` timed ones: (last result, warm-up s, sorted s)."""
    t0 = time.perf_counter()
    res = shade_points(c["points"], c["normals"], c["wo"], c["brdf"], lights, **kw)
    sync(device)
    warmup = time.perf_counter() - t0
    times = []
    for _ in range(max(1, int(repeats))):
        t0 = time.perf_counter()
        res = shade_points(c["points"], c["normals"], c["wo"], c["brdf"], lights, **kw)
        sync(device)
        times.append(time.perf_counter() - t0)
    return res, warmup, sorted(times)


def bench_lobes(
    *,
    device: str = "cpu",
    repeats: int = 20,
    threads: tuple = (1, None),
    fused: tuple = (False, True),
) -> dict:
    """Time both configurations (module docstring); JSON-serialisable dict.

    Parameters
    ----------
    device : torch device
    repeats : timed frames per configuration, thread count and fusion setting (after one
        warm-up frame, which for a fused run includes compiling)
    threads : torch CPU thread counts to try for eager runs (None: the process's setting);
        fused runs use the process's setting; ignored on a GPU
    fused : fusion settings to try (``shade_points``' ``fused``: False eager, True
        ``torch.compile``)

    Returns
    -------
    dict with per configuration: points, occluders, depth, ``ms_best``, ``ms_median``, ``fps``
    (from the best frame), products and leaves per point (mean, max), the goal and the
    paper's fps, per thread count and fusion setting under ``runs`` (with ``warmup_s``, the
    first frame: compile time for a fused run) and the best run's numbers at the top level;
    for ``occluded`` also ``threshold_0``, the fused frame with no threshold (nothing culled,
    every leaf built); with ``fused`` the ``large`` configuration (seconds per image, best and
    median, leaves and products per point, at t = 1e-3 and 0); and ``machine``
    """
    dev = torch.device(device)
    get_tables(device=dev)
    cfgs, lights = _configs(dev)
    thread_opts = threads if dev.type == "cpu" else (None,)
    result: dict = {
        "benchmark": "cosine_lobes",
        "machine": machine(str(device)),
        "repeats": max(1, int(repeats)),
    }
    for name, c in cfgs.items():
        runs = []
        for fz in fused:
            # compiled kernels keep the thread count they were compiled with: fused runs use
            # the process's own
            for th in thread_opts if not fz else (None,):
                kw = dict(
                    spheres=c["spheres"],
                    depth=5,
                    mode="aggressive",
                    threshold=1e-3,
                    threads=th,
                    fused=bool(fz),
                    device=dev,
                )
                res, warmup, times = _frames(c, lights, kw, repeats, device)
                runs.append(
                    {
                        "fused": bool(fz),
                        "threads": th if th is not None else torch.get_num_threads(),
                        "warmup_s": warmup,
                        "ms_best": 1e3 * times[0],
                        "ms_median": 1e3 * times[len(times) // 2],
                        "fps": 1.0 / times[0],
                        "fps_median": 1.0 / times[len(times) // 2],
                    }
                )
        best = max(runs, key=lambda r: r["fps"])
        keys = ("fused", "threads", "ms_best", "ms_median", "fps", "fps_median")
        result[name] = {
            "points": int(c["points"].shape[0]),
            "lights": 1,
            "occluders": 0 if c["spheres"] is None else int(c["spheres"].shape[0]),
            "depth": 5 if c["spheres"] is not None else None,
            **{k: best[k] for k in keys},
            "products_per_point_mean": float(res.products.float().mean()),
            "products_per_point_max": int(res.products.max()),
            "leaves_per_point_mean": float(res.leaves.float().mean()),
            "shadowed_points": int((res.leaves > 0).sum()),
            "goal_fps": GOALS_FPS[name],
            "meets_goal": best["fps"] >= GOALS_FPS[name],
            "paper_fps": PAPER_FPS[name],
            "runs": runs,
        }
        if c["spheres"] is not None and True in fused:
            # the same frame with no threshold: every leaf built and multiplied (the cost when
            # nothing is dim enough to cull; the threshold also culls the masks' construction)
            kw = dict(spheres=c["spheres"], depth=5, threshold=0.0, fused=True, device=dev)
            res, _, times = _frames(c, lights, kw, repeats, device)
            result[name]["threshold_0"] = {
                "ms_best": 1e3 * times[0],
                "ms_median": 1e3 * times[len(times) // 2],
                "fps": 1.0 / times[0],
                "leaves_per_point_mean": float(res.leaves.float().mean()),
                "products_per_point_mean": float(res.products.float().mean()),
            }
    if True in fused:
        result["large"] = _large(dev, min(3, max(1, int(repeats))))
    return result


def _large(dev: torch.device, repeats: int) -> dict:
    """The ``large`` configuration (module docstring): seconds per image at t = 1e-3 and 0."""
    scene = default_scene()
    scene.spheres = sphere_set((scene.vertices, scene.faces), 1024)  # 20,000 volume samples
    gb = gbuffer(scene, 800, 600, device=dev)
    c = {k: gb[k] for k in ("points", "normals", "wo", "brdf")}
    out: dict = {
        "points": int(gb["points"].shape[0]),
        "image": [800, 600],
        "occluders": int(scene.spheres.spheres.shape[0]),
        "depth": 5,
        "paper_seconds": 6.25,
        "paper_points": 480000,
    }
    for name, t in (("threshold_1e-3", 1e-3), ("threshold_0", 0.0)):
        kw = dict(spheres=scene.world_spheres().to(dev), depth=5, threshold=t, fused=True)
        res, warmup, times = _frames(c, scene.lights, kw, repeats, dev)
        out[name] = {
            "s_best": times[0],
            "s_median": times[len(times) // 2],
            "warmup_s": warmup,
            "leaves_per_point_mean": float(res.leaves.float().mean()),
            "products_per_point_mean": float(res.products.float().mean()),
        }
    return out


def bench_tables(device: str = "cpu") -> dict:
    """Time building the default tables from scratch (no cache), plus writing and reading them.

    Returns
    -------
    dict with ``seconds`` (the full build), its product and cap parts, the fit count, table
    shapes, ``bytes`` in memory and on disk, the torch threads of the build, the goal (120 s on
    a 2-core CPU; the paper: ~4 hours) and the machine.
    """
    sync(device)
    threads = 1 if device == "cpu" else None  # build_tables' default on a CPU
    t0 = time.perf_counter()
    tables = build_tables(device=device, threads=threads)
    sync(device)
    seconds = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "tables.npz"
        t1 = time.perf_counter()
        save_tables(tables, path)
        load_tables(path)
        io_seconds = time.perf_counter() - t1
        file_bytes = path.stat().st_size
    return {
        "benchmark": "cosine_tables",
        "seconds": seconds,
        "seconds_product": tables.info["seconds_product"],
        "seconds_cap": tables.info["seconds_cap"],
        "seconds_save_load": io_seconds,
        "product_fits": tables.info["product_fits"],
        "unconverged_fits": tables.info["unconverged_fits"],
        "shapes": tables.shapes,
        "bytes": tables.nbytes,
        "file_bytes": file_bytes,
        "params": tables.params.to_dict(),
        "build_threads": threads or torch.get_num_threads(),
        "goal_seconds": 120.0,
        "paper_seconds": 4 * 3600.0,
        "machine": machine(device),
    }
