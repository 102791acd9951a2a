"""BRDFs as spherical-Gaussian mixtures fitted by EM, rendered with prefiltered lighting.

The second of lobelight's methods (SG mixtures of BRDFs fitted by EM): for a set of fixed view
directions ``o_j`` in the tangent frame, ``rho(i, o_j) (n.i)`` is fitted once per material as a
mixture of ``N`` (8) spherical Gaussians; at render time each pixel interpolates the lobes for
its view, rotates them to the world and integrates each against the environment in one lookup.
No visibility is precomputed, so scenes may change freely.

EM for von Mises-Fisher mixtures (:mod:`._em`), batched over independent problems
    - :func:`em_fit` ``(dirs (..., S, 3), weights (..., S) | None, *, n_lobes, init, max_iter,
      tol, kappa_solver, prior, prior_strength) -> VMFMixture`` (``mu (..., N, 3)``,
      ``kappa (..., N)``, ``alpha (..., N)``, ``loglik``, ``iterations``)
    - :func:`init_paper` the paper's initial guess;  :func:`kappa_from_gap` the concentration
      from ``1 - r`` (exact or Banerjee's approximation);  :func:`sample_mixture` exact draws

Fitting materials (:mod:`._fit`)
    - :func:`fit` ``(brdf, *, n_lobes=8, layout=None, n_views=16, samples=4096,
      coherent=True, ...) -> SGBRDF``; ``SGBRDF.params`` is the ``(M, N, 7)`` texture
      ``(w_rgb, mu_xyz, kappa)`` indexed by (view, lobe); ``SGBRDF.lobes(o)`` interpolates.
    - view sets: :func:`elevation_views` (isotropic), :func:`geodesic_tangent_views`
    - coherence: :func:`view_jump`, :func:`match_components`, :func:`view_transport`
    - accuracy: :func:`mixture_error`, :func:`fit_error`, :func:`interpolation_error`
    - :func:`fit_many` ``(brdfs, **fit options) -> list[SGBRDF]``: several materials in one
      batched EM (materials sharing a view layout share the sweep)

Rendering (:mod:`._render`)
    - :func:`shade` ``(model, lighting, normals, views, *, tangents=None) -> (..., 3)`` with
      ``lighting`` a :class:`lobelight.envmap.Prefiltered` (exact, default choice) or a
      :class:`MipChain` from :func:`mip_chain` (the paper's eq. 10)
    - :func:`render_sphere` ``(model, lighting, *, width, height, camera, background) ->
      (image, mask)``; :func:`sphere_hits` the rays and surface frames it shades

Baselines and the paper's comparison (docs/sgbrdf.md)
    - :func:`shade_fis` ``(brdf, chain, normals, views, *, tangents, samples=40) -> (..., 3)``
      filtered importance sampling (Colbert & Křivánek 2007) on a :class:`MipChain`;
      :func:`hammersley` its point set
    - :func:`shade_wang09` ``(ward, lighting, normals, views) -> (..., 3)`` the single warped
      SG lobe of Wang et al. 2009; :func:`wang09_lobe` the lobe itself

Elsewhere: the Monte Carlo reference (MIS of BRDF and environment sampling) is
:func:`lobelight.reference.sgbrdf.shade_reference`; the comparison of every method per material
(PSNR, relative L2, fps, image grid, ``compare-brdf.json``) is
:func:`lobelight.studies.compare_brdf.compare_brdf`; the fit's timing is
:func:`lobelight.bench.brdf_fit.bench_brdf_fit`.
"""

from ._em import (
    KAPPA_MAX,
    KAPPA_MIN,
    VMFMixture,
    em_fit,
    init_paper,
    kappa_from_gap,
    log_vmf_normalization,
    sample_mixture,
    vmf_log_pdf,
)
from ._fis import FIS_SAMPLES, hammersley, shade_fis
from ._fit import (
    FIT_SAMPLES,
    SGBRDF,
    brdf_samples,
    elevation_views,
    fit,
    fit_error,
    fit_many,
    geodesic_tangent_views,
    interpolation_error,
    is_isotropic,
    match_components,
    mixture_error,
    view_jump,
    view_transport,
)
from ._render import (
    COVERAGE,
    MipChain,
    mip_chain,
    normals_and_views,
    render_sphere,
    shade,
    sphere_hits,
)
from ._wang09 import shade_wang09, wang09_lobe

__all__ = [
    "COVERAGE",
    "FIS_SAMPLES",
    "FIT_SAMPLES",
    "KAPPA_MAX",
    "KAPPA_MIN",
    "SGBRDF",
    "MipChain",
    "VMFMixture",
    "brdf_samples",
    "elevation_views",
    "em_fit",
    "fit",
    "fit_error",
    "fit_many",
    "geodesic_tangent_views",
    "hammersley",
    "init_paper",
    "interpolation_error",
    "is_isotropic",
    "kappa_from_gap",
    "log_vmf_normalization",
    "match_components",
    "mip_chain",
    "mixture_error",
    "normals_and_views",
    "render_sphere",
    "sample_mixture",
    "shade",
    "shade_fis",
    "shade_wang09",
    "sphere_hits",
    "view_jump",
    "view_transport",
    "vmf_log_pdf",
    "wang09_lobe",
]
