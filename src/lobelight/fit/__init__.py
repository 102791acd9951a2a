"""Fitting light transport with spherical Gaussians (Green et al. 2006, section 4).

- :func:`gather` samples each vertex's glossy transport where it lives (:class:`FitData`).
- :func:`fit_batch` minimises eq. (6), ``alpha D + beta M + gamma V + delta S``, for a batch of
  vertices over all views at once (:class:`Gaussians`, :class:`Weights`).
"""

from ._data import FitData, gather, lobe_estimate
from ._objective import Weights, flip_count
from ._optimize import LAM_RANGE, Gaussians, fit_batch, initial_guess

__all__ = [
    "LAM_RANGE",
    "FitData",
    "Gaussians",
    "Weights",
    "fit_batch",
    "flip_count",
    "gather",
    "initial_guess",
    "lobe_estimate",
]
