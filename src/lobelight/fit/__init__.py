"""Fitting light transport with spherical Gaussians (Green et al. 2006, section 4).

- :func:`gather` samples each vertex's glossy transport where it lives (:class:`FitData`).
- :func:`fit_batch` minimises eq. (6), ``alpha D + beta M + gamma V + delta S``, for a batch of
  vertices over all views at once (:class:`Gaussians`, :class:`Weights`).
- :func:`fit_mesh` fits a whole mesh by flood-fill wavefronts, with a relaxation pass against
  flipped Gaussians (:class:`MeshFit`), resumable from a checkpoint file.
- :func:`fit_model` ``(scene, n_gaussians="auto", *, device, memory_gb=4, ...) ->
  lobelight.model.Model`` does it all, on the mesh :func:`refine_scene` refines where an
  edge's ends see the environment differently, with :func:`choose_gaussians` choosing the
  Gaussians per view from the material, and the batch sizes derived from the memory budget
  (:data:`MEMORY_GB`).
- ``fit_model(..., client=)`` runs the chunks of the bake on a Dask cluster (a
  ``distributed.Client``, or a scheduler's address; the optional ``[cluster]`` extra), and
  :func:`cluster` connects to one or starts one on this machine (:mod:`lobelight.fit._cluster`
  says how the work is split and what crosses).
"""

from ._auto import choose_gaussians, lobe_shape
from ._cluster import CONNECT_TIMEOUT, WORKER_ENVIRON, cluster
from ._data import FitData, gather, half_vector_lobes, lobe_estimate
from ._floodfill import MeshFit, count_flips, fit_mesh, wavefronts
from ._memory import MEMORY_GB
from ._model import fit_model
from ._objective import Weights, flip_count
from ._optimize import LAM_RANGE, Gaussians, fit_batch, initial_guess
from ._refine import (
    REFINE_DIFFERENCE,
    REFINE_MAX_GROWTH,
    REFINE_MIN_EDGE,
    REFINE_ROUNDS,
    refine_scene,
)

__all__ = [
    "CONNECT_TIMEOUT",
    "LAM_RANGE",
    "MEMORY_GB",
    "REFINE_DIFFERENCE",
    "REFINE_MAX_GROWTH",
    "REFINE_MIN_EDGE",
    "REFINE_ROUNDS",
    "WORKER_ENVIRON",
    "FitData",
    "Gaussians",
    "MeshFit",
    "Weights",
    "choose_gaussians",
    "cluster",
    "count_flips",
    "fit_batch",
    "fit_mesh",
    "fit_model",
    "flip_count",
    "gather",
    "half_vector_lobes",
    "initial_guess",
    "lobe_estimate",
    "lobe_shape",
    "refine_scene",
    "wavefronts",
]
