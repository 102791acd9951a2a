"""Benchmark of the ray-casting engines (``lobelight bench rays``): Embree and NVIDIA Warp side
by side on the same rays.

Two sets of ``rays`` rays each on a built-in scene's mesh:

- ``surface``: visibility rays as a bake casts them: from random vertices (origins offset with
  :meth:`~lobelight.geometry.raycast.RayCaster.spawn`), random directions above the vertex
  normal;
- ``outside``: from a sphere around the mesh (radius its diagonal) toward random points of its
  bounding box grown by 40 %, so that some miss.

Per engine: the caster's construction (the BVH build, and the float64 triangle table both
engines share), first and best of ``repeats``; the first query (Warp compiles its kernels on
first use, or reads them from its disk cache: reported apart); then occlusion and first-hit
rays per second on each set, best of ``repeats`` (the engines take turns, so that a machine's
load falls on both alike). Agreement with the first engine: the share of rays with the same
triangle and the same occlusion, and the largest distance between the two hit points of a ray
both hit (a ray passing within float32 rounding of an outline may hit it in one engine and the
surface behind in the other).
"""

from __future__ import annotations

import importlib.metadata
import time

import torch

from .. import scene as _scene
from ..errors import InputError
from ..geometry import raycast
from ._machine import machine, sync

__all__ = ["bench_rays"]


def _version(dist: str) -> str | None:
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return None


def _ray_sets(caster, n: int, seed: int) -> dict[str, tuple[torch.Tensor, torch.Tensor]]:
    """``{"surface": (o, d), "outside": (o, d)}``, each (n, 3) float32 on the caster's mesh's
    device (surface origins offset by ``caster``'s spawn, the same for every engine)."""
    mesh = caster.mesh
    dev = mesh.device
    g = torch.Generator(device=dev).manual_seed(seed)
    vid = torch.randint(0, mesh.n_vertices, (n,), generator=g, device=dev)
    d = torch.nn.functional.normalize(torch.randn(n, 3, generator=g, device=dev), dim=-1)
    nrm = mesh.normals[vid]
    d = torch.where(((d * nrm).sum(-1) < 0)[:, None], -d, d)
    o = caster.spawn(mesh.vertices[vid], nrm, d)
    lo, hi = mesh.bounds
    u = torch.nn.functional.normalize(torch.randn(n, 3, generator=g, device=dev), dim=-1)
    o2 = (lo + hi) / 2 + mesh.scale * u
    aim = lo + (hi - lo) * (1.4 * torch.rand(n, 3, generator=g, device=dev) - 0.2)
    d2 = torch.nn.functional.normalize(aim - o2, dim=-1)
    return {"surface": (o, d), "outside": (o2, d2)}


def _timed(fn, device: str):
    sync(device)
    t0 = time.perf_counter()
    out = fn()
    sync(device)
    return time.perf_counter() - t0, out


def bench_rays(
    *,
    scene: str = "knot:2",
    rays: int = 1 << 20,
    device: str = "cpu",
    engines: tuple[str, ...] = ("embree", "warp"),
    repeats: int = 3,
    threads: int | None = None,
    seed: int = 0,
) -> dict:
    """Time and compare the ray engines on ``scene``'s mesh (see the module docstring).

    ``engines``: names of :data:`lobelight.geometry.raycast.ENGINES` ("warp" is left out,
    with a note, when Warp is not installed); ``threads``: the casters' CPU threads (default:
    the cores torch may use).

    Returns
    -------
    dict with ``"benchmark": "rays"``, ``engines`` (one record per engine: ``build_seconds``
    first and best, ``first_call_seconds``, and per ray set ``{set}_occluded_rays_per_second``
    and ``{set}_first_hit_rays_per_second``; ``occluded_rays_per_second`` and
    ``first_hit_rays_per_second`` are those of the surface set), ``agreement`` (per later
    engine and set, against the first) and ``machine``.
    """
    repeats = max(1, int(repeats))
    mesh = _scene.load(scene, device=device).mesh
    names = [e for e in engines if e != "warp" or raycast.warp_available()]
    if not names:
        raise InputError("engines", f"none of {list(engines)} can run here")
    notes = [] if names == list(engines) else ["warp left out: NVIDIA Warp is not installed"]

    def build(name: str) -> raycast.RayCaster:
        return raycast.RayCaster(mesh, engine=name, threads=threads)

    casters, records, sets = {}, {}, None
    for name in names:
        first, casters[name] = _timed(lambda name=name: build(name), device)
        again = [_timed(lambda name=name: build(name), device)[0] for _ in range(1, repeats)]
        if sets is None:
            sets = _ray_sets(casters[name], int(rays), seed)
        o, d = (x[:1024] for x in sets["surface"])
        c = casters[name]
        call, _ = _timed(lambda c=c, o=o, d=d: (c.occluded(o, d), c.first_hit(o, d)), device)
        records[name] = {
            "engine": casters[name].engine,
            "threads": casters[name].threads if mesh.device.type == "cpu" else None,
            "first_build_seconds": first,
            "build_seconds": min([first, *again]),
            "first_call_seconds": call,
        }

    best: dict[tuple[str, str, str], float] = {}
    results: dict[tuple[str, str], tuple] = {}
    for _ in range(repeats):
        for set_name, (o, d) in sets.items():
            for name in names:  # the engines take turns: a machine's load falls on both alike
                c = casters[name]
                t_occ, occ = _timed(lambda c=c, o=o, d=d: c.occluded(o, d), device)
                t_hit, hit = _timed(lambda c=c, o=o, d=d: c.first_hit(o, d), device)
                for query, t in (("occluded", t_occ), ("first_hit", t_hit)):
                    key = (name, set_name, query)
                    best[key] = min(best.get(key, float("inf")), t)
                results[name, set_name] = (occ, *hit)
    for (name, set_name, query), t in best.items():
        records[name][f"{set_name}_{query}_rays_per_second"] = int(rays) / t
        records[name][f"{set_name}_{query}_seconds"] = t
    for rec in records.values():
        rec["occluded_rays_per_second"] = rec["surface_occluded_rays_per_second"]
        rec["first_hit_rays_per_second"] = rec["surface_first_hit_rays_per_second"]

    agreement = {}
    for name in names[1:]:
        for set_name, (_, d) in sets.items():
            occ_a, tri_a, t_a, _ = results[names[0], set_name]
            occ_b, tri_b, t_b, _ = results[name, set_name]
            both = (tri_a >= 0) & (tri_b >= 0)
            gap = ((t_a - t_b).abs() * d.norm(dim=-1))[both]
            agreement[f"{names[0]}_vs_{name}_{set_name}"] = {
                "same_triangle": float((tri_a == tri_b).float().mean()),
                "same_occlusion": float((occ_a == occ_b).float().mean()),
                "rays_that_differ": int((tri_a != tri_b).sum()),
                "max_point_distance": float(gap.max()) if gap.numel() else 0.0,
                "max_point_distance_of_diagonal": (
                    float(gap.max()) / mesh.scale if gap.numel() else 0.0
                ),
                "occluded_share": float(occ_a.float().mean()),
            }

    return {
        "benchmark": "rays",
        "scene": scene,
        "triangles": mesh.n_faces,
        "rays": int(rays),
        "repeats": repeats,
        "engines": [records[n] for n in names],
        "agreement": agreement,
        "notes": notes,
        "versions": {"embreex": _version("embreex"), "warp-lang": _version("warp-lang")},
        "machine": machine(device),
    }
