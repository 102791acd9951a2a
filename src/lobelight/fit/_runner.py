"""How a bake's chunks run: in groups, on threads of this process or on a cluster's workers.

:func:`lobelight.fit.fit_mesh` hands the chunks of its flood fill and its relaxation
(:mod:`._chunk`) to a :class:`ChunkRun`: :class:`ThreadRun` here, or
:class:`lobelight.fit._cluster.ClusterRun` on a Dask cluster. Both run them the same way:

- **Groups**: with one Gaussian per view the chunks are independent and form one group; with
  two or more, the spatial term reads processed neighbours, so each wavefront of the flood fill
  is a group, and the groups run in order (:func:`groups`).
- **What a chunk reads** is gathered when its group starts (:func:`inputs`): in the flood fill
  its neighbours in earlier wavefronts, in the relaxation all its neighbours' Gaussians as the
  group found them. A chunk never reads the result of another chunk of its group, so the
  chunks of a group run at once, and the result does not depend on how many run at once, in
  what order they finish, or where: on one thread, on several, or on a cluster's workers.
- **Results** are written into the bake's state as they arrive, in this thread; the checkpoint
  is saved after each (flood fill) or after each group (relaxation), and the progress counts
  chunks.

A chunk's work runs on one torch thread (:class:`ThreadRun` sets torch's thread count to 1
while it runs, and a cluster's workers have one thread each): the chunks' small tensor
operations gain little from a second thread inside one chunk, and much from a second chunk
beside it, and a chunk's arithmetic, and so the model, is the same bit for bit wherever it ran.
"""

from __future__ import annotations

import concurrent.futures
import ctypes
from collections.abc import Callable, Iterable, Iterator

import torch

from .._memory import glibc_function
from ..errors import InputError
from ._checkpoint import Checkpoint, Position
from ._chunk import Bake, Chunk, ChunkResult, compute_chunk, fit_inputs, refit_inputs

__all__ = ["ChunkRun", "ThreadRun", "checked", "groups", "inputs", "name_vertices"]

#: Vertex ids an error message lists before it counts the rest.
_LISTED = 12


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


class ChunkRun:
    """The chunks of one bake, run in groups (module docstring). A subclass says where a chunk
    runs: :meth:`_submit` starts one and returns its future, :meth:`_completed` yields futures
    as they finish, :meth:`_take` returns a future's result (or raises one clear error),
    :meth:`_cancel` gives up futures not yet taken."""

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
        (:func:`groups`), writing each result into ``bake``'s state as it arrives, saving the
        checkpoint (after each result in the flood fill, after each group in the relaxation,
        whose chunks read the state as the group found it; a save forced after the last one
        where ``force_last``) and reporting progress."""
        finished = _finished(stage, bake, chunks, start)
        readable = _fronts(bake, chunks) if stage == "fit" and bake.n > 1 else None
        for group in groups(chunks, bake.n):
            todo = [c for c in group if not finished[c.index]]
            if not todo:
                continue
            self._group(stage, bake, todo, readable, finished, ckpt, progress, force_last)

    def close(self) -> None:
        """Release what the run holds (threads, a cluster's plugin)."""

    def _group(self, stage, bake, todo, readable, finished, ckpt, progress, force_last) -> None:
        """Start the chunks ``todo`` at once and take their results as they come."""
        futures = {}
        try:
            for c in todo:
                futures[self._submit(stage, c, inputs(stage, bake, c, readable))] = c
            for fut in self._completed(list(futures)):
                chunk = futures.pop(fut)
                result = self._take(fut, chunk, stage)
                checked(result.to(bake.state.w.device), stage).apply(bake)
                finished[chunk.index] = True
                done, total = int(finished.sum()), finished.numel()
                if stage == "fit":  # the first chunk not done yet
                    nxt = int(finished.logical_not().nonzero()[0]) if done < total else total
                elif not futures:  # the relaxation's group, whole: the chunk after it
                    nxt = todo[-1].index + 1
                else:  # a part of a group is not a state to resume from
                    nxt = None
                if nxt is not None:
                    at = Position(stage, nxt, bake.flips_before, bake.flips_after)
                    ckpt.save(at, bake.state.arrays(), force=force_last and nxt == total)
                if progress is not None:
                    progress(stage, done, total)
        finally:
            if futures:  # a fault, or the caller gone: the rest is not wanted
                self._cancel(list(futures))

    def _submit(self, stage: str, chunk: Chunk, inputs):
        raise NotImplementedError

    def _completed(self, futures: list) -> Iterable:
        raise NotImplementedError

    def _take(self, fut, chunk: Chunk, stage: str) -> ChunkResult:
        raise NotImplementedError

    def _cancel(self, futures: list) -> None:
        raise NotImplementedError


class ThreadRun(ChunkRun):
    """The chunks of ``bake`` on ``threads`` threads of this process, each chunk on one torch
    thread: on the CPU torch's thread count is 1 while a stage's chunks run (:meth:`run`), and
    restored after (a process-wide setting: other torch work of the process meanwhile runs on
    one thread too)."""

    def __init__(self, bake: Bake, threads: int):
        self.bake = bake
        self.threads = threads
        # what every chunk reads first and the transport makes on first use, made here once
        # (the threads would each make it: the vertices' ray origins, with their rays)
        _ = bake.transport.origins
        self._pool = concurrent.futures.ThreadPoolExecutor(
            threads, thread_name_prefix="lobelight-chunk"
        )

    def run(self, *args, **kwargs) -> None:
        """:meth:`ChunkRun.run` on one torch thread per chunk; then torch's thread count as it
        was, and the threads' free memory given back (:func:`_trim_heap`) for the work after
        the stage, which runs on this thread."""
        before = torch.get_num_threads()
        if self.bake.transport.device.type == "cpu":  # a GPU's arithmetic does not depend on it
            torch.set_num_threads(1)
        try:
            super().run(*args, **kwargs)
        finally:
            torch.set_num_threads(before)
            _trim_heap()

    def close(self) -> None:
        """Stop the threads, once the chunks under way (after a fault or an interruption; their
        results are not taken) have ended: at most one chunk's time per thread. A thread still
        computing when the process ends would have the C++ runtimes' teardown run under it."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def _submit(self, stage: str, chunk: Chunk, inputs):
        return self._pool.submit(compute_chunk, stage, self.bake, chunk, inputs)

    def _completed(self, futures: list) -> Iterator:
        return concurrent.futures.as_completed(futures)

    def _take(self, fut, chunk: Chunk, stage: str) -> ChunkResult:
        return fut.result()  # the chunk's own exception, as it raised it

    def _cancel(self, futures: list) -> None:
        for fut in futures:
            fut.cancel()


def inputs(stage: str, bake: Bake, chunk: Chunk, readable: torch.Tensor | None):
    """What ``chunk`` reads of the state when its group starts: in the flood fill its processed
    neighbours (in the wavefronts before its own, ``readable`` each vertex's wavefront, with
    two or more Gaussians per view), in the relaxation its :func:`refit_inputs`."""
    if stage == "fit":
        return fit_inputs(bake, chunk, None if readable is None else readable < chunk.front)
    return refit_inputs(bake, chunk)


def groups(chunks: list[Chunk], n: int) -> list[list[Chunk]]:
    """The chunks that run at once, in the order the groups run: all of them with one Gaussian
    per view, one wavefront's with more."""
    if n == 1:
        return [chunks]
    out: list[list[Chunk]] = []
    for c in chunks:
        if out and out[-1][0].front == c.front:
            out[-1].append(c)
        else:
            out.append([c])
    return out


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


def _trim_heap() -> None:
    """Return the free memory of glibc's heaps to the system (``malloc_trim``; elsewhere
    nothing). Each chunk thread allocates from a heap (arena) of its own, which a process that
    keeps freed memory (:func:`lobelight.cli.tune`) never shrinks, and which the work after a
    stage's chunks, on the main thread, cannot reuse: without this its peak adds to theirs."""
    trim = glibc_function("malloc_trim", [ctypes.c_size_t], ctypes.c_int)
    if trim is not None:
        trim(0)
