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
- **The order**: with one Gaussian per view the chunks are independent and all are handed out
  at once. With two or more, the spatial term reads processed neighbours: the chunks of one
  wavefront of the flood fill run at once, each reading the wavefronts before its own only,
  and the wavefronts run in order; the relaxation refits one wavefront's chunks at once
  against the current Gaussians of all the others. Neighbours in one wavefront do not see
  each other's new lobes, as they do in the single-process bake, so with two or more
  Gaussians the result differs from it (and the checkpoint's settings say which order made
  it); with one it is the same, bit for bit.
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
from collections.abc import Callable, Iterator
from concurrent.futures import CancelledError

import torch

from ..errors import InputError
from ._checkpoint import Checkpoint, Position
from ._chunk import Bake, Chunk, ChunkResult, fit_inputs, refit_inputs

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
#: Vertex ids an error message lists before it counts the rest.
_LISTED = 12
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


def name_vertices(ids: torch.Tensor) -> str:
    """``"vertices 3, 4, 9"``, the first few and a count where there are many."""
    ids = ids.reshape(-1).tolist()
    text = ", ".join(str(i) for i in ids[:_LISTED])
    if len(ids) > _LISTED:
        text += f", ... ({len(ids)} in all)"
    return f"vertices {text}" if len(ids) != 1 else f"vertex {text}"


def checked(result: ChunkResult, stage: str) -> ChunkResult:
    """``result``, after checking that its values are finite (an InputError naming the
    vertices where they are not)."""
    bad = result.nonfinite()
    if bad.numel():
        raise InputError(
            name_vertices(bad),
            f"the {stage} gave values that are not finite (NaN or infinite): a degenerate "
            "triangle or material there?",
        )
    return result


class ClusterRun:
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

    def run(
        self,
        stage: str,
        bake: Bake,
        chunks: list[Chunk],
        start: Position,
        ckpt: Checkpoint,
        progress: Callable[[str, int, int], None] | None,
        *,
        force_last: bool,
    ) -> None:
        """Run the chunks of ``stage`` (``"fit"`` or ``"relax"``) not yet done, group by group
        (:func:`_groups`), writing each result into ``bake``'s state as it arrives, saving the
        checkpoint (after each result in the flood fill, after each group in the relaxation,
        whose chunks read the state as the group found it) and reporting progress."""
        finished = _finished(stage, bake, chunks, start)
        readable = _fronts(bake, chunks) if stage == "fit" and bake.n > 1 else None
        total = len(chunks)
        for group in _groups(chunks, bake.n):
            todo = [c for c in group if not finished[c.index]]
            if not todo:
                continue
            self._group(stage, bake, todo, readable, finished, ckpt, progress, force_last)
            if stage != "fit":
                nxt = group[-1].index + 1
                at = Position(stage, nxt, bake.flips_before, bake.flips_after)
                ckpt.save(at, bake.state.arrays(), force=force_last and nxt == total)

    def _group(self, stage, bake, todo, readable, finished, ckpt, progress, force_last) -> None:
        """Submit the chunks ``todo`` at once and take their results as they come."""
        from distributed import as_completed  # optional: the [cluster] extra

        from ._worker import run_chunk  # optional: needs distributed (the [cluster] extra)

        futures = {}
        for c in todo:
            inputs = _inputs(stage, bake, c, readable)
            cpu = Chunk(c.index, c.vertices.cpu(), c.front)
            fut = self.client.submit(run_chunk, self.name, stage, cpu, inputs, pure=False)
            futures[fut] = c
        try:
            for fut in as_completed(list(futures), loop=self.client.loop):
                chunk = futures.pop(fut)
                result = _take(fut, chunk, stage, self.client.scheduler.address)
                fut.release()  # the worker may forget it
                checked(result.to(bake.state.w.device), stage).apply(bake)
                finished[chunk.index] = True
                done, total = int(finished.sum()), finished.numel()
                if stage == "fit":
                    nxt = int(finished.logical_not().nonzero()[0]) if done < total else total
                    at = Position(stage, nxt, bake.flips_before, bake.flips_after)
                    ckpt.save(at, bake.state.arrays(), force=force_last and done == total)
                if progress is not None:
                    progress(stage, done, total)
        finally:
            if futures:  # a fault, or the caller gone: the rest is not wanted
                with contextlib.suppress(Exception):  # nothing to cancel on a lost scheduler
                    self.client.cancel(list(futures))


def _inputs(stage: str, bake: Bake, chunk: Chunk, readable):
    """What ``chunk`` reads of the state, on the CPU."""
    if stage == "fit":
        nb = fit_inputs(bake, chunk, None if readable is None else readable < chunk.front)
        return None if nb is None else nb.to("cpu")
    return refit_inputs(bake, chunk).to("cpu")


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


def _finished(stage: str, bake: Bake, chunks: list[Chunk], start: Position) -> torch.Tensor:
    """(K,) bool, the chunks of ``stage`` done already: in the flood fill, those whose
    vertices it has all reached (a resumed bake's results may have come in any order);
    in the relaxation, those before the checkpoint's next chunk."""
    done = torch.zeros(len(chunks), dtype=torch.bool)
    if stage == "fit":
        reached = bake.state.done.cpu()
        for c in chunks:
            done[c.index] = bool(reached[c.vertices.cpu()].all())
    else:
        done[: start.first_chunk(stage)] = True
    return done


def _fronts(bake: Bake, chunks: list[Chunk]) -> torch.Tensor:
    """(V,) int64, each vertex's wavefront (its chunk's ``front``), on the state's device."""
    front = torch.zeros(bake.mesh.n_vertices, dtype=torch.int64, device=bake.state.done.device)
    for c in chunks:
        front[c.vertices] = c.front
    return front


def _groups(chunks: list[Chunk], n: int) -> list[list[Chunk]]:
    """The chunks that run at once, in the order the groups run: all of them with one Gaussian
    per view, one wavefront's with more."""
    if n == 1:
        return [chunks]
    groups: list[list[Chunk]] = []
    for c in chunks:
        if groups and groups[-1][0].front == c.front:
            groups[-1].append(c)
        else:
            groups.append([c])
    return groups
