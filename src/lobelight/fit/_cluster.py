"""A bake on a Dask cluster: its chunks run on the workers, its state stays with the client.

:func:`lobelight.fit.fit_mesh` with a ``client`` (a ``distributed.Client``) runs the flood fill
and the relaxation (:mod:`lobelight.fit._chunk`) through a :class:`ClusterRun`:

- **What crosses, once**: the scene, the views and the settings, as a worker plugin
  (:class:`lobelight.fit._worker.BakePlugin`) that the scheduler hands to every worker, and to
  every worker that joins or is restarted later; a worker builds the scene's transport at its
  first chunk and keeps it. Workers need lobelight and Dask installed, and no data files.
- **Devices**: a worker computes on the bake's ``device`` where one is given (the client
  too), else on its own CUDA device where it has one, else on its CPU; results cross on the
  CPU.
- **What crosses per chunk**: the chunk (its vertex ids) and what it reads of the state (its
  processed neighbours' Gaussians, with two or more Gaussians per view), then its result
  (the state's arrays at its vertices): tensors of the chunk's size, on the CPU.
- **Where the state is**: with the client, which writes each result into it as it arrives
  (``as_completed``), reports progress and saves the checkpoint
  (:mod:`lobelight.fit._checkpoint`) as the single-process bake does.
- **The order**: the chunks run in groups, as on threads in one process
  (:mod:`lobelight.fit._runner`): all at once with one Gaussian per view, a wavefront's at once
  with two or more, each reading what its group found; the workers have one thread each, so
  the model is the one process's, bit for bit.
- **The interreflection** (:func:`lobelight.transport.diffuse_interreflection`), which couples
  all vertices, runs on the client: it reads every vertex's diffuse transfer and final
  Gaussians, the largest arrays of the bake, which are already there; on a worker they would
  cross the network twice. Its cost per vertex (a few hundred rays, a sparse product per
  bounce) is small beside the fit's on one machine, but it does not shrink with the workers:
  on many of them it is the part of the bake left to the client.

Faults: a worker that dies mid-chunk has its chunks run again on another (the scheduler
reschedules the tasks of a lost worker, up to ``distributed.scheduler.allowed-failures``
times; the nanny restarts the worker, and the plugin reaches it again). A chunk that raises on
a worker, kills workers in turn or returns values that are not finite stops the bake with one
:class:`lobelight.errors.InputError` naming its vertices. A client that dies leaves its
checkpoint, which a bake with a cluster or without one resumes. :func:`cluster` connects to a
scheduler, or starts a local cluster, with one clear error where none answers; a scheduler lost
in the middle of a bake is one clear error too (the checkpoint stays).
"""

from __future__ import annotations

import contextlib
import uuid
from collections.abc import Iterator
from concurrent.futures import CancelledError

from ..errors import InputError
from ._chunk import Chunk, ChunkResult
from ._runner import ChunkRun, name_vertices

__all__ = ["CONNECT_TIMEOUT", "WORKER_ENVIRON", "ClusterRun", "cluster"]

#: Seconds :func:`cluster` waits for a scheduler to answer.
CONNECT_TIMEOUT = 10.0
#: The environment of the worker processes :func:`cluster` starts: glibc's allocator settings
#: of :func:`lobelight.cli.tune` (blocks up to 32 MB served from a heap that is never
#: trimmed), as glibc reads them at a process's start. A Dask nanny starts its worker with
#: ``MALLOC_TRIM_THRESHOLD_=65536`` (its ``distributed.nanny.pre-spawn-environ``), under
#: which a fit page-faults its memory in again at every allocation of its large tensors.
WORKER_ENVIRON = {
    "MALLOC_MMAP_THRESHOLD_": 32 * 1024 * 1024,
    "MALLOC_TRIM_THRESHOLD_": 2**31 - 1,
    "MALLOC_TOP_PAD_": 512 * 1024 * 1024,
}
_HINT = "pip install 'lobelight[cluster]' (dask[distributed])"


@contextlib.contextmanager
def cluster(
    address: str | None = None, *, workers: int | None = None, timeout: float = CONNECT_TIMEOUT
) -> Iterator:
    """A ``distributed.Client`` for a bake, closed on leaving the ``with`` block: connected to
    the scheduler at ``address`` (``tcp://HOST:8786``, started with ``dask scheduler``), or to a
    cluster of ``workers`` local worker processes of one thread each (a nanny restarts one that
    dies; their environment :data:`WORKER_ENVIRON`), started here and closed on leaving.

    Raises
    ------
    InputError
        no scheduler answers at ``address`` within ``timeout`` seconds; neither or both of
        ``address`` and ``workers``; Dask not installed
    """
    try:
        import dask  # optional: the [cluster] extra
        from distributed import Client, LocalCluster  # optional: the [cluster] extra
    except ImportError as e:
        raise InputError("cluster", f"a bake on a cluster needs Dask: {_HINT}") from e
    if (address is None) == (workers is None):
        raise InputError("cluster", "give a scheduler's address or a number of local workers")
    if address is not None:
        try:
            client = Client(address, timeout=timeout, set_as_default=False)
        except (OSError, TimeoutError, ValueError) as e:
            raise InputError(
                address,
                f"no Dask scheduler answered within {timeout:g} s ({type(e).__name__}); start "
                "one with `dask scheduler` and give the address it prints (tcp://HOST:8786)",
            ) from e
        with client:
            yield client
        return
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise InputError("workers", f"must be a positive number of processes, got {workers!r}")
    environ = {f"distributed.nanny.pre-spawn-environ.{k}": v for k, v in WORKER_ENVIRON.items()}
    with (
        dask.config.set(environ),
        LocalCluster(
            n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None
        ) as local,
        Client(local, set_as_default=False) as client,
    ):
        yield client


class ClusterRun(ChunkRun):
    """The chunks of one bake on the cluster of ``client`` (module docstring).

    Parameters
    ----------
    client : distributed.Client;  spec : :class:`lobelight.fit._worker.BakeSpec` of the bake
    """

    def __init__(self, client, spec):
        from ._worker import BakePlugin  # optional: needs distributed (the [cluster] extra)

        self.client = client
        self.name = f"lobelight-bake-{uuid.uuid4().hex}"
        client.register_plugin(BakePlugin(self.name, spec))

    def close(self) -> None:
        """Remove the bake's plugin (and with it each worker's transport) from the cluster."""
        with contextlib.suppress(Exception):  # a lost scheduler has nothing left to remove
            self.client.unregister_worker_plugin(self.name)

    def workers(self) -> int:
        """Workers the scheduler knows now."""
        return len(self.client.scheduler_info(n_workers=-1).get("workers", {}))

    def _submit(self, stage: str, chunk: Chunk, inputs):
        from ._worker import run_chunk  # optional: needs distributed (the [cluster] extra)

        cpu = Chunk(chunk.index, chunk.vertices.cpu(), chunk.front)
        inputs = None if inputs is None else inputs.to("cpu")
        return self.client.submit(run_chunk, self.name, stage, cpu, inputs, pure=False)

    def _completed(self, futures: list) -> Iterator:
        from distributed import as_completed  # optional: the [cluster] extra

        return as_completed(futures, loop=self.client.loop)

    def _take(self, fut, chunk: Chunk, stage: str) -> ChunkResult:
        result = _take(fut, chunk, stage, self.client.scheduler.address)
        fut.release()  # the worker may forget it
        return result

    def _cancel(self, futures: list) -> None:
        with contextlib.suppress(Exception):  # nothing to cancel on a lost scheduler
            self.client.cancel(futures)


def _take(fut, chunk: Chunk, stage: str, scheduler: str) -> ChunkResult:
    """The result of ``fut``, or one InputError naming the chunk's vertices (or the
    ``scheduler``, where the client lost it)."""
    from distributed import KilledWorker  # optional: the [cluster] extra

    try:
        return fut.result()
    except CancelledError as e:  # the client cancels only what it no longer waits for
        raise InputError(
            scheduler,
            "the connection to the Dask scheduler was lost in the middle of the bake "
            f"({type(e).__name__}); run the bake again to resume from its checkpoint",
        ) from e
    except KilledWorker as e:
        raise InputError(
            name_vertices(chunk.vertices),
            f"the {stage} of this chunk ended the worker processes it ran on, one after "
            "another (out of memory, or a crash on its data)",
        ) from e
    except ImportError as e:
        raise InputError(
            "cluster", f"a worker cannot run lobelight ({type(e).__name__}: {e}): {_HINT}"
        ) from e
    except (OSError, TimeoutError):
        raise  # the scheduler lost, not the chunk's doing
    except Exception as e:  # the chunk's own work raised on the worker
        raise InputError(
            name_vertices(chunk.vertices),
            f"the {stage} of this chunk failed on a worker: {type(e).__name__}: {e}",
        ) from e
