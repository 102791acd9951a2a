"""Benchmark: the SG-BRDF fit (:func:`lobelight.sgbrdf.fit`) of all views of one material."""

from __future__ import annotations

import time

import torch

from .._checks import check_int
from ..brdf import BRDF, GGX, Beckmann, Ward
from ..errors import InputError
from ..sgbrdf import FIT_SAMPLES, fit, fit_error
from ._machine import machine, sync

__all__ = ["bench_brdf_fit"]


def _material(name: str) -> BRDF:
    table = {
        "ward": lambda: Ward(1.0, 0.1),
        "ward_sharp": lambda: Ward(1.0, 0.01),
        "ward_aniso": lambda: Ward(1.0, 0.01, 0.2),
        "ggx": lambda: GGX(0.1),
        "beckmann": lambda: Beckmann(0.1),
    }
    if name not in table:
        raise InputError("material", f"unknown material {name!r}; known: {', '.join(table)}")
    return table[name]()


def bench_brdf_fit(
    material: str = "ward", device: str = "cpu", *, repeats: int = 3, threads: int | None = 1
) -> dict:
    """Time :func:`fit` (coherent, default settings) of all views of one material.

    ``material``: "ward" (isotropic, alpha 0.1), "ward_sharp" (alpha 0.01), "ward_aniso"
    (0.01, 0.2: the paper's, 61 fitted geodesic views), "ggx" or "beckmann" (alpha 0.1). One
    warm-up fit, then ``repeats`` timed fits. ``threads`` sets torch's CPU threads for the run
    (restored after; None keeps the current setting). It defaults to 1: EM is many small
    operations, and on a shared machine a contended second thread makes the fit several times
    slower while an idle second core gains little (docs/benchmarks.md). Returns seconds (best
    and median), the view and lobe counts, the mean fit error, the goal (5 s on a 2-core CPU)
    and the machine.
    """

    before = torch.get_num_threads()
    if threads is not None:
        torch.set_num_threads(check_int(threads, "threads", minimum=1))
    try:
        return _bench_fit(material, str(device), repeats)
    finally:
        torch.set_num_threads(before)


def _bench_fit(material: str, device: str, repeats: int) -> dict:
    brdf = _material(material)
    fit(brdf, device=device)  # warm-up
    times = []
    model = None
    for _ in range(check_int(repeats, "repeats", minimum=1)):
        sync(device)
        t0 = time.perf_counter()
        model = fit(brdf, device=device)
        sync(device)
        times.append(time.perf_counter() - t0)
    times.sort()
    err = fit_error(model, brdf, samples=4096)
    return {
        "benchmark": "sgbrdf_fit",
        "material": material,
        "brdf": brdf.to_dict(),
        "layout": model.layout,
        "views": int(model.used.sum()),
        "lobes": model.n_lobes,
        "samples": FIT_SAMPLES,
        "seconds_best": times[0],
        "seconds_median": times[len(times) // 2],
        "repeats": len(times),
        "fit_error_mean": float(err[model.used].mean()),
        "goal_seconds": 5.0,
        "machine": machine(device),
    }
