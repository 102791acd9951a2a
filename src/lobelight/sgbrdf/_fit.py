"""Fitting ``rho(i, o_j) (n.i)`` at fixed views as mixtures of spherical Gaussians.

View sets (tangent frame: ``x`` = tangent, ``y`` = bitangent, ``z`` = normal)
    ``"elevation"`` (default for isotropic materials): ``M`` views (16 by default) in the
    ``xz`` half-plane, ``o_j = (sin theta_j, 0, cos theta_j)`` with ``theta_j`` uniform in
    ``[0, 88]`` degrees. An isotropic BRDF depends on the azimuth of ``o`` only through a
    rotation about the normal, so a view of azimuth ``phi`` uses the lobes interpolated
    linearly in ``theta`` (clamped to the table), turned by ``phi`` about ``z``.

    ``"geodesic"`` (default for anisotropic materials): the 92 views of
    :func:`lobelight.geometry.sphere.geodesic_views` with their +Y axis mapped to the normal, i.e.
    local ``(x, y, z) = (g_z, g_x, g_y)`` (a cyclic permutation, so right-handed); interpolation is
    barycentric in the geodesic triangle (:func:`lobelight.geometry.sphere.locate_views`). The
    views of triangles that reach above the horizon are fitted (61 of 92); the 15 of them below the
    horizon are fitted at their azimuth on the elevation layout's last elevation (88 degrees),
    so that directions near grazing interpolate towards the grazing BRDF rather than towards
    zero. The 31 views no direction above the horizon can reach get weight 0 (and a copy of the
    nearest fitted view's means and sharpness).

Parameter layout (a texture indexed by (view, lobe), the paper's sec. V)
    ``params[j, k] = (w_r, w_g, w_b, mu_x, mu_y, mu_z, kappa)``, ``(M, N, 7)`` float32: view
    ``j``'s lobe ``k`` is the spherical Gaussian ``w exp(kappa (mu.i - 1))`` (conventions: peak
    ``w``, sharpness ``kappa`` = the vMF concentration), ``mu`` a unit vector in the tangent
    frame, so ``rho(i, o_j) (n.i) ~ sum_k w_jk G(i; mu_jk, kappa_jk)`` per RGB channel.
    With ``A_j`` the directional albedo and ``alpha_jk`` the EM mixture weights,
    ``w_jk = A_j alpha_jk C(kappa_jk)``, ``C`` the vMF normalisation: the mixture integrates
    to exactly ``A_j`` per channel.

Samples (weighted EM)
    Per view, ``S`` (4096) directions from the BRDF's own importance sampling
    (:meth:`lobelight.brdf.BRDF.sample`) driven by a deterministic Fibonacci lattice in the
    unit square, with weights ``f cos / pdf`` (their mean is the albedo ``A_j`` per channel,
    their channel mean the EM weight). Importance sampling puts the directions where the lobe
    lives at any roughness, so no grid has to be sized to it.

Coherence across views (beyond the paper)
    The paper fits each view on its own from its own initial guess, so neighbouring views may
    describe the same lobe with differently arranged components and the parameters cannot be
    interpolated. ``coherent=True`` instead sweeps the views outward from the normal (the
    elevation order, or breadth-first over the geodesic mesh): the first view gets the paper's
    initialisation; every later view starts from its fitted parent (its nearest neighbour one
    step closer to the normal), with the lobe means carried along by the rotation that takes
    the parent's mirror direction to the view's (:func:`view_transport`), so component ``k``
    describes the same part of the lobe in every view. Each view's independent fit is the
    other candidate, its lobes re-paired to the transported parent's
    (:func:`match_components`): the continued fit is kept only where it fits the view's own
    samples at least 5 % better (``CONTINUATION_MARGIN``; it does where EM from the paper's
    start gets stuck, e.g. near-round lobes near normal incidence), otherwise the re-paired
    independent fit is taken (where both fit alike, the independent fits of neighbouring views
    tend to agree with each other better than continuations along different paths of the
    sweep). Either way a view's error on its samples is at most its independent fit's, so
    coherence costs no fit quality. Optionally (``prior_strength > 0``) a MAP prior
    (:func:`em_fit`'s ``prior``) also pulls each lobe towards its transported parent; it
    lowers the mean jump between neighbouring views a little but raises the worst jump and the
    fit error, so it is off by default.
    :func:`view_jump` measures the result.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Any

import torch

from .._checks import check_directions, check_int
from .._tol import DIVISOR_F32, DIVISOR_F64, REL_F64
from ..brdf import BRDF
from ..errors import InputError
from ..geometry import sphere
from ..lobes.sg import evaluate_mixture, integral
from ._em import (
    KAPPA_MIN,
    em_fit,
    log_vmf_normalization,
    sample_mixture,
    vmf_log_pdf,
)

__all__ = [
    "SGBRDF",
    "elevation_views",
    "fit",
    "fit_error",
    "fit_many",
    "geodesic_tangent_views",
    "interpolation_error",
    "is_isotropic",
    "match_components",
    "mixture_error",
    "view_jump",
    "view_transport",
]

#: Views of the elevation layout, and its last elevation (degrees).
N_ELEVATIONS = 16
THETA_MAX_DEG = 88.0
#: Geodesic views below the horizon are fitted at this height (the elevation layout's last).
FOLD_Z = math.cos(math.radians(THETA_MAX_DEG))
#: Samples per view and EM settings of :func:`fit`.
FIT_SAMPLES = 4096
MAX_ITER = 300
TOL = 1e-6
PRIOR_STRENGTH = 0.0
#: The continued fit of a view is kept only where its in-sample error is this much (relative)
#: below the independent fit's; elsewhere the independent fit, re-paired, is taken.
CONTINUATION_MARGIN = 0.05


# --------------------------------------------------------------------------------------------
# view sets


def elevation_views(
    n_views: int = N_ELEVATIONS,
    *,
    theta_max_deg: float = THETA_MAX_DEG,
    dtype: torch.dtype = torch.float32,
    device: Any = None,
) -> torch.Tensor:
    """``(M, 3)`` views ``(sin theta_j, 0, cos theta_j)``, ``theta_j`` uniform in
    ``[0, theta_max]``, in the tangent frame (module docstring)."""
    n_views = check_int(n_views, "n_views", minimum=2)
    th = torch.linspace(0.0, math.radians(theta_max_deg), n_views, dtype=torch.float64)
    v = torch.stack([th.sin(), torch.zeros_like(th), th.cos()], -1)
    return v.to(dtype=dtype, device=device)


def geodesic_tangent_views(*, dtype: torch.dtype = torch.float32, device: Any = None):
    """The 92 geodesic views in the tangent frame, ``(92, 3)``: ``(g_z, g_x, g_y)``."""
    g = sphere.geodesic_views(dtype=dtype, device=device)
    return g[:, [2, 0, 1]]


def _to_geodesic(v: torch.Tensor) -> torch.Tensor:
    """Tangent-frame ``(x, y, z)`` -> geodesic frame ``(y, z, x)`` (inverse of the above)."""
    return v[..., [1, 2, 0]]


@functools.lru_cache(maxsize=1)
def _geodesic_used() -> tuple[torch.Tensor, torch.Tensor]:
    """Views of triangles reaching above the horizon (92,) bool, and those triangles' edges."""
    views = geodesic_tangent_views(dtype=torch.float64)
    faces = sphere.geodesic_faces()  # (180, 3)
    up = (views[faces][..., 2] > 0).any(-1)  # (180,) a triangle with no vertex above is below
    used_faces = faces[up]
    used = torch.zeros(92, dtype=torch.bool)
    used[used_faces.reshape(-1)] = True
    pairs = torch.cat([used_faces[:, [0, 1]], used_faces[:, [1, 2]], used_faces[:, [2, 0]]])
    edges = torch.unique(torch.sort(pairs, dim=1).values, dim=0)
    return used, edges


def _fold(views: torch.Tensor, z_min: float) -> torch.Tensor:
    """Directions with ``z < z_min`` lowered (raised) onto ``z = z_min`` at the same azimuth."""
    xy = views[..., :2]
    r = torch.linalg.vector_norm(xy, dim=-1, keepdim=True)
    x_hat = torch.zeros_like(xy)
    x_hat[..., 0] = 1
    dir_xy = torch.where(r > 1e-9, xy / r.clamp_min(DIVISOR_F32), x_hat)
    folded = torch.cat([dir_xy * math.sqrt(1 - z_min * z_min), torch.full_like(r, z_min)], -1)
    return torch.where(views[..., 2:] < z_min, folded, views)


def _mirror(v: torch.Tensor) -> torch.Tensor:
    return v * torch.tensor([-1.0, -1.0, 1.0], dtype=v.dtype, device=v.device)


def view_transport(v_from: torch.Tensor, v_to: torch.Tensor) -> torch.Tensor:
    """Rotation carrying the lobes of view ``v_from`` to where they belong at view ``v_to``:
    the minimal rotation taking the mirror direction ``(-x, -y, z)`` of ``v_from`` to that of
    ``v_to`` (parallel transport along the great circle between them, no twist).

    Parameters
    ----------
    v_from, v_to : (..., 3) unit views, tangent frame

    Returns
    -------
    (..., 3, 3)
    """
    return sphere.rotation_between(_mirror(v_from), _mirror(v_to))


def is_isotropic(brdf: BRDF) -> bool:
    """Whether ``brdf`` is invariant under rotations about the normal (its lobes only depend on
    the elevation of the view): :attr:`lobelight.brdf.BRDF.isotropic`."""
    return brdf.isotropic


# --------------------------------------------------------------------------------------------
# samples


def _frame_tensors(like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    n = torch.tensor([0.0, 0.0, 1.0], dtype=like.dtype, device=like.device)
    t = torch.tensor([1.0, 0.0, 0.0], dtype=like.dtype, device=like.device)
    return n, t


def brdf_samples(brdf: BRDF, views: torch.Tensor, /, *, samples: int = FIT_SAMPLES):
    """Importance samples of ``rho(., o_j) cos`` for each view (module docstring).

    Parameters
    ----------
    brdf : the material;  views : (M, 3) unit view directions in the tangent frame

    Returns
    -------
    dirs : (M, S, 3) sampled directions;  values : (M, S, 3) ``f cos / pdf`` (0 for samples
    the model rejects); the per-channel mean of ``values`` over ``S`` is the albedo estimate;
    pdf : (M, S) sampling density (0 for rejected samples)
    """
    samples = check_int(samples, "samples", minimum=1)
    n, t = _frame_tensors(views)
    u = sphere.fibonacci_lattice(samples, dtype=views.dtype, device=views.device)  # (S, 2)
    return brdf.sample(views.unsqueeze(1), n, u.unsqueeze(0), t)  # (M, S, 3), (M, S, 3), (M, S)


# --------------------------------------------------------------------------------------------
# the fitted model


@dataclass
class SGBRDF:
    """A material as spherical-Gaussian mixtures at fixed views (module docstring).

    Attributes
    ----------
    params : (M, N, 7) float32 ``(w_rgb, mu_xyz, kappa)`` per (view, lobe), tangent frame
    views : (M, 3) interpolation nodes (view directions, tangent frame)
    fit_views : (M, 3) directions each view was fitted at (``views`` folded to the horizon)
    layout : "elevation" or "geodesic"
    albedo : (M, 3) directional albedo at ``fit_views`` (the samples' mean)
    used : (M,) bool, views that were fitted (unused ones have weight 0)
    material : the BRDF's :meth:`~lobelight.brdf.BRDF.to_dict`
    loglik : (M,) EM log-likelihood per view;  iterations : (M,) EM iterations per view
    """

    params: torch.Tensor
    views: torch.Tensor
    fit_views: torch.Tensor
    layout: str
    albedo: torch.Tensor
    used: torch.Tensor
    material: dict = field(default_factory=dict)
    loglik: torch.Tensor | None = None
    iterations: torch.Tensor | None = None

    @property
    def n_lobes(self) -> int:
        return int(self.params.shape[1])

    @property
    def weight(self) -> torch.Tensor:
        """(M, N, 3) RGB peak weights."""
        return self.params[..., 0:3]

    @property
    def mu(self) -> torch.Tensor:
        """(M, N, 3) unit lobe means, tangent frame."""
        return self.params[..., 3:6]

    @property
    def kappa(self) -> torch.Tensor:
        """(M, N) sharpness."""
        return self.params[..., 6]

    @property
    def edges(self) -> torch.Tensor:
        """(E, 2) int64 neighbouring view pairs: consecutive elevations, or the geodesic mesh
        edges between fitted views."""
        return _default_edges(self.views, self.layout)

    def to(self, device: Any) -> SGBRDF:
        """A copy with every tensor on ``device``."""
        kw = {
            k: (v.to(device) if isinstance(v, torch.Tensor) else v) for k, v in vars(self).items()
        }
        return SGBRDF(**kw)

    def lobes(self, o: Any, /) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The lobes for view directions ``o`` (tangent frame), interpolated between views.

        Interpolated per lobe index: lobe mass (the integral ``w Z(kappa)``, so the mixture's
        integral, the albedo, interpolates linearly), ``log kappa``, and the mean (normalised
        after the blend). Elevation layout: linear in ``theta`` between the two nearest views
        (clamped to the table), then turned by the azimuth of ``o``; geodesic layout:
        barycentric in the geodesic triangle. Views with ``o_z <= 0`` get weight 0.

        Parameters
        ----------
        o : (..., 3) unit view directions, tangent frame

        Returns
        -------
        mu : (..., N, 3) unit means, tangent frame;  kappa : (..., N);  weight : (..., N, 3)
        """
        o = torch.as_tensor(o, device=self.params.device)
        check_directions(o, "o")
        o = o.to(self.params.dtype)
        shape = o.shape[:-1]
        q = o.reshape(-1, 3)  # (Q, 3)
        if self.layout == "elevation":
            idx, bary = _elevation_weights(self.views, q)  # (Q, 2) each
        else:
            idx, bary = sphere.locate_views(_to_geodesic(q))  # (Q, 3) each
        p = self.params[idx]  # (Q, K, N, 7)
        b = bary.unsqueeze(-1)  # (Q, K, 1)
        kap = p[..., 6].clamp_min(KAPPA_MIN)  # (Q, K, N)
        mass = p[..., 0:3] * integral(kap).unsqueeze(-1)  # (Q, K, N, 3)
        mass = (b.unsqueeze(-1) * mass).sum(1)  # (Q, N, 3)
        kappa = torch.exp((b * kap.log()).sum(1))  # (Q, N)
        mu = torch.nn.functional.normalize((b.unsqueeze(-1) * p[..., 3:6]).sum(1), dim=-1)
        if self.layout == "elevation":
            phi = torch.atan2(q[:, 1], q[:, 0])  # (Q,)
            c, s = phi.cos().unsqueeze(-1), phi.sin().unsqueeze(-1)
            mu = torch.stack(
                [c * mu[..., 0] - s * mu[..., 1], s * mu[..., 0] + c * mu[..., 1], mu[..., 2]], -1
            )
        weight = mass / integral(kappa).unsqueeze(-1)
        weight = torch.where((q[:, 2] > 0).view(-1, 1, 1), weight, torch.zeros_like(weight))
        n = self.n_lobes
        return mu.reshape(*shape, n, 3), kappa.reshape(*shape, n), weight.reshape(*shape, n, 3)

    def evaluate(self, wi: Any, o: Any, /) -> torch.Tensor:
        """The fitted ``rho(wi, o) (n.wi)``: ``(..., 3)`` for ``wi (..., S, 3)``, ``o (..., 3)``
        in the tangent frame (the mixture, interpolated between views)."""
        mu, kappa, weight = self.lobes(o)
        wi = torch.as_tensor(wi, device=self.params.device).to(self.params.dtype)
        return evaluate_mixture(wi, mu.unsqueeze(-3), kappa.unsqueeze(-2), weight.unsqueeze(-3))


def _elevation_weights(views: torch.Tensor, q: torch.Tensor):
    """Indices (Q, 2) and linear weights (Q, 2) in ``theta`` for the elevation layout."""
    th_views = torch.atan2(torch.linalg.vector_norm(views[:, :2], dim=-1), views[:, 2])  # (M,)
    th = torch.atan2(torch.linalg.vector_norm(q[:, :2], dim=-1), q[:, 2])  # (Q,)
    th = th.clamp(float(th_views[0]), float(th_views[-1]))
    j1 = torch.searchsorted(th_views.contiguous(), th.contiguous()).clamp(1, len(th_views) - 1)
    j0 = j1 - 1
    t = ((th - th_views[j0]) / (th_views[j1] - th_views[j0])).clamp(0, 1)
    return torch.stack([j0, j1], -1), torch.stack([1 - t, t], -1)


def _default_edges(views: torch.Tensor, layout: str) -> torch.Tensor:
    if layout == "geodesic":
        return _geodesic_used()[1].to(views.device)
    m = views.shape[0]
    i = torch.arange(m - 1, device=views.device)
    return torch.stack([i, i + 1], -1)


# --------------------------------------------------------------------------------------------
# fitting


def fit(
    brdf: BRDF,
    /,
    *,
    n_lobes: int = 8,
    layout: str | None = None,
    n_views: int = N_ELEVATIONS,
    samples: int = FIT_SAMPLES,
    coherent: bool = True,
    prior_strength: float = PRIOR_STRENGTH,
    max_iter: int = MAX_ITER,
    tol: float = TOL,
    kappa_solver: str = "exact",
    device: Any = "cpu",
) -> SGBRDF:
    """Fit a material's ``rho(i, o_j) (n.i)`` as ``n_lobes`` spherical Gaussians per view.

    Parameters
    ----------
    brdf : the material (any :class:`lobelight.brdf.BRDF` with scalar parameters)
    n_lobes : lobes per view ``N >= 1`` (the paper uses 8)
    layout : "elevation" or "geodesic"; default "elevation" for isotropic materials
        (:func:`is_isotropic`) and "geodesic" otherwise
    n_views : views of the elevation layout (``>= 2``; the geodesic layout has its 92)
    samples : importance samples per view
    coherent : sweep the views outward, each continued from its parent, keeping the
        independent fit where it is better (module docstring); False fits every view
        independently from the paper's initialisation, as the paper does
    prior_strength : weight of the optional neighbour prior, as a fraction of each view's data
        (0: off, the default)
    max_iter, tol, kappa_solver : EM settings (:func:`lobelight.sgbrdf.em_fit`)
    device : torch device of the computation and of the result

    Returns
    -------
    SGBRDF
    """
    return fit_many(
        [brdf],
        n_lobes=n_lobes,
        layout=layout,
        n_views=n_views,
        samples=samples,
        coherent=coherent,
        prior_strength=prior_strength,
        max_iter=max_iter,
        tol=tol,
        kappa_solver=kappa_solver,
        device=device,
        _name="brdf",
    )[0]


def fit_many(
    brdfs: Any,
    /,
    *,
    n_lobes: int = 8,
    layout: str | None = None,
    n_views: int = N_ELEVATIONS,
    samples: int = FIT_SAMPLES,
    coherent: bool = True,
    prior_strength: float = PRIOR_STRENGTH,
    max_iter: int = MAX_ITER,
    tol: float = TOL,
    kappa_solver: str = "exact",
    device: Any = "cpu",
    _name: str = "brdfs",
) -> list[SGBRDF]:
    """Fit several materials at once: :func:`fit` of each, with the EM of all materials that
    share a view layout run as one batch (one sweep over the views for all of them).

    Parameters
    ----------
    brdfs : sequence of materials with scalar parameters
    n_lobes, layout, n_views, samples, coherent, prior_strength, max_iter, tol,
        kappa_solver, device : as for :func:`fit` (``layout`` None picks per material)

    Returns
    -------
    list of SGBRDF, one per material in order; each equals ``fit`` of that material (EM stops
    per problem, so batching does not change a result)
    """
    if isinstance(brdfs, BRDF) or not isinstance(brdfs, (list, tuple)) or not brdfs:
        raise InputError(_name, "must be a non-empty list of lobelight.brdf.BRDF materials")
    names = [_name if _name == "brdf" else f"{_name}[{i}]" for i in range(len(brdfs))]
    for nm, brdf in zip(names, brdfs, strict=True):
        if not isinstance(brdf, BRDF):
            raise InputError(nm, f"must be a lobelight.brdf.BRDF, got {type(brdf).__name__}")
        per_element = brdf.per_element_params
        if per_element:
            raise InputError(
                f"{nm}.{per_element[0]}", "must be a single value (fit one material at a time)"
            )
    n = check_int(n_lobes, "n_lobes", minimum=1)
    layouts = []
    for brdf in brdfs:
        lay = layout if layout is not None else ("elevation" if is_isotropic(brdf) else "geodesic")
        if lay not in ("elevation", "geodesic"):
            raise InputError("layout", f"must be 'elevation' or 'geodesic', got {lay!r}")
        if lay == "elevation" and not is_isotropic(brdf):
            raise InputError("layout", "the elevation layout needs an isotropic material")
        layouts.append(lay)
    dev = torch.device(device)
    out: list[SGBRDF | None] = [None] * len(brdfs)
    em_kw = {"n_lobes": n, "max_iter": max_iter, "tol": tol, "kappa_solver": kappa_solver}
    for lay in ("elevation", "geodesic"):
        idx = [i for i, la in enumerate(layouts) if la == lay]
        if not idx:
            continue
        group = [brdfs[i].to(dev) for i in idx]
        for i, model in zip(
            idx,
            _fit_group(group, lay, n_views, samples, coherent, prior_strength, em_kw, dev),
            strict=True,
        ):
            out[i] = model
    return out  # type: ignore[return-value]


def _fit_group(brdfs, layout, n_views, samples, coherent, prior_strength, em_kw, dev):
    """Materials sharing one view layout, fitted as one batch ``(U views, B materials)``."""
    if layout == "elevation":
        views = elevation_views(n_views, device=dev)
        used = torch.ones(views.shape[0], dtype=torch.bool, device=dev)
        fit_views = views
    else:
        views = geodesic_tangent_views(device=dev)
        used = _geodesic_used()[0].to(dev)
        fit_views = _fold(views, FOLD_Z)
    sel = used.nonzero().squeeze(-1)  # (U,)
    per = [brdf_samples(b, fit_views[sel], samples=samples) for b in brdfs]  # B x (U, S, ...)
    dirs, values, pdf = (torch.stack(x, 1) for x in zip(*per, strict=True))  # (U, B, S, ...)
    albedo_u = values.mean(2)  # (U, B, 3)
    w = values.mean(-1).clamp_min(0)  # (U, B, S) EM weights
    if coherent:
        parent, depth = _sweep_order(fit_views[sel], layout, sel)
        res = _sweep(dirs, w, pdf, fit_views[sel], parent, depth, em_kw, prior_strength)
    else:
        r = em_fit(dirs, w, **em_kw)
        res = (r.mu, r.kappa, r.alpha, r.loglik, r.iterations)
    mu_u, kappa_u, alpha_u, ll_u, it_u = res  # (U, B, N, ...)
    weight_u = albedo_u.unsqueeze(2) * (alpha_u * log_vmf_normalization(kappa_u).exp()).unsqueeze(
        -1
    )  # (U, B, N, 3)
    # every view: unused ones copy the nearest fitted view's lobes with weight 0
    near = (fit_views @ fit_views[sel].T).argmax(-1)  # (M,) index into sel
    params_all = torch.cat([weight_u, mu_u, kappa_u.unsqueeze(-1)], -1)[near]  # (M, B, N, 7)
    models = []
    for j, brdf in enumerate(brdfs):
        params = params_all[:, j].clone()
        params[~used, :, 0:3] = 0
        models.append(
            SGBRDF(
                params=params.to(torch.float32).contiguous(),
                views=views,
                fit_views=fit_views,
                layout=layout,
                albedo=albedo_u[near, j] * used.unsqueeze(-1),
                used=used,
                material=brdf.to_dict(),
                loglik=ll_u[near, j],
                iterations=it_u[near, j],
            )
        )
    return models


def _sweep_order(fit_views: torch.Tensor, layout: str, sel: torch.Tensor):
    """Parent (U,) (-1 for the root) and depth (U,) of each fitted view in the sweep."""
    u = fit_views.shape[0]
    if layout == "elevation":
        idx = torch.arange(u, device=fit_views.device)
        return idx - 1, idx
    # breadth-first over the geodesic mesh from the normal (view 0), among fitted views
    pos = {int(v): i for i, v in enumerate(sel.tolist())}
    nbrs = sphere.geodesic_neighbors()
    depth = [-1] * u
    parent = [-1] * u
    depth[pos[0]] = 0
    frontier = [pos[0]]
    fv = fit_views.detach().cpu().double()
    while frontier:
        nxt = []
        for i in frontier:
            for v in nbrs[int(sel[i])]:
                j = pos.get(v)
                if j is not None and depth[j] < 0:
                    depth[j] = depth[i] + 1
                    nxt.append(j)
        for j in nxt:  # parent: the nearest neighbour one step closer to the normal
            cands = [
                pos[v] for v in nbrs[int(sel[j])] if v in pos and depth[pos[v]] == depth[j] - 1
            ]
            parent[j] = max(cands, key=lambda c: float(fv[c] @ fv[j]))
        frontier = nxt
    dev = fit_views.device
    return torch.tensor(parent, device=dev), torch.tensor(depth, device=dev)


def _sample_error(x, w, pdf, mu, kappa, alpha) -> torch.Tensor:
    """In-sample relative L2 error of ``A sum_k alpha_k g_k`` against ``f cos = w pdf`` (grey),
    ``A = mean(w)``, from the fit's own importance samples: ``x (..., S, 3)``, ``w, pdf (...,
    S)``, mixture ``(..., N, ...)`` -> ``(...)``. Used to choose between candidate fits."""
    x, w, q = x.double(), w.double(), pdf.double()
    logp = vmf_log_pdf(x.unsqueeze(-2), mu.double().unsqueeze(-3), kappa.double().unsqueeze(-2))
    mix = (alpha.double().unsqueeze(-2) * logp.exp()).sum(-1) * w.mean(-1, keepdim=True)
    f = w * q  # (..., S)
    inv = torch.where(q > 0, 1 / q.clamp_min(DIVISOR_F64), torch.zeros_like(q))
    return torch.sqrt(((mix - f) ** 2 * inv).sum(-1) / (f * f * inv).sum(-1).clamp_min(DIVISOR_F64))


def _sweep(dirs, w, pdf, fit_views, parent, depth, em_kw, prior_strength):
    """Fit views wave by wave (one depth = one batch), each from its transported parent.

    Every view also has its independent fit (the paper's initialisation, all views in one
    batch). The continued fit is kept where its in-sample error (:func:`_sample_error`) is at
    least ``CONTINUATION_MARGIN`` below the independent one's; elsewhere the independent fit is
    taken, its lobes relabelled to match the transported parent's (:func:`match_components`).
    The sweep continues from whichever was taken, so one labelling runs through all views and
    no view fits its samples worse than its independent fit.

    Shapes: the view index is the first axis (``dirs (U, [B,] S, 3)``, ``w, pdf (U, [B,] S)``,
    ``fit_views (U, 3)``); an optional second axis ``B`` batches materials that share the views.
    """
    indep = em_fit(dirs, w, **em_kw)
    err_ind = _sample_error(dirs, w, pdf, indep.mu, indep.kappa, indep.alpha)  # (U,)
    mu, kappa, alpha = indep.mu.clone(), indep.kappa.clone(), indep.alpha.clone()
    ll, iters = indep.loglik.clone(), indep.iterations.clone()
    for d in range(1, int(depth.max()) + 1):
        sel = (depth == d).nonzero().squeeze(-1)
        par = parent[sel]
        rot = view_transport(fit_views[par], fit_views[sel])  # (m, 3, 3)
        rot = rot.reshape(rot.shape[0], *[1] * (mu.ndim - 2), 3, 3)  # (m, [B,] 1, 3, 3)
        mu0 = (rot @ mu[par].unsqueeze(-1)).squeeze(-1)  # (m, [B,] N, 3)
        start = (mu0, kappa[par], alpha[par])
        prior = start if prior_strength > 0 else None
        r = em_fit(
            dirs[sel], w[sel], init=start, prior=prior, prior_strength=prior_strength, **em_kw
        )
        err = _sample_error(dirs[sel], w[sel], pdf[sel], r.mu, r.kappa, r.alpha)  # (m, [B])
        perm = match_components(
            mu0, kappa[par], alpha[par], indep.mu[sel], indep.kappa[sel], indep.alpha[sel]
        )  # (m, [B,] N)
        take = (err_ind[sel] < err * (1 + CONTINUATION_MARGIN)).unsqueeze(-1)  # (m, [B,] 1)
        mu_i = indep.mu[sel].gather(-2, perm.unsqueeze(-1).expand(*perm.shape, 3))
        mu[sel] = torch.where(take.unsqueeze(-1), mu_i, r.mu)
        kappa[sel] = torch.where(take, indep.kappa[sel].gather(-1, perm), r.kappa)
        alpha[sel] = torch.where(take, indep.alpha[sel].gather(-1, perm), r.alpha)
        ll[sel] = torch.where(take[..., 0], indep.loglik[sel], r.loglik)
        iters[sel] = iters[sel] + r.iterations
    return mu, kappa, alpha, ll, iters


# --------------------------------------------------------------------------------------------
# coherence measure


def match_components(
    mu_a: torch.Tensor,
    kappa_a: torch.Tensor,
    alpha_a: torch.Tensor,
    mu_b: torch.Tensor,
    kappa_b: torch.Tensor,
    alpha_b: torch.Tensor,
) -> torch.Tensor:
    """Matching of the lobes of mixture ``b`` to those of mixture ``a``, batched.

    The cost of pairing lobe ``i`` of ``a`` with lobe ``j`` of ``b`` is the squared
    2-Wasserstein distance of the lobes as small-angle 2-D Gaussians, ``theta^2 + 2 (s_i -
    s_j)^2`` (``theta`` the angle between the means, ``s = 1/sqrt(kappa)`` the widths), times
    the pair's mean weight ``(alpha_i + alpha_j) / 2``. Unlike an L2 distance it keeps growing
    with the angle after two lobes stop overlapping, so a chain of lobes that shifts along
    itself between views is paired in order. The assignment minimising the summed cost is
    sought by a greedy pass (cheapest remaining pair first) and then pairwise exchanges (swap
    the partners of two lobes while that lowers the sum: the greedy pass alone can be forced
    into a bad last pair). Loops run over lobes and exchange rounds, vectorised over the batch.

    Parameters
    ----------
    mu_a, mu_b : (..., N, 3);  kappa_a, kappa_b, alpha_a, alpha_b : (..., N)

    Returns
    -------
    (..., N) int64 ``perm`` with lobe ``perm[i]`` of ``b`` matched to lobe ``i`` of ``a``
    """
    n = mu_a.shape[-2]
    f64 = torch.float64
    ma, mb = (
        mu_a.to(f64).unsqueeze(-2),
        mu_b.to(f64).unsqueeze(-3),
    )  # (..., N, 1, 3), (..., 1, N, 3)
    theta = torch.atan2(
        torch.linalg.vector_norm(torch.cross(ma, mb, dim=-1), dim=-1), (ma * mb).sum(-1)
    )  # (..., N, N)
    sa = kappa_a.to(f64).clamp_min(KAPPA_MIN).rsqrt().unsqueeze(-1)
    sb = kappa_b.to(f64).clamp_min(KAPPA_MIN).rsqrt().unsqueeze(-2)
    wab = 0.5 * (alpha_a.to(f64).unsqueeze(-1) + alpha_b.to(f64).unsqueeze(-2))
    cost = wab * (theta * theta + 2 * (sa - sb) ** 2)
    cost = cost.reshape(-1, n, n)  # (B, N, N)
    bsz = cost.shape[0]
    work = cost.clone()
    perm = torch.zeros(bsz, n, dtype=torch.int64, device=cost.device)
    rows = torch.arange(bsz, device=cost.device)
    for _ in range(n):
        flat = work.reshape(bsz, -1).argmin(-1)  # (B,)
        i, j = flat // n, flat % n
        perm[rows, i] = j
        work[rows, i, :] = math.inf
        work[rows, :, j] = math.inf
    for _ in range(n * n):  # pairwise exchanges, best one per problem per round
        cur = cost.gather(2, perm.unsqueeze(-1)).squeeze(-1)  # (B, N) cost[i, perm[i]]
        swapped = cost.gather(2, perm.unsqueeze(1).expand(bsz, n, n))  # [i, i'] = cost[i, perm[i']]
        delta = swapped + swapped.transpose(1, 2) - cur.unsqueeze(-1) - cur.unsqueeze(-2)
        best = delta.reshape(bsz, -1).min(-1)
        better = best.values < -REL_F64 * cost.abs().amax((1, 2))  # (B,)
        if not bool(better.any()):
            break
        i, k = best.indices // n, best.indices % n
        pi, pk = perm[rows, i], perm[rows, k]
        perm[rows, i] = torch.where(better, pk, pi)
        perm[rows, k] = torch.where(better, pi, pk)
    return perm.reshape(*mu_a.shape[:-2], n)


def view_jump(
    params: Any, views: Any, /, *, edges: Any = None, match: bool = False, transport: bool = True
) -> dict[str, float]:
    """How much the lobes jump between neighbouring views.

    For every pair of neighbouring views ``(i, j)`` and lobe index ``k`` (the renderer
    interpolates by index; ``match=True`` pairs lobes by :func:`match_components` first), the
    angle between the means and ``|log(kappa_i / kappa_j)|``, averaged with the weights
    ``(a_ik + a_jk) / 2`` where ``a`` is a lobe's share of its view's integral (so that
    negligible lobes count for little), then over all pairs. With ``transport`` (default) view
    ``i``'s means are first turned by :func:`view_transport` (taking its mirror direction to
    view ``j``'s): a lobe that follows the mirror direction rigidly, as a specular lobe does,
    then counts as no jump, and what is left is the change of arrangement that interpolation
    has to bridge.

    Parameters
    ----------
    params : (M, N, 7) (module docstring);  views : (M, 3) tangent-frame views the lobes were
        fitted at (:attr:`SGBRDF.fit_views`)
    edges : optional (E, 2) neighbour pairs; default for ``M = 92`` the geodesic mesh edges
        between fitted views, else consecutive views (a chain)
    match : pair lobes by geometry rather than by index

    Returns
    -------
    dict with ``angle_deg`` (mean), ``angle_deg_max`` (worst pair, its weighted mean over lobes),
    ``log_kappa`` (mean), ``alpha`` (mean over pairs of ``sum_k |a_ik - a_jk| / 2``, the share of
    the integral that changes lobe), ``edges``
    """
    params = torch.as_tensor(params)
    views = torch.as_tensor(views, device=params.device)
    if params.ndim != 3 or params.shape[-1] != 7:
        raise InputError("params", f"must be (M, N, 7), got shape {tuple(params.shape)}")
    if views.shape != (params.shape[0], 3):
        raise InputError("views", f"must be ({params.shape[0]}, 3), got {tuple(views.shape)}")
    if edges is None:
        edges = _default_edges(views, "geodesic" if views.shape[0] == 92 else "elevation")
    edges = torch.as_tensor(edges, device=params.device).long()
    if edges.ndim != 2 or edges.shape[-1] != 2:
        raise InputError("edges", f"must be (E, 2), got shape {tuple(edges.shape)}")
    p = params.double()
    kap = p[..., 6].clamp_min(KAPPA_MIN)
    mass = p[..., 0:3].mean(-1) * integral(kap)  # (M, N)
    share = mass / mass.sum(-1, keepdim=True).clamp_min(DIVISOR_F64)
    mu = torch.nn.functional.normalize(p[..., 3:6], dim=-1)
    i, j = edges[:, 0], edges[:, 1]
    mu_i, mu_j, k_j, s_j = mu[i], mu[j], kap[j], share[j]
    if transport:
        v = views.double()
        rot = view_transport(v[i], v[j])  # (E, 3, 3)
        mu_i = (rot.unsqueeze(1) @ mu_i.unsqueeze(-1)).squeeze(-1)
    if match:
        perm = match_components(mu_i, kap[i], share[i], mu_j, k_j, s_j)  # (E, N)
        mu_j = mu_j.gather(1, perm.unsqueeze(-1).expand(-1, -1, 3))
        k_j, s_j = k_j.gather(1, perm), s_j.gather(1, perm)
    cross = torch.linalg.vector_norm(torch.cross(mu_i, mu_j, dim=-1), dim=-1)
    ang = torch.atan2(cross, (mu_i * mu_j).sum(-1))  # (E, N)
    dlk = (kap[i].log() - k_j.log()).abs()
    wgt = 0.5 * (share[i] + s_j)  # (E, N)
    wsum = wgt.sum(-1).clamp_min(DIVISOR_F64)
    ang_e = (wgt * ang).sum(-1) / wsum  # (E,)
    dlk_e = (wgt * dlk).sum(-1) / wsum
    da_e = 0.5 * (share[i] - s_j).abs().sum(-1)
    return {
        "angle_deg": math.degrees(float(ang_e.mean())),
        "angle_deg_max": math.degrees(float(ang_e.max())),
        "log_kappa": float(dlk_e.mean()),
        "alpha": float(da_e.mean()),
        "edges": int(edges.shape[0]),
    }


# --------------------------------------------------------------------------------------------
# fit error


def mixture_error(
    brdf: BRDF,
    mu: torch.Tensor,
    kappa: torch.Tensor,
    weight: torch.Tensor,
    views: torch.Tensor,
    /,
    *,
    samples: int = 16384,
    seed: int = 0,
) -> torch.Tensor:
    """Relative L2 error ``||m - f|| / ||f||`` over the sphere of SG mixtures ``m`` against
    ``f = rho(., o) cos`` (channel means), per view.

    Estimated by multiple importance sampling: half the samples from the BRDF's sampling
    routine, half from the mixture itself, combined with the balance heuristic, so that both
    where ``f`` lives and where the mixture puts mass (also below the horizon, where ``f = 0``)
    are resolved at any sharpness. Seeded: the same call gives the same number.

    Parameters
    ----------
    brdf : the material;  mu : (Q, N, 3);  kappa : (Q, N);  weight : (Q, N, 3)
    views : (Q, 3) view directions (tangent frame)

    Returns
    -------
    (Q,) relative errors (float64)
    """
    samples = check_int(samples, "samples", minimum=2)
    dev, dt = mu.device, torch.float64
    mu, kappa, weight, views = (t.to(dt) for t in (mu, kappa, weight, views))
    brdf = brdf.to(dev, dt)
    q, h = views.shape[0], samples // 2
    g = torch.Generator(device="cpu").manual_seed(seed)
    ub = torch.rand(q, h, 2, generator=g, dtype=dt).to(dev)
    um = torch.rand(q, h, 3, generator=g, dtype=dt).to(dev)
    n, t = _frame_tensors(views)
    o = views.unsqueeze(1)  # (Q, 1, 3)
    wi_b, _, pdf_b0 = brdf.sample(o, n, ub, t)  # (Q, h, 3)
    kap = kappa.clamp_min(KAPPA_MIN)
    mass = weight.mean(-1) * integral(kap)  # (Q, N)
    alpha = mass / mass.sum(-1, keepdim=True).clamp_min(DIVISOR_F64)
    wi_m = sample_mixture(mu, kap, alpha, um)  # (Q, h, 3)
    wi = torch.cat([wi_b, wi_m], 1)  # (Q, S, 3)
    valid = torch.cat([pdf_b0 > 0, torch.ones_like(pdf_b0, dtype=torch.bool)], 1)
    p_b = brdf.pdf(wi, o, n, t)  # (Q, S)
    logp = log_vmf_normalization(kap).unsqueeze(1) - 0.5 * kap.unsqueeze(1) * (
        (wi.unsqueeze(2) - mu.unsqueeze(1)) ** 2
    ).sum(-1)  # (Q, S, N)
    p_m = (alpha.unsqueeze(1) * logp.exp()).sum(-1)  # (Q, S)
    dens = 0.5 * (p_b + p_m)
    f = brdf.eval(wi, o, n, t).mean(-1) * wi[..., 2].clamp_min(0)  # (Q, S)
    m = evaluate_mixture(wi, mu.unsqueeze(1), kap.unsqueeze(1), weight.unsqueeze(1)).mean(-1)
    inv = torch.where(valid, 1 / dens.clamp_min(DIVISOR_F64), torch.zeros_like(dens))
    num = ((m - f) ** 2 * inv).mean(-1)
    den = (f * f * inv).mean(-1)
    return torch.sqrt(num / den.clamp_min(DIVISOR_F64))


def fit_error(model: SGBRDF, brdf: BRDF, /, *, samples: int = 16384, seed: int = 0):
    """Relative L2 error of each fitted view's mixture at the direction it was fitted at
    (:func:`mixture_error`); ``(M,)``, NaN for unused views."""
    sel = model.used.nonzero().squeeze(-1)
    err = mixture_error(
        brdf,
        model.mu[sel],
        model.kappa[sel],
        model.weight[sel],
        model.fit_views[sel],
        samples=samples,
        seed=seed,
    )
    out = torch.full((model.params.shape[0],), math.nan, dtype=err.dtype, device=err.device)
    out[sel] = err
    return out


def interpolation_error(
    model: SGBRDF, brdf: BRDF, views: Any, /, *, samples: int = 16384, seed: int = 0
):
    """Relative L2 error of the mixture interpolated at arbitrary view directions
    (:meth:`SGBRDF.lobes`), ``views (Q, 3)`` in the tangent frame -> ``(Q,)``. Between fixed
    views this is what a renderer sees; it exposes lobes that do not interpolate."""
    views = torch.as_tensor(views, device=model.params.device).to(model.params.dtype)
    mu, kappa, weight = model.lobes(views)
    return mixture_error(brdf, mu, kappa, weight, views, samples=samples, seed=seed)
