"""The checkpoint of a bake: the file an interrupted bake resumes from.

A bake (:func:`lobelight.fit.fit_mesh`) runs its :data:`STAGES` in order; the flood fill and the
relaxation run their chunks (:class:`lobelight.fit._chunk.Chunk`) in groups, several at once
(:mod:`lobelight.fit._runner`). Where the bake stands is a :class:`Position`; a
:class:`Checkpoint` saves the bake's arrays with it, and a bake that finds a checkpoint of the
same scene and settings (:func:`settings_key`) goes on from there.

The file is an ``.npz`` of plain arrays, never pickled, written whole
(:func:`lobelight._io.atomic_writer`): one array per entry of the bake's state (``mu``,
``lam``, ``w``, ...), and ``meta``, UTF-8 JSON as uint8 bytes holding ``key``, ``stage``,
``next`` (the first chunk of that stage not done: in the flood fill, which records
each chunk's vertices as reached, later chunks may be done too; in the relaxation, which saves
whole groups, none after it is), ``flips_before`` and ``flips_after`` (each a pair of
counts: all flipped pairs, and those of separated lobes). The caller removes the file once the
finished model is written.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

from .._cache import UNREADABLE
from .._io import atomic_writer

__all__ = ["STAGES", "START", "Checkpoint", "Position", "settings_key"]

logger = logging.getLogger(__name__)

#: The stages of a bake, in order, as checkpoints name them: the flood fill (by chunks), the
#: relaxation (by chunks, then the reordering), the diffuse interreflection (one step: it needs
#: every vertex's self-shadowed transfer and final Gaussians), then done.
STAGES = ("fit", "relax", "interreflection", "done")


class Position(NamedTuple):
    """Where a bake stands: the stage it is in, the next chunk of that stage, and the flipped
    (edge, view) pairs counted after the flood fill and after the relaxation, each as (all,
    among separated lobes)."""

    stage: str
    next_chunk: int
    flips_before: tuple[int, int]
    flips_after: tuple[int, int]

    def todo(self, stage: str) -> bool:
        """Whether ``stage`` is still to run, whole or in part, from this position."""
        return STAGES.index(stage) >= STAGES.index(self.stage)

    def first_chunk(self, stage: str) -> int:
        """The chunk a stage still to run starts at: the next one where this position is in
        it, else the first."""
        return self.next_chunk if stage == self.stage else 0


#: Where a bake without a usable checkpoint starts.
START = Position("fit", 0, (0, 0), (0, 0))


def settings_key(scene, n, views, weights, batch, transport_settings, relax, seed) -> str:
    """A digest of everything a bake's result depends on: geometry, materials and settings
    (``transport_settings``: a tuple of the transport's, hashed by its ``repr``)."""
    h = hashlib.sha256()
    for t in (scene.mesh.vertices, scene.mesh.faces, views):
        h.update(t.detach().cpu().contiguous().numpy().tobytes())
    h.update(json.dumps(scene.materials.to_dict(), sort_keys=True).encode())
    h.update(repr((n, weights, batch, transport_settings, relax, seed)).encode())
    return h.hexdigest()


class Checkpoint:
    """The checkpoint file of one bake (module docstring), or none (``path`` None: resuming
    starts afresh and saving does nothing).

    Parameters
    ----------
    path : the file;  key : :func:`settings_key` of the bake
    every : seconds between saves; :meth:`save` with ``force`` saves at once (a stage's end)
    """

    def __init__(self, path: str | os.PathLike | None, key: str, *, every: float = 30.0):
        self.path = Path(path) if path is not None else None
        self.key = key
        self.every = every
        self._last_save = time.perf_counter()

    def resume(self, state: dict[str, torch.Tensor]) -> Position:
        """Load a matching checkpoint into ``state`` (in place) and return its position, or
        leave ``state`` alone and return :data:`START`.

        A checkpoint of another scene or other settings is left alone and the bake starts
        over; a damaged one (cut short, bits flipped, fields of the wrong type, arrays of the
        wrong kind or not finite) is moved aside as ``NAME.corrupt`` with one warning, and the
        bake starts afresh: it never stands in the way of a bake.
        """
        position = self._resume(state)
        self._last_save = time.perf_counter()
        return position

    def save(self, position: Position, state: dict[str, torch.Tensor], *, force=False) -> None:
        """Save ``state`` at ``position``, if ``every`` seconds have passed since the last save
        (or ``force``)."""
        if self.path is None or (not force and time.perf_counter() - self._last_save < self.every):
            return
        arrays = {k: v.detach().cpu().numpy() for k, v in state.items()}
        meta = {
            "key": self.key,
            "stage": position.stage,
            "next": position.next_chunk,
            "flips_before": list(position.flips_before),
            "flips_after": list(position.flips_after),
        }
        arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)
        with atomic_writer(self.path) as f:
            np.savez(f, **arrays)
        self._last_save = time.perf_counter()

    def _resume(self, state: dict[str, torch.Tensor]) -> Position:
        if self.path is None or not self.path.is_file():
            return START
        try:
            found = self._read(state)
        except (*UNREADABLE, TypeError) as e:
            # damaged: kept aside for a look, never in the way of a bake
            aside = self.path.with_name(self.path.name + ".corrupt")
            os.replace(self.path, aside)
            logger.warning(
                "%s: unreadable checkpoint (%s), moved to %s; the bake starts afresh",
                self.path, type(e).__name__, aside.name,
            )  # fmt: skip
            return START
        if found is None:
            return START
        position, loaded = found
        for k, v in loaded.items():
            state[k].copy_(v.to(state[k].device))
        return position

    def _read(self, state: dict[str, torch.Tensor]):
        """``(position, arrays)`` of the file, or None where it belongs to another bake;
        raises what :meth:`_resume` takes for damage."""
        with np.load(self.path, allow_pickle=False) as z:
            meta = json.loads(bytes(z["meta"]).decode())
            if (
                not isinstance(meta, dict)
                or meta.get("key") != self.key
                or meta.get("stage") not in STAGES
            ):
                return None  # another scene or other settings: start over
            position = _position(meta)
            loaded = {k: torch.from_numpy(z[k]) for k in state}
        for k, v in loaded.items():
            if v.shape != state[k].shape:
                return None
            if v.dtype != state[k].dtype or (v.is_floating_point() and not v.isfinite().all()):
                raise ValueError(f"{k}: {v.dtype} values, not finite {state[k].dtype} ones")
        return position, loaded


def _count(x) -> int:
    if isinstance(x, bool) or not isinstance(x, int) or x < 0:
        raise ValueError(f"{x!r} is not a count")
    return x


def _pair(x) -> tuple[int, int]:
    if isinstance(x, int) and not isinstance(x, bool):  # a single count
        return _count(x), 0
    a, b = x  # TypeError / ValueError for anything but a pair
    return _count(a), _count(b)


def _position(meta: dict) -> Position:
    """The :class:`Position` in a checkpoint's metadata; raises ValueError or TypeError where
    a field is not what a bake writes."""
    return Position(
        str(meta["stage"]),
        _count(meta["next"]),
        _pair(meta.get("flips_before", [0, 0])),
        _pair(meta.get("flips_after", [0, 0])),
    )
