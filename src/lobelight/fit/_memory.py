"""A bake's memory: the budget its batch sizes are derived from, and its peak per stage.

A bake holds two kinds of memory. What every vertex keeps until the model is written (the
fitted Gaussians, the SH transfer, and in the interreflection the gather matrix and the
Gaussians' zonal coefficients) grows with the mesh: a few tens of kilobytes per vertex at most
(:func:`state_bytes`, :func:`interreflection_bytes`). The work between (a chunk's transport
samples and its Levenberg-Marquardt systems, the interreflection's rays and glossy records) is
done in batches whose size
:func:`plan_memory` derives from the budget before anything is allocated, so it does not grow
with the mesh. :class:`PeakMeter` measures what a bake held, stage by stage.
"""

from __future__ import annotations

import math
import sys
import threading
from dataclasses import dataclass

import torch

try:
    import resource  # Unix only: elsewhere no peak is reported
except ImportError:  # pragma: no cover
    resource = None

from ..errors import InputError
from ._data import CAP_SAMPLES, GLOBAL_SAMPLES

__all__ = [
    "MEMORY_GB",
    "MemoryPlan",
    "PeakMeter",
    "chunk_bytes",
    "interreflection_bytes",
    "plan_memory",
    "state_bytes",
]

#: A bake's default memory budget, in GB (2**30 bytes): resident memory of the whole process.
MEMORY_GB = 4.0

_GB = 2**30
# What the process holds before a bake's first batch: the interpreter, torch and the other
# libraries, the scene and the ray caster's BVH (an allowance, so that batch sizes, which the
# results depend on, do not depend on what else the process has done).
_BASE_BYTES = 1 * _GB
# Bytes per (vertex, view, sample) of a fit chunk, temporaries included: the transport samples
# (direction, weight, RGB value and their float64 copies) and per Gaussian its values, Jacobian
# rows and products in the Levenberg-Marquardt iteration. Measured as the rise of the peak
# resident memory over one 64-vertex chunk of a 3,002-vertex bunny (92 views, 16 indirect
# paths) of a GGX alpha 0.04 metal, the largest (a rougher lobe's samples of weight 0 are
# dropped: at alpha 0.25 two Gaussians hold 6.4 MiB a vertex, three 7.0): 10.7, 16.0 and
# 19.6 MiB a vertex with one, two and three Gaussians; the figures below hold 1.27x, 1.22x
# and 1.29x those.
_SAMPLE_BYTES = 130
_SAMPLE_GAUSSIAN_BYTES = 100
# Samples per (vertex, view) of the fit (lobelight.fit.gather's cap grid and global set).
_SAMPLES = CAP_SAMPLES + GLOBAL_SAMPLES
# Vertices per chunk on the CPU: larger chunks gain nothing there.
_CPU_BATCH = 64
# Bytes per vertex the interreflection keeps besides the bake's state: the Gaussians (direct
# and indirect) as float32 copies with their zonal coefficients (J x (N + 1) x 12 floats), the
# gather matrix (at most 3 corners x 192 rays above the horizon x 20 bytes) and six copies of
# the SH transfer.
_INTERREFLECTION_VERTEX_BYTES = 3 * 192 * 20 + 6 * 25 * 3 * 4
# The least the interreflection's batches are given (a few hundred vertices' rays at once).
_MIN_BATCH_BYTES = 2**20
# The most the interreflection's batches are given (rays, glossy records, zonal coefficients):
# larger batches gain nothing.
_INTERREFLECTION_BATCH_BYTES = 512 * 2**20


@dataclass(frozen=True)
class MemoryPlan:
    """Batch sizes of a bake, derived from its memory budget.

    Attributes
    ----------
    budget : bytes the whole process may hold
    batch : vertices fitted at once (a chunk)
    interreflection : bytes each batch of the interreflection may hold
    chunks_at_once : how many chunks of ``batch`` vertices the budget holds side by side
    """

    budget: int
    batch: int
    interreflection: int
    chunks_at_once: int = 1


def chunk_bytes(j: int, n: int) -> float:
    """Bytes a fit chunk holds per vertex, for J views and N Gaussians per view."""
    return j * _SAMPLES * (_SAMPLE_BYTES + _SAMPLE_GAUSSIAN_BYTES * n)


def state_bytes(v: int, j: int, n: int) -> int:
    """Bytes of the bake's state, which grows with the mesh
    (:class:`lobelight.fit._chunk.BakeState`: per vertex and view N direct and one indirect
    Gaussian, 7 floats each, the lobe estimate, 5 floats, and the cap samples' visibility, a bit
    each; per vertex two SH transfers, a few flags and the global samples' visibility)."""
    cap_bytes, global_bytes = -(-CAP_SAMPLES // 8), -(-GLOBAL_SAMPLES // 8)
    return v * (4 * (j * ((n + 1) * 7 + 5) + 2 * 25 * 3 + 2) + j * cap_bytes + global_bytes)


def interreflection_bytes(v: int, j: int, n: int) -> int:
    """Bytes the interreflection keeps per vertex besides the state, which grow with the mesh:
    the Gaussians (direct and indirect) as float32 copies with their zonal coefficients
    (J x (N + 1) x 12 floats), the gather matrix, six copies of the SH transfer."""
    return v * (4 * j * (n + 1) * 12 + _INTERREFLECTION_VERTEX_BYTES)


def plan_memory(
    memory_gb: float, v: int, j: int, n: int, *, device, batch: int | None = None
) -> MemoryPlan:
    """The batch sizes of a bake of V vertices, J views and N Gaussians within ``memory_gb``.

    The budget less an allowance for the process before the bake and less the state that
    grows with the mesh (:func:`state_bytes`) is what the flood fill's chunks may hold
    (:func:`chunk_bytes` per vertex, at most 64 on the CPU, where larger chunks gain nothing,
    or 2,048 on a GPU, whose free memory also bounds them; as many such chunks side by side as
    it holds, ``chunks_at_once``); less what the interreflection keeps
    per vertex too (:func:`interreflection_bytes`), what its batches may hold (at most 512 MB:
    larger batches gain nothing). ``batch`` given is kept as it is.

    Raises
    ------
    InputError
        where the budget cannot hold the mesh's state and one vertex's chunk, or the
        interreflection's state and a small batch (1 MB).
    """
    if not (isinstance(memory_gb, int | float) and math.isfinite(memory_gb) and memory_gb > 0):
        raise InputError("memory_gb", f"must be a positive number of GB, got {memory_gb!r}")
    budget = int(memory_gb * _GB)
    per_vertex = chunk_bytes(j, n)
    work = budget - _BASE_BYTES - state_bytes(v, j, n)
    ir_work = work - interreflection_bytes(v, j, n)
    need = max(per_vertex - work, _MIN_BATCH_BYTES - ir_work)
    if need > 0:
        least = math.ceil((budget + need) / _GB * 10) / 10
        raise InputError(
            "memory_gb",
            f"{memory_gb:g} GB cannot hold a bake of {v} vertices ({n} Gaussian(s) per view): "
            f"it needs at least {least:g} GB",
        )
    dev = torch.device(device)
    cap = _CPU_BATCH
    if dev.type == "cuda":
        free, _ = torch.cuda.mem_get_info(dev)
        cap = int(min(2048, max(64, (0.5 * free / per_vertex) // 64 * 64)))
    if batch is None:
        batch = max(1, min(cap, int(work // per_vertex)))
    at_once = max(1, int(work // (batch * per_vertex)))
    return MemoryPlan(budget, int(batch), int(min(_INTERREFLECTION_BATCH_BYTES, ir_work)), at_once)


def resident_bytes() -> int | None:
    """The process's resident memory now (``VmRSS``; None where /proc is not there)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def _max_resident() -> int:
    """The process's peak resident memory so far (``ru_maxrss``: KB on Linux, bytes on macOS)."""
    if resource is None:
        return 0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(peak if sys.platform == "darwin" else peak * 1024)


class PeakMeter:
    """Peak resident memory of the process per stage, sampled by a thread every ``period``
    seconds (where /proc gives the resident memory; elsewhere the process's peak so far at
    each stage's end).

    ``stage(name)`` starts a stage (ending the one before); ``stop()`` ends the last and
    returns ``{stage: peak bytes}``. A stage shorter than the period still gets the resident
    memory at its start and end.
    """

    def __init__(self, period: float = 0.05):
        self.period = period
        self._peaks: dict[str, int] = {}
        self._current: str | None = None
        self._lock = threading.Lock()
        self._done = threading.Event()
        self._proc = resident_bytes() is not None
        self._thread: threading.Thread | None = None

    def _sample(self) -> None:
        now = resident_bytes() if self._proc else _max_resident()
        if now is None:
            return
        with self._lock:
            if self._current is not None:
                self._peaks[self._current] = max(self._peaks.get(self._current, 0), now)

    def _run(self) -> None:
        while not self._done.wait(self.period):
            self._sample()

    def stage(self, name: str) -> None:
        """End the current stage and start ``name``."""
        self._sample()
        with self._lock:
            self._current = name
        self._sample()
        if self._thread is None and self._proc:
            self._thread = threading.Thread(target=self._run, name="lobelight-memory", daemon=True)
            self._thread.start()

    def stop(self) -> dict[str, int]:
        """End the last stage; returns the peak resident bytes of every stage."""
        self._sample()
        self._done.set()
        if self._thread is not None:
            self._thread.join()
        with self._lock:
            self._current = None
            return dict(self._peaks)
