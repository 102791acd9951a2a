"""lobelight: real-time, all-frequency relighting with spherical lobes.

Modules follow the pipeline (conventions: docs/conventions.md):

- :mod:`lobelight.sphere`   directions: the 92 geodesic views, Fibonacci and local sets, rotations
- :mod:`lobelight.cubemap`  cube-map texel directions, exact solid angles, seamless sampling
- :mod:`lobelight.sg`       spherical Gaussians ``G(w; mu, lam) = exp(lam (mu.w - 1))``
- :mod:`lobelight.sh`       real orthonormal spherical harmonics up to order 10 and rotation
- :mod:`lobelight.haar`     Haar wavelets on cube maps (the Ng 2003 baseline)
- :mod:`lobelight.envmap`   environment maps: load/save, built-in sky, Gaussian-prefiltered chain
"""

__version__ = "0.1.0"
