"""Benchmarks (``lobelight bench ...``): timings with the machine they ran on, as JSON.

Speed is measured here, never in unit tests. Each benchmark returns a dict that the CLI prints
(``--json``) and that ``docs/benchmarks.md`` records by hand with the machine description.
"""

from __future__ import annotations

import os
import platform
import time

import torch

__all__ = ["bench_prefilter", "machine"]


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
