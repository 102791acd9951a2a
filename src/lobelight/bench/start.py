"""Benchmark of a render's start (``lobelight bench start``): ``lobelight render`` of a model in
a fresh process, its wall time and where that time goes.

The model is a synthetic torus (:func:`lobelight.bench.synthetic_model`, ``shape="torus"``,
``vary=True``: its file holds visibility and hit tiles and compresses as a fitted model's
does), baked once into the benchmark's folder and reused. Every run is a new Python process
running the real command line with timers around the library calls it makes
(``bench/_start_child.py``); the parent measures the wall time from just before it starts the
process until the process has exited.

The child runs with Python's bytecode cache on (``PYTHONDONTWRITEBYTECODE`` is dropped from
its environment), as an installed package has it: the first run writes what is missing. The
child's cache folder (``LOBELIGHT_CACHE``) is the benchmark's own: the first run starts
from an empty cache (``cold``: the map's prefiltered chain, its resampled cubes, the geodesic
candidate table and the sharp lobe's measurement are computed and written), the runs after it
find them there (``warm``). The model file and the Python modules are in the operating
system's file cache in both: a first start after a reboot reads them from the disk as well.

Phases of a run, in seconds (``phases``; they sum to ``wall``):

- ``process_start``: from before the process is started to its first line (the interpreter);
- ``import_torch``, ``import_library`` (lobelight's model, map and render packages), and
  ``command_start``: from there until the model is read (the command line's own imports,
  its argument parsing and checks);
- ``model_read``, ``map_read``;
- ``renderer_setup`` (:class:`lobelight.render.Renderer`: the lighting, the GL context, the
  shaders, the uploads), ``frame`` (one rendered image), ``save`` (exposure and the file);
- ``exit``: from the child's record, written by the last of the process's exit handlers, to
  the process's end (:func:`lobelight.cli.main` ends its process without the interpreter's
  teardown); ``other``: the rest (between the timed calls: the summary's print, the other
  exit handlers).

``setup_parts`` splits ``renderer_setup`` by the calls timed inside it: ``lighting`` (of which
``sun`` and ``sh_projection``), ``chain`` (the prefiltered chain read or built),
``background`` (the background's cube map), ``candidates`` (the geodesic candidate table),
``sharp_lobe`` (the material's sharp lobe), ``gl_context``, ``gl_programs`` (shader
compilation), and ``rest`` (uploads and everything else); and, inside those, ``sh_cube`` and
``chain_cube``, the cube maps resampled for the SH projection and for a chain being built.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

try:
    import resource
except ImportError:  # not on Windows: the runs' CPU seconds are then not measured
    resource = None

from .._cache import cache_dir
from ._machine import machine
from .synthetic import synthetic_model

__all__ = ["GOAL_SECONDS", "bench_start", "phases"]

#: The goal: a warm start of a ~15K-vertex model's render, wall seconds, on the 2-core CPU.
GOAL_SECONDS = 2.5
#: Version of the benchmark's model: a new one is baked when this changes.
MODEL_VERSION = 2
#: The child script (run as a file, so that this package is not imported by it).
CHILD = Path(__file__).with_name("_start_child.py")
#: The phases of :func:`phases`, in the order of a run.
PHASES = (
    "process_start",
    "import_torch",
    "import_library",
    "command_start",
    "model_read",
    "map_read",
    "renderer_setup",
    "frame",
    "save",
    "exit",
    "other",
)


def _model(folder: Path, vertices: int) -> tuple[Path, float | None]:
    """The benchmark's model file in ``folder`` (baked now if absent) and the seconds its bake
    took (None when it was there)."""
    path = folder / f"torus-{vertices}-v{MODEL_VERSION}.npz"
    if path.is_file():
        return path, None
    t = time.perf_counter()
    synthetic_model(vertices, 3, shape="torus", vary=True).save(path)
    return path, time.perf_counter() - t


def _vertices(path: Path) -> int:
    """The vertex count of a model file (its ``vertices`` array's first axis)."""
    with np.load(path, allow_pickle=False) as z:
        return int(z["vertices"].shape[0])


def _seconds(timers: dict, label: str) -> float:
    return float(timers.get(label, {}).get("seconds", 0.0))


def phases(record: dict, wall: float) -> tuple[dict, dict]:
    """A run's phases and the parts of its renderer set-up (module docstring), in seconds, from
    the child's record (``_start_child.py``) and the wall time the parent measured.

    Returns
    -------
    phases : the :data:`PHASES`, summing to ``wall``;  setup_parts : ``renderer_setup`` split
    """
    timers = record["timers"]
    first_read = timers.get("model_read", {}).get("first", record["finished"])
    out = {
        "process_start": record["start"] - record["parent_t0"],
        "import_torch": record["torch_imported"],
        "import_library": record["library_imported"] - record["torch_imported"],
        "command_start": first_read - record["library_imported"],
        "model_read": _seconds(timers, "model_read"),
        "map_read": _seconds(timers, "map_read"),
        "renderer_setup": _seconds(timers, "renderer_setup"),
        "frame": _seconds(timers, "frame"),
        "save": _seconds(timers, "save") + _seconds(timers, "exposure"),
        "exit": max(record["parent_t0"] + wall - record["end"], 0.0),
    }
    out["other"] = wall - sum(out.values())
    parts = {
        "lighting": _seconds(timers, "lighting"),
        "sun": _seconds(timers, "sun"),
        "sh_projection": _seconds(timers, "sh_projection"),
        "chain": _seconds(timers, "chain"),
        "background": _seconds(timers, "background"),
        "candidates": _seconds(timers, "candidates"),
        "sharp_lobe": _seconds(timers, "sharp_lobe"),
        "gl_context": _seconds(timers, "gl_context"),
        "gl_programs": _seconds(timers, "gl_programs"),
    }
    inside = ("lighting", "chain", "background", "candidates", "sharp_lobe")
    inside += ("gl_context", "gl_programs")
    parts["rest"] = out["renderer_setup"] - sum(parts[k] for k in inside)
    parts["sh_cube"] = _seconds(timers, "sh_cube")
    parts["chain_cube"] = _seconds(timers, "chain_cube")
    return out, parts


def _children_cpu() -> float:
    """User and system seconds of this process's finished children (NaN where unknown)."""
    if resource is None:
        return math.nan
    use = resource.getrusage(resource.RUSAGE_CHILDREN)
    return use.ru_utime + use.ru_stime


def _run(python: str, args: list[str], env: dict, work: Path, *, timed: bool) -> dict:
    """One ``lobelight render`` in a new process: its wall seconds, the CPU seconds it used
    (user and system, all its threads), the 1-minute load average before it, and with
    ``timed`` its phases (through the child script) rather than the plain command line."""
    times = work / "times.json"
    times.unlink(missing_ok=True)
    load = os.getloadavg()[0]
    before = _children_cpu()
    t0 = time.time()
    p0 = time.perf_counter()
    if timed:
        cmd = [python, str(CHILD), str(times), repr(t0), "--", *args]
    else:
        cmd = [python, "-m", "lobelight.cli", *args]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - p0
    after = _children_cpu()
    if proc.returncode != 0:
        raise RuntimeError(f"the render failed ({proc.returncode}): {proc.stderr.strip()[-800:]}")
    out = {"wall": wall, "cpu": after - before, "load_1min_before": load}
    if timed:
        record = json.loads(times.read_text())
        out["phases"], out["setup_parts"] = phases(record, wall)
        out["torch_threads"] = record["torch_threads"]
    return out


def _median(runs: list[dict], key: str) -> dict:
    names = runs[0][key]
    return {k: statistics.median(r[key][k] for r in runs) for k in names}


def bench_start(
    *,
    vertices: int = 15_000,
    runs: int = 3,
    size: int = 512,
    env: str = "studio_small_03_512",
    folder: str | os.PathLike | None = None,
    python: str | None = None,
) -> dict:
    """Wall time of ``lobelight render MODEL`` in a new process, cold and warm, and where it
    goes (module docstring).

    Parameters
    ----------
    vertices : about how many vertices the benchmark's torus has
    runs : warm runs after the cold one (each phase's median is reported too)
    size : the image's width and height
    env : the map (a bundled map's name, a file, or ``builtin``)
    folder : the benchmark's folder, for its model and its private cache (default
        ``lobelight._cache.cache_dir() / "bench-start"``)
    python : the interpreter to run (default: this one)

    Returns
    -------
    dict: ``cold`` and ``warm`` (a list) runs, each ``wall``, ``cpu`` (the process's user and
    system seconds: on a busy machine the wall time grows with the load, this much less),
    ``load_1min_before``, ``phases`` and ``setup_parts``;
    ``warm_median`` the warm runs' median per phase, ``warm_wall_median``; ``plain_wall``
    the plain command line's wall time (no timers, warm), to show the timers cost nothing;
    the model, the goal and the machine.
    """
    if runs < 1:
        raise ValueError(f"runs must be >= 1, got {runs}")
    folder = Path(folder) if folder is not None else cache_dir() / "bench-start"
    folder.mkdir(parents=True, exist_ok=True)
    model, baked = _model(folder, vertices)
    cache = folder / "cache"
    shutil.rmtree(cache, ignore_errors=True)  # the cold run's empty cache
    # Python's bytecode cache as a user's install has it: with PYTHONDONTWRITEBYTECODE set
    # (some CI and container images set it) every start would compile lobelight's modules anew
    child_env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    child_env["LOBELIGHT_CACHE"] = str(cache)
    image = folder / "start.png"
    args = ["render", str(model), "-o", str(image), "--env", env, "--size", str(size), "-q"]
    python = python or sys.executable
    cold = _run(python, args, child_env, folder, timed=True)
    warm = [_run(python, args, child_env, folder, timed=True) for _ in range(runs)]
    plain = _run(python, args, child_env, folder, timed=False)
    return {
        "benchmark": "start",
        "command": "lobelight " + " ".join([*args[:1], "MODEL", *args[2:]]),
        "model": {
            "file": str(model),
            "vertices": _vertices(model),
            "bytes": model.stat().st_size,
            "seconds_baked": baked,
        },
        "env": env,
        "size": size,
        "cold": cold,
        "warm": warm,
        "warm_wall_median": statistics.median(r["wall"] for r in warm),
        "warm_cpu_median": statistics.median(r["cpu"] for r in warm),
        "warm_median": _median(warm, "phases"),
        "warm_setup_median": _median(warm, "setup_parts"),
        "plain_wall": plain["wall"],
        "goal": {"warm_wall_seconds": GOAL_SECONDS},
        "machine": machine("cpu"),
    }
