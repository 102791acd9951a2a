"""Every benchmark with a goal, in one run (``lobelight bench all``), and the table made from it.

One call measures what the goals in ``docs/benchmarks.md`` are about, on one device:

- ``prefilter``: the Gaussian-prefiltered chain at base 512 (goals: 5 ms on one H100/H200 for a
  dynamic environment, a new map each build through a CUDA graph; 0.5 s on the 2-core CPU);
- ``rays``: the ray engines side by side on the same rays (Embree and Warp; on CUDA, Warp on
  the device);
- ``bake_10k`` and ``bake_50k``: transport and fit, 92 views, N = 1, with the bake's default
  interreflection, of the knot at 11,457 and 45,697 vertices (goals on one H100/H200: 10 s per
  10K vertices' model, 60 s per 50K);
- ``render``: the GL renderer at 50K vertices, 1024^2, N = 1 and 3 (goals on one H100/H200:
  1000 and 500 fps), with its per-pass GPU times.

``start`` (a render's start, :func:`lobelight.bench.bench_start`: ``lobelight render`` of a
15K-vertex model in a fresh process, goal 2.5 s warm on the 2-core CPU) is not in the default
list (it measures the CPU and the machine's OpenGL, whatever the device): ``only=("start",)``
runs it.

Each benchmark's record is written to ``output`` as soon as it is measured (atomically, the
whole summary each time), so a run stopped by a time limit keeps what it measured; a benchmark
that fails is recorded with its error and the others still run. :func:`table` turns the summary
into the Markdown rows of ``docs/benchmarks.md``.
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable
from pathlib import Path

from .._io import atomic_writer
from ..errors import one_line
from ._machine import machine
from .fit import bench_fit
from .prefilter import bench_prefilter
from .rays import bench_rays
from .render import bench_render
from .start import GOAL_SECONDS, bench_start

__all__ = ["BENCHMARKS", "GOALS", "bench_all", "table"]

#: The benchmarks ``bench all`` runs, in order, by name.
BENCHMARKS = ("prefilter", "rays", "bake_10k", "bake_50k", "render")

#: Goals on one H100/H200 (``cuda``) and on the 2-core CPU: (figure's key, goal, direction).
GOALS = {
    "cuda": {
        "prefilter": ("seconds_dynamic_best", 0.005, "at most"),
        "bake_10k": ("seconds_per_10k_vertices", 10.0, "at most"),
        "bake_50k": ("seconds_per_50k_vertices", 60.0, "at most"),
        "render_n1": ("fps", 1000.0, "at least"),
        "render_n3": ("fps", 500.0, "at least"),
    },
    "cpu": {
        "prefilter": ("seconds_best", 0.5, "at most"),
        "bake_10k": ("seconds_per_10k_vertices", 600.0, "at most"),
        "start": ("warm_wall_median", GOAL_SECONDS, "at most"),
    },
}


def _runs(device: str, progress) -> dict[str, Callable[[], dict]]:
    def bake(scene: str) -> Callable[[], dict]:
        def run() -> dict:
            out = bench_fit(scene=scene, n_gaussians=1, device=device, progress=progress)
            out["seconds_per_50k_vertices"] = out["seconds"] * 5e4 / out["vertices"]
            return out

        return run

    return {
        "prefilter": lambda: bench_prefilter(base_res=512, device=device),
        "rays": lambda: bench_rays(device=device),
        "bake_10k": bake("knot:2"),
        "bake_50k": bake("knot:4"),
        "render": lambda: bench_render(
            vertices=(50_000,), lobes=(1, 3), sizes=(1024,), backend="gl", min_seconds=2.0
        ),
        "start": bench_start,
    }


def bench_all(
    *,
    device: str = "cuda",
    output: str | Path | None = None,
    only: tuple[str, ...] | None = None,
    budget_seconds: float | None = None,
    progress=None,
    runs: dict[str, Callable[[], dict]] | None = None,
) -> dict:
    """Run the benchmarks of :data:`BENCHMARKS` (or ``only`` those) on ``device``.

    Parameters
    ----------
    output : JSON file rewritten after each benchmark (None: not written)
    budget_seconds : benchmarks not yet started once this many seconds have passed are skipped
        (recorded as such; the first always runs), so that a run under a time limit ends with
        its file written
    progress : reporter for the bakes (None: quiet)
    runs : name -> benchmark, standing in for the real ones (tests)

    Returns
    -------
    dict: ``results`` maps each benchmark to its record (or ``{"error": ...}`` /
    ``{"skipped": ...}``), ``seconds`` the whole run, ``machine`` where it ran.
    """
    names = BENCHMARKS if only is None else tuple(only)
    runs = _runs(device, progress) if runs is None else runs
    unknown = [n for n in names if n not in runs]
    if unknown:
        raise ValueError(f"unknown benchmarks {unknown}; known: {list(runs)}")
    summary = {
        "benchmark": "all",
        "device": device,
        "results": {},
        "seconds": 0.0,
        "machine": machine(device),
    }
    t0 = time.perf_counter()
    for i, name in enumerate(names):
        elapsed = time.perf_counter() - t0
        # the first benchmark always runs: a budget smaller than it would measure nothing
        if i and budget_seconds is not None and elapsed > budget_seconds:
            summary["results"][name] = {"skipped": f"the {budget_seconds:g} s budget was spent"}
        else:
            try:
                summary["results"][name] = runs[name]()
            except Exception as exc:  # one benchmark's failure must not lose the others' figures
                summary["results"][name] = {"error": one_line(f"{type(exc).__name__}: {exc}")}
        summary["seconds"] = time.perf_counter() - t0
        if output is not None:
            _write(output, summary)
    return summary


def _write(path: str | Path, summary: dict) -> None:
    with atomic_writer(path) as f:
        f.write(json.dumps(summary, indent=2, default=str).encode())


def _figures(name: str, record: dict) -> list[tuple[str, dict]]:
    """The rows one benchmark's record gives the table: (row name, record holding its figure)."""
    if name == "render":
        return [(f"render_n{row['n_gaussians']}", row) for row in record.get("rows", [])]
    return [(name, record)]


def table(summary: dict) -> str:
    """Markdown rows ``| benchmark | figure | goal | gap |`` of a :func:`bench_all` summary.

    The gap is how many times the figure misses (> 1) or beats (< 1) its goal; rows without a
    goal on this device show the figure alone.
    """
    kind = "cuda" if str(summary.get("device", "cpu")).startswith("cuda") else "cpu"
    goals = GOALS[kind]
    where = summary.get("machine", {})
    lines = [
        f"Machine: {where.get('gpu') or where.get('cpu', '?')}; torch {where.get('torch', '?')}.",
        "",
        "| benchmark | figure | goal | gap |",
        "| --- | --- | --- | --- |",
    ]
    for name, record in summary.get("results", {}).items():
        if "error" in record or "skipped" in record:
            lines.append(f"| {name} | {record.get('error') or record.get('skipped')} | | |")
            continue
        for row, rec in _figures(name, record):
            if row == "rays":
                for eng in rec.get("engines", []):
                    occ = eng.get("occluded_rays_per_second", float("nan"))
                    hit = eng.get("first_hit_rays_per_second", float("nan"))
                    lines.append(
                        f"| rays ({eng.get('engine')}) | {occ:.3g} occlusion rays/s, "
                        f"{hit:.3g} first-hit rays/s | | |"
                    )
                continue
            if row not in goals:
                continue
            key, goal, direction = goals[row]
            value = rec.get(key)
            if value is None:
                lines.append(f"| {row} | (no {key}) | {direction} {goal:g} | |")
                continue
            gap = value / goal if direction == "at most" else goal / value
            lines.append(f"| {row} | {key} = {value:.4g} | {direction} {goal:g} | {gap:.2f}x |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    """``python -m lobelight.bench table RESULT.json``: print the Markdown table."""
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 2 or args[0] != "table":
        raise SystemExit("usage: python -m lobelight.bench table RESULT.json")
    print(table(json.loads(Path(args[1]).read_text())), end="")
