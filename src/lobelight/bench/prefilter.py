"""Benchmark of the Gaussian-prefiltered chain (``lobelight bench prefilter``): a cold build,
warm builds, reads from the disk cache, and a dynamic environment through one
:class:`lobelight.envmap.ChainBuilder` (a CUDA graph on CUDA), with the operators one build runs.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from torch.utils._python_dispatch import TorchDispatchMode

from ..envmap import ChainBuilder, builtin, clear_memory_caches, prefilter
from ..errors import one_line
from ._machine import machine, sync

__all__ = ["bench_prefilter"]


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
    sync(device)
    t0 = time.perf_counter()
    prefilter(cube, base_res=base_res, phases=phases, cache=False)
    sync(device)
    cold = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        pf = prefilter(cube, base_res=base_res, phases=phases, cache=False)
        sync(device)
        times.append(time.perf_counter() - t0)
    times.sort()
    with tempfile.TemporaryDirectory(prefix="lobelight-bench-") as folder:
        prefilter(cube, base_res=base_res, phases=phases, cache=folder)  # writes the entry
        on_disk = sum(p.stat().st_size for p in Path(folder).iterdir())
        cached = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            prefilter(cube, base_res=base_res, phases=phases, cache=folder)
            sync(device)
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
    sync(device)
    first = time.perf_counter() - t0
    times = []
    for i in range(max(repeats, 20) if builder.graph else repeats):
        t0 = time.perf_counter()
        builder(maps[i % 2])
        sync(device)
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
