"""The calibrated visibility weights of eq. (39), read from the package data file ``weights.json``.

Visibility of a point is ``V = 1 - sum_k w(depth_k, dist) c_k`` (:mod:`._visibility`), with one
weight per shadow leaf depth and per ``dist`` node (:data:`~._visibility.DIST_NODES`, the
paper's ``{0.25, 0.5, 1, 2, ..., 10}``), linearly interpolated in ``dist`` between the nodes.
The file holds one table per ``(mode, max depth)`` of the masks:

``weights``
    ``{"mode:max_depth": rows}``; row ``d`` is leaf depth ``d`` (``0..max_depth``), its
    column ``i`` the weight at ``dist = DIST_NODES[i]``: ``(max_depth + 1, 12)`` numbers
``dist_nodes``
    the ``dist`` grid the columns are on (:data:`~._visibility.DIST_NODES`)
``report``
    per key the calibration's rms and largest errors, relative to each light's unoccluded
    maximum, before (all weights 1) and after, and the number of points fitted
``about``
    these facts in a sentence

The weights are calibrated once, as the paper prescribes, on one scene (a plane, an object
of spheres, one light at the distances of the ``dist`` nodes) by non-negative least squares
against Monte Carlo radiance: ``tools/calibrate_cosine_weights.py`` in the source tree writes
the file. JSON numbers are Python's shortest round-tripping ``repr`` of each float, so the
values read are exactly the calibrated ones.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Mapping
from importlib import resources
from types import MappingProxyType

import torch

from ..errors import InputError, LobelightError
from ._visibility import DIST_NODES

__all__ = ["WEIGHTS_FILE", "calibrated_weights", "default_weights"]

#: The data file's name inside the package ``lobelight.cosine``.
WEIGHTS_FILE = "weights.json"


@functools.cache
def calibrated_weights() -> Mapping[str, tuple[tuple[float, ...], ...]]:
    """The stored tables, read once: ``{"mode:max_depth": ((max_depth + 1) x 12 floats)}``.

    Read through :mod:`importlib.resources`, so an installed wheel finds its own copy. The
    mapping and its rows are read-only (one cached copy serves every caller).
    """
    text = resources.files(__package__).joinpath(WEIGHTS_FILE).read_text(encoding="utf-8")
    doc = json.loads(text)
    if tuple(doc.get("dist_nodes", ())) != DIST_NODES:
        raise LobelightError(
            f"{WEIGHTS_FILE}: its dist nodes {doc.get('dist_nodes')!r} are not {DIST_NODES}"
        )
    return MappingProxyType(
        {key: tuple(tuple(row) for row in rows) for key, rows in doc["weights"].items()}
    )


def default_weights(mode: str, depth: int) -> torch.Tensor:
    """The stored eq. (39) weights of ``(mode, depth)``: ``(depth + 1, 12)`` float32."""
    weights = calibrated_weights()
    key = f"{mode}:{int(depth)}"
    if key not in weights:
        raise InputError(
            "depth",
            f"no calibrated weights for {key}; have {sorted(weights)} "
            "(tools/calibrate_cosine_weights.py calibrates more)",
        )
    return torch.tensor(weights[key], dtype=torch.float32)
