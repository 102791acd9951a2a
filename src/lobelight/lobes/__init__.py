"""Bases on the sphere that the methods fit and integrate.

- :mod:`lobelight.lobes.sg`    spherical Gaussians ``G(w; mu, lam) = exp(lam (mu.w - 1))``: the
  Gaussians record (:class:`~lobelight.lobes.sg.Gaussians`) and the one integral
- :mod:`lobelight.lobes.sh`    real orthonormal spherical harmonics of any order: evaluation,
  projection, rotation and zonal convolution
- :mod:`lobelight.lobes.haar`  Haar wavelets on cube maps (the all-frequency baseline of the
  view-dependent PRT paper's Figure 5)

Cosine lobes, which carry their own product tables, live with their method in
:mod:`lobelight.cosine`.
"""
