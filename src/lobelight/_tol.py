"""Named guard tolerances: the small numbers that keep a division, a logarithm or a root finite.

One home for them, as trimesh keeps its ``tol``. Each guard is far below any value the guarded
quantity takes where it matters and far above its dtype's underflow, so a guarded expression
equals the unguarded one wherever that one is finite, and is finite where it is not (an empty
sum, a zero-length vector, a Gaussian of zero sharpness). A tolerance that belongs to one
algorithm (a convergence test, a fit's step) stays beside it as a named module constant.
"""

from __future__ import annotations

__all__ = ["DIVISOR_F32", "DIVISOR_F64", "REL_F64", "SHARPNESS_MIN", "SMALL"]

#: Floor of a divisor or of a logarithm's argument in float32 arithmetic (a norm, a sum of
#: non-negative weights, a probability density): above float32's smallest normal (1.2e-38),
#: so its reciprocal (1e30) and logarithm (-69) stay finite and exact enough.
DIVISOR_F32 = 1e-30

#: The same floor in float64 arithmetic (float64's smallest normal is 2.2e-308).
DIVISOR_F64 = 1e-300

#: Floor of a Gaussian's sharpness ``lam`` before ``rsqrt`` or ``log``: a width
#: ``sigma = lam^-1/2`` of at most 1e6 radians, a lobe wider than any sphere.
SHARPNESS_MIN = 1e-12

#: Floor of a physical magnitude used as a divisor (a range of heights, a peak radiance, a
#: length) where it is a scale of the data, not a density: small against any real scale,
#: large enough that dividing by it stays finite in float32.
SMALL = 1e-12

#: Relative round-off allowance of a float64 comparison: a value within this fraction of a
#: bound counts as at it (float64's epsilon is 2.2e-16, so it allows a few thousand ulps).
REL_F64 = 1e-12
