"""A bake's side on a Dask worker: the plugin that holds what every chunk reads, and the task.

:mod:`lobelight.fit._cluster` registers one :class:`BakePlugin` per bake with the scheduler,
which hands it to every worker once, and to every worker that joins or is restarted later: the
scene, the views and the settings cross to a worker once, never with a chunk. The worker builds
its :class:`lobelight.fit._chunk.Bake` (the scene's transport, without a state) at its first
chunk and keeps it; :func:`run_chunk` is the task, one chunk's work
(:func:`lobelight.fit._chunk.compute_chunk`) on
the inputs that crossed with it, its result returned on the CPU.

This module needs ``distributed`` (the optional ``[cluster]`` extra); nothing imports it
unless a bake runs on a cluster.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import torch
from distributed import WorkerPlugin, get_worker

from ..scene import Scene
from ..transport import Transport
from ._chunk import Bake, Chunk, ChunkResult, compute_chunk
from ._objective import Weights

__all__ = ["BakePlugin", "BakeSpec", "run_chunk"]


@dataclass(frozen=True)
class BakeSpec:
    """What every chunk of one bake reads besides its own inputs.

    Attributes
    ----------
    scene : Scene;  views : (J, 3) view directions, on the CPU
    n, weights, indirect_paths, seed, shadows : the bake's settings (:func:`lobelight.fit.fit_mesh`)
    device : the device a worker computes on; None: its CUDA device where it has one, else
        the CPU
    """

    scene: Scene
    views: torch.Tensor
    n: int
    weights: Weights
    indirect_paths: int
    seed: int
    shadows: bool
    device: str | None = None

    def build(self) -> Bake:
        """The bake's transport and settings on this process's device, without a state."""
        dev = self.device
        if dev is None:
            dev = "cuda" if torch.cuda.is_available() else "cpu"
        tr = Transport(self.scene, device=dev, shadows=self.shadows)
        return Bake.start(
            tr,
            self.views.to(tr.device),
            n=self.n,
            weights=self.weights,
            indirect_paths=self.indirect_paths,
            seed=self.seed,
            state=False,
        )


class BakePlugin(WorkerPlugin):
    """One bake's :class:`BakeSpec` on a worker, and the worker's :class:`Bake`, built at its
    first chunk and kept until the plugin is removed at the bake's end."""

    def __init__(self, name: str, spec: BakeSpec):
        self.name = name
        self.spec = spec
        self._bake: Bake | None = None
        self._lock: threading.Lock | None = None

    def setup(self, worker) -> None:
        self._lock = threading.Lock()

    def teardown(self, worker) -> None:
        self._bake = None

    def bake(self) -> Bake:
        """The worker's bake, built once whatever the number of its threads."""
        with self._lock:
            if self._bake is None:
                self._bake = self.spec.build()
            return self._bake


def run_chunk(name: str, stage: str, chunk: Chunk, inputs) -> ChunkResult:
    """One chunk's work on this worker: the flood fill's (``stage`` ``"fit"``, ``inputs`` a
    :class:`lobelight.fit._chunk.Neighbours` or None) or the relaxation's (``"relax"``,
    ``inputs`` a :class:`lobelight.fit._chunk.RefitInputs`), for the bake of plugin ``name``.
    Returns the result on the CPU."""
    bake = get_worker().plugins[name].bake()
    dev = bake.transport.device
    chunk = Chunk(chunk.index, chunk.vertices.to(dev), chunk.front)
    inputs = None if inputs is None else inputs.to(dev)
    # a chunk's work runs on one torch thread wherever it runs (lobelight.fit._runner): the
    # same arithmetic, so the same model, as a bake in one process
    if torch.get_num_threads() != 1:
        torch.set_num_threads(1)
    return compute_chunk(stage, bake, chunk, inputs).to("cpu")
