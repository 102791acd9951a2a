"""Fitting light transport with spherical Gaussians (Green et al. 2006, section 4).

- :func:`gather` samples each vertex's glossy transport where it lives (:class:`FitData`).
- :func:`fit_batch` minimises eq. (6), ``alpha D + beta M + gamma V + delta S``, for a batch of
  vertices over all views at once (:class:`Gaussians`, :class:`Weights`).
- :func:`fit_mesh` fits a whole mesh by flood-fill wavefronts, with a relaxation pass against
  flipped Gaussians (:class:`MeshFit`), resumable from a checkpoint file.
- :func:`fit_model` ``(scene, n_gaussians=1, *, device, ...) -> lobelight.model.Model`` does it all.
"""

from ._data import FitData, gather, half_vector_lobes, lobe_estimate
from ._floodfill import MeshFit, count_flips, fit_mesh, wavefronts
from ._model import fit_model
from ._objective import Weights, flip_count
from ._optimize import LAM_RANGE, Gaussians, fit_batch, initial_guess

__all__ = [
    "LAM_RANGE",
    "FitData",
    "Gaussians",
    "MeshFit",
    "Weights",
    "count_flips",
    "fit_batch",
    "fit_mesh",
    "fit_model",
    "flip_count",
    "gather",
    "half_vector_lobes",
    "initial_guess",
    "lobe_estimate",
    "wavefronts",
]
