"""Figure 5 of Green et al. 2006: Gaussians against Haar wavelets and spherical harmonics.

For three transport functions ``T(w) = f_s(w, v) V(w) max(n.w, 0)`` of one vertex and one view
(paper eq. 2), made by :meth:`lobelight.transport.Transport.direct` on a small real scene (a
ground plane and a box, ray cast by :class:`lobelight.geometry.raycast.RayCaster`), this module
measures the relative L2 error

    ``err = sqrt( int (T~ - T)^2 dw / int T^2 dw )``

of three approximations with the same number of coefficients, as the paper counts them
(section 6.3): one Gaussian is stored as seven floats (RGB weight, mean, sigma), so ``K``
Gaussians are set against ``7 K`` Haar coefficients and ``7 K`` spherical-harmonic coefficients
*per colour channel*. The functions are grey (white specular), so one channel carries all of
them; an RGB Haar or SH approximation would store ``3 x 7 K`` numbers (and Haar its ``7 K``
indices besides) against the Gaussians' ``7 K``. That is the paper's generous allotment: it
favours the linear bases.

Functions (:func:`transport_functions`)
---------------------------------------
``a_glossy``  a small symmetric glossy lobe: modified Phong, exponent 300 (lobe width ~3.3
    degrees), view 30 degrees from the normal, nothing in the way.
``b_visibility``  a large lobe cut by visibility: Phong exponent 12 (~17 degrees), view 35
    degrees from the normal, at a ground vertex next to a box whose top edge and front corner
    run through the lobe: a binary, sharp-edged visibility from ray casting.
``c_anisotropic``  a highly anisotropic, highly specular lobe: Ward with ``alpha_x = 0.01``
    (along the tangent, in the plane of incidence) and ``alpha_y = 0.2``, at a grazing-ish view
    65 degrees from the normal: a streak ~0.8 degrees wide and ~8.5 times as long.

Representation and error
------------------------
Every function is tabulated at the texel centres of a ``(6, R, R)`` cube map (conventions.md,
default ``R = 256``); every error is the solid-angle-weighted quadrature over all ``6 R^2``
texels (exact texel solid angles), in float64. All three methods are measured against the same
table. ``docs/figure5.md`` shows that the numbers hardly move between ``R = 128, 256, 512``.

Haar
    :func:`lobelight.lobes.haar.forward` (orthonormal nonstandard Haar per face), keeping the ``k``
    largest coefficients ranked by their solid-angle L2 energy ``c^2 * mean texel solid angle
    over the coefficient's support`` (the area weighting that makes texel-space Haar rank by the
    spherical norm the error is measured in), then :func:`lobelight.lobes.haar.inverse`.
SH
    the first ``k`` real SH coefficients in band order (a partial last band when ``k`` is not a
    square: exactly ``7 K`` coefficients), fitted by least squares in the same solid-angle
    weighted norm (the Gram matrix of the texel quadrature, which is the identity to ~1e-5 at
    ``R >= 64``, so this is the quadrature projection made exactly optimal; the error therefore
    never grows with ``k``). Full orders are also reported.
Gaussians
    ``K = 1 .. max_gaussians`` lobes fitted by lobelight's batched Levenberg-Marquardt
    (:func:`lobelight.fit.fit_batch`, data term only, RGB weights solved exactly and kept
    non-negative). Lobe ``K`` is warm-started from the best ``K - 1`` fit plus a new lobe at the
    peak of the positive residual, from several starts (different widths, the residual's
    centroid, a seeded random one), all fitted at once as a batch on an adaptive quadrature of
    64^2 cells per face where the function is non-zero and coarse blocks elsewhere ("sample a
    lobe where it lives"); the best start is polished on the full-resolution texels
    (again only where the function lives). Every candidate is scored on the full cube map with
    its weights re-solved there (non-negative least squares), and the best is kept, including
    the ``K - 1`` fit with an unused lobe, so the error never grows with ``K``.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .. import fit
from .._io import atomic_path
from .._tol import DIVISOR_F64
from ..errors import InputError
from ..fit import FitData, Gaussians, Weights
from ..geometry import cubemap, sphere
from ..lobes import haar, sg, sh
from ..scene import Scene, mesh_from_arrays, uniform
from ..transport import Transport

__all__ = [
    "FLOATS_PER_GAUSSIAN",
    "FUNCTIONS",
    "figure5",
    "fit_gaussians",
    "haar_errors",
    "plot",
    "relative_error",
    "sh_errors",
    "sh_order_errors",
    "transport_functions",
]

#: Floats per Gaussian as the paper stores it (RGB weight 3, mean 3, sigma 1), section 6.1.
FLOATS_PER_GAUSSIAN = 7

#: Default cube-map face resolution: resolves the narrowest lobe (Ward's 0.014 rad streak) by
#: ~2.3 texels per standard deviation; docs/figure5.md compares 128, 256 and 512.
DEFAULT_RES = 256

#: The three transport functions: material, vertex position, view (polar angle from the normal
#: and azimuth in the vertex's tangent frame, degrees).
FUNCTIONS: dict[str, dict[str, Any]] = {
    "a_glossy": {
        "label": "(a) small symmetric glossy lobe",
        "material": {"model": "phong", "specular": [0.8] * 3, "exponent": 300.0},
        "vertex": [-1.5, 0.0, 0.0],
        "view": [30.0, 0.0],
    },
    "b_visibility": {
        "label": "(b) large lobe with visibility",
        "material": {"model": "phong", "specular": [0.8] * 3, "exponent": 12.0},
        "vertex": [0.0, 0.0, 0.0],
        "view": [35.0, 180.0],
    },
    "c_anisotropic": {
        "label": "(c) anisotropic, highly specular lobe",
        "material": {"model": "ward", "specular": [0.8] * 3, "alpha_x": 0.01, "alpha_y": 0.2},
        "vertex": [-1.5, 0.0, 0.0],
        "view": [65.0, 0.0],
    },
}

# The box that shadows function (b): from the vertex at the origin its top edge is at ~55
# degrees elevation toward +x (the lobe's peak for a 35 degree view) and its front corner at
# ~23 degrees azimuth, so both edges cross the lobe. Functions (a) and (c) look toward -x from
# x = -1.5, where the box is behind them.
_BOX = ((0.35, 0.0, -0.15), (1.2, 0.5, 0.9))

# Fit settings. The multi-start fit runs on a 64^2-per-face quadrature (cells of 0.025 rad at
# face centres: a lobe of sigma >= 0.05 rad is smooth on them), which is cheap for five starts;
# the best start is then polished on the full-resolution texels, where the sharp lobes of (a)
# and (c) are resolved (a polish on coarser cells fits them worse). Blocks where the function
# is below _ACTIVE_LEVEL of its peak are 16^2-per-face samples. The sharpness range runs from a
# hemisphere-wide lobe to past the narrowest feature a 512^2 face resolves. The iteration
# counts are where more iterations hardly lower the errors.
_LM_ITERS = 40
_POLISH_ITERS = 25
_FIT_RES = 64
_COARSE_RES = 16
_LAM_RANGE = (0.05, 1e5)
_ACTIVE_LEVEL = 1e-5
#: Ridge of the non-negative weights' normal equations, relative to their mean diagonal: keeps
#: coincident lobes solvable while far below the equations' own scale.
_RIDGE = 1e-12


# --------------------------------------------------------------------------------------------
# the transport functions


def _ground_and_box() -> tuple[np.ndarray, np.ndarray]:
    """A 4 x 4 ground grid (a vertex at the origin and at x = -1.5) and a box on it."""
    n = 17
    c = np.linspace(-2.0, 2.0, n)  # spacing 0.25: vertices at 0 and -1.5
    xx, zz = np.meshgrid(c, c, indexing="ij")
    gv = np.stack([xx.ravel(), np.zeros(n * n), zz.ravel()], -1)  # (n^2, 3)
    i = np.arange(n * n).reshape(n, n)
    a, b, cc, d = i[:-1, :-1].ravel(), i[1:, :-1].ravel(), i[1:, 1:].ravel(), i[:-1, 1:].ravel()
    gf = np.concatenate([np.stack([a, d, cc], -1), np.stack([a, cc, b], -1)])  # up-facing
    lo, hi = np.asarray(_BOX[0]), np.asarray(_BOX[1])
    corner = np.array([[(k >> ax) & 1 for ax in range(3)] for k in range(8)])  # (8, 3) bits
    bv = lo + corner * (hi - lo)
    bf = np.array(
        [
            [0, 2, 3], [0, 3, 1], [4, 5, 7], [4, 7, 6], [0, 1, 5], [0, 5, 4],
            [2, 6, 7], [2, 7, 3], [0, 4, 6], [0, 6, 2], [1, 3, 7], [1, 7, 5],
        ]
    )  # fmt: skip
    return np.concatenate([gv, bv]), np.concatenate([gf, bf + len(gv)])


def _view(normal: torch.Tensor, theta_deg: float, phi_deg: float) -> torch.Tensor:
    """Unit view direction at polar angle theta from ``normal``, azimuth phi in its frame
    (:func:`lobelight.geometry.sphere.frame`, whose tangent is the anisotropic models' x axis).
    (3,)"""
    t, b, n = sphere.frame(normal)
    th, ph = math.radians(theta_deg), math.radians(phi_deg)
    return math.sin(th) * (math.cos(ph) * t + math.sin(ph) * b) + math.cos(th) * n


def transport_functions(
    res: int = DEFAULT_RES, *, device="cpu", names=None
) -> dict[str, torch.Tensor]:
    """The three transport functions of the figure, tabulated on a cube map.

    Each is the direct glossy transport ``f_s(w, v) V(w) max(n.w, 0)`` of one ground vertex
    for one view (:data:`FUNCTIONS`), from :meth:`lobelight.transport.Transport.direct` with
    ray-cast visibility. The specular colour is grey, so the first channel is the function.

    Parameters
    ----------
    res : face resolution R (a power of two, for Haar)
    device : torch device of the results
    names : optional subset of :data:`FUNCTIONS`' keys

    Returns
    -------
    {name: (6, R, R) float64 cube map}
    """
    if not isinstance(res, int) or res < 2 or res & (res - 1):
        raise InputError("res", f"must be a power of two >= 2, got {res!r}")
    names = list(FUNCTIONS) if names is None else list(names)
    unknown = [n for n in names if n not in FUNCTIONS]
    if unknown:
        raise InputError("names", f"unknown functions {unknown}; known: {list(FUNCTIONS)}")
    v, f = _ground_and_box()
    mesh = mesh_from_arrays(v, f, name="figure5", weld=False)
    dirs = cubemap.texel_directions(res, device=device).reshape(-1, 3)  # (6 R^2, 3)
    out = {}
    for name in names:
        spec = FUNCTIONS[name]
        mats = uniform({"diffuse": [0.0] * 3, **spec["material"]}, mesh.n_vertices)
        tr = Transport(Scene(mesh, mats, name=name), device=device)
        p = torch.tensor(spec["vertex"], device=tr.device)
        vid = int((tr.mesh.vertices - p).norm(dim=-1).argmin())
        view = _view(tr.mesh.normals[vid], *spec["view"]).to(tr.device)
        t = tr.direct(torch.tensor([vid], device=tr.device), view[None], dirs)  # (1, 1, D, 3)
        out[name] = t[0, 0, :, 0].reshape(6, res, res).double()
    return out


# --------------------------------------------------------------------------------------------
# errors of the three representations


def relative_error(approx: torch.Tensor, cube: torch.Tensor, omega: torch.Tensor) -> float:
    """Relative L2 error ``sqrt(sum omega (approx - cube)^2 / sum omega cube^2)``.

    Parameters
    ----------
    approx, cube : (6, R, R) values at the texel centres;  omega : (6, R, R) solid angles
    """
    num = (omega * (approx - cube) ** 2).sum()
    return float((num / (omega * cube * cube).sum()).sqrt())


def _support_solid_angle(omega: torch.Tensor) -> torch.Tensor:
    """Mean texel solid angle over the support of every Haar coefficient, in
    :func:`lobelight.lobes.haar.forward`'s quadrant layout. (6, R, R) -> (6, R, R)."""
    res = omega.shape[-1]
    out = torch.empty_like(omega)
    h = res // 2
    while h >= 1:
        # a coefficient at (i, j) of the quadrants of size h covers a block of R/h texels
        pooled = torch.nn.functional.avg_pool2d(omega[:, None], res // h)[:, 0]  # (6, h, h)
        out[:, :h, h : 2 * h] = pooled
        out[:, h : 2 * h, :h] = pooled
        out[:, h : 2 * h, h : 2 * h] = pooled
        h //= 2
    out[:, 0, 0] = omega.mean((1, 2))  # the scaling coefficient covers the whole face
    return out


def haar_errors(cube: torch.Tensor, counts, *, weighting: str = "solid_angle") -> list[float]:
    """Relative L2 error of non-linear Haar approximations keeping ``k`` coefficients.

    Parameters
    ----------
    cube : (6, R, R) function at the texel centres, R a power of two
    counts : iterable of k (coefficients kept over the whole cube map)
    weighting : ``"solid_angle"`` ranks by ``c^2 * mean solid angle of the support`` (the energy
        in the norm the error is measured in); ``"texel"`` by ``|c|`` (plain texel norm, as
        :func:`lobelight.lobes.haar.truncate`)

    Returns
    -------
    [error for each k]
    """
    res = cube.shape[-1]
    omega = cubemap.texel_solid_angles(res, device=cube.device, dtype=cube.dtype)
    coeffs = haar.forward(cube[..., None])[..., 0]  # (6, R, R)
    if weighting == "solid_angle":
        score = coeffs * coeffs * _support_solid_angle(omega)
    elif weighting == "texel":
        score = coeffs.abs()
    else:
        raise InputError("weighting", f"must be 'solid_angle' or 'texel', got {weighting!r}")
    order = torch.argsort(score.reshape(-1), descending=True)  # (6 R^2,) ranking
    errs = []
    for k in counts:
        keep = torch.zeros(coeffs.numel(), dtype=coeffs.dtype, device=coeffs.device)
        keep[order[: int(k)]] = 1
        approx = haar.inverse((coeffs * keep.reshape(coeffs.shape))[..., None])[..., 0]
        errs.append(relative_error(approx, cube, omega))
    return errs


def _sh_normal_equations(cube: torch.Tensor, order: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Gram matrix ``sum omega Y Y^T`` (n, n) and ``sum omega Y f`` (n,) over the texels,
    n = order^2, float64, accumulated over chunks of texels to bound memory."""
    res = cube.shape[-1]
    dirs = cubemap.texel_directions(res, device=cube.device, dtype=torch.float64).reshape(-1, 3)
    omega = cubemap.texel_solid_angles(res, device=cube.device, dtype=torch.float64).reshape(-1)
    f = cube.reshape(-1).double()
    n = order * order
    gram = torch.zeros(n, n, dtype=torch.float64, device=cube.device)
    rhs = torch.zeros(n, dtype=torch.float64, device=cube.device)
    chunk = max(1, (1 << 22) // n)
    for s in range(0, dirs.shape[0], chunk):
        y = sh.basis(dirs[s : s + chunk], order)  # (c, n)
        yw = y * omega[s : s + chunk, None]
        gram += yw.T @ y
        rhs += yw.T @ f[s : s + chunk]
    return gram, rhs


def _ls_errors(gram, rhs, energy, counts) -> list[float]:
    """Relative error of the least-squares fit with the first k basis functions:
    ``||f||^2 - b_k^T G_k^-1 b_k`` is the squared residual of the weighted LS problem."""
    errs = []
    for k in counts:
        k = int(k)
        c = torch.linalg.solve(gram[:k, :k], rhs[:k])
        res2 = (energy - rhs[:k] @ c).clamp_min(0)
        errs.append(float((res2 / energy).sqrt()))
    return errs


def sh_errors(cube: torch.Tensor, counts) -> list[float]:
    """Relative L2 error of the least-squares SH fit with the first ``k`` coefficients in band
    order (``k = l^2 + l + m + 1``), for each ``k`` in ``counts``.

    Parameters
    ----------
    cube : (6, R, R);  counts : iterable of k >= 1
    """
    counts = [int(k) for k in counts]
    order = math.isqrt(max(counts) - 1) + 1  # smallest order with >= max(counts) coefficients
    gram, rhs = _sh_normal_equations(cube, order)
    omega = cubemap.texel_solid_angles(cube.shape[-1], device=cube.device, dtype=torch.float64)
    return _ls_errors(gram, rhs, (omega * cube.double() ** 2).sum(), counts)


def sh_order_errors(cube: torch.Tensor, orders) -> list[float]:
    """Relative L2 error of full-order SH least-squares fits (order n = n^2 coefficients)."""
    return sh_errors(cube, [int(n) ** 2 for n in orders])


# --------------------------------------------------------------------------------------------
# Gaussians


def _cells(x: torch.Tensor, a: int) -> torch.Tensor:
    """Group a cube map into square cells of ``a x a`` texels:
    (6, R, R, ...) -> (6, R/a, R/a, a*a, ...)."""
    r = x.shape[1] // a
    x = x.reshape(6, r, a, r, a, *x.shape[3:]).transpose(2, 3)
    return x.reshape(6, r, r, a * a, *x.shape[5:])


def _adaptive_samples(cube: torch.Tensor, fit_res: int, *, coarse: int = _COARSE_RES):
    """A quadrature of the sphere for the fit: ``fit_res`` cells where the function lives,
    ``coarse`` cells elsewhere.

    The cube map is grouped into cells of ``R / fit_res`` texels (each one sample: its
    solid-angle-weighted mean direction, the sum of its solid angles and its mean value), then
    into blocks of ``fit_res / coarse`` cells; a block where the function exceeds
    ``_ACTIVE_LEVEL`` of its peak, or next to one, keeps its cells, any other block becomes one
    sample, where the function is ~0 and a fitted lobe has no business. The samples partition
    the sphere. The fit needs ``int G^2`` and ``int G T`` only (``int T^2`` is a constant), and
    those are exact to second order in the cell size wherever the *lobe* is smooth on a cell,
    however sharp ``T`` is: cell means keep ``int G T`` right across a visibility edge.

    Parameters
    ----------
    cube : (6, R, R) float64;  fit_res : cells per face side (a power of two <= R)

    Returns
    -------
    dirs : (S, 3);  weights : (S,);  values : (S,)  (float32)
    """
    res = cube.shape[-1]
    fit_res = min(fit_res, res)
    coarse = min(coarse, fit_res)
    dirs = cubemap.texel_directions(res, device=cube.device, dtype=torch.float64)
    omega = cubemap.texel_solid_angles(res, device=cube.device, dtype=torch.float64)

    def pool(a, d, w, v):  # cells of a x a: (6, r, r, ...) each
        dc, wc = _cells(d, a), _cells(w, a)
        wsum = wc.sum(-1)
        return (
            torch.nn.functional.normalize((dc * wc[..., None]).sum(-2), dim=-1),
            wsum,
            (_cells(v, a) * wc).sum(-1) / wsum,
        )

    peak_cells = _cells(cube.abs(), res // coarse).amax(-1)  # (6, c, c) block maxima
    hot = (peak_cells > _ACTIVE_LEVEL * cube.abs().amax()).double()
    # one block of margin, within each face (a lobe across a seam is hot on both sides)
    active = torch.nn.functional.max_pool2d(hot[:, None], 3, 1, 1)[:, 0] > 0  # (6, c, c)
    fd, fw, fv = pool(res // fit_res, dirs, omega, cube)  # (6, f, f, ...)
    b = fit_res // coarse
    fd, fw, fv = _cells(fd, b), _cells(fw, b), _cells(fv, b)  # (6, c, c, b*b, ...)
    cd, cw, cv = pool(res // coarse, dirs, omega, cube)  # (6, c, c, ...)
    d = torch.cat([fd[active].reshape(-1, 3), cd[~active]])
    w = torch.cat([fw[active].reshape(-1), cw[~active]])
    v = torch.cat([fv[active].reshape(-1), cv[~active]])
    return d.float(), w.float(), v.float()


class _FullGrid:
    """The full-resolution cube map, for scoring mixtures (float64)."""

    def __init__(self, cube: torch.Tensor):
        res = cube.shape[-1]
        self.dirs = cubemap.texel_directions(res, device=cube.device, dtype=torch.float64)
        self.dirs = self.dirs.reshape(-1, 3)  # (P, 3)
        self.omega = cubemap.texel_solid_angles(res, device=cube.device, dtype=torch.float64)
        self.omega = self.omega.reshape(-1)
        self.f = cube.reshape(-1).double()
        self.energy = (self.omega * self.f * self.f).sum()

    def lobes(self, mu: torch.Tensor, lam: torch.Tensor) -> torch.Tensor:
        """``G_k`` at every texel: mu (N, 3), lam (N,) -> (N, P)."""
        return sg.evaluate(self.dirs[None], mu.double()[:, None], lam.double()[:, None])

    def nnls(self, g: torch.Tensor) -> tuple[torch.Tensor, float]:
        """Non-negative least-squares weights for lobes ``g`` (N, P), and the relative error.

        Active set: solve, drop the most negative weight, repeat (at most N times; N <= ~10).
        """
        n = g.shape[0]
        gw = g * self.omega
        a = gw @ g.T  # (N, N)
        b = gw @ self.f  # (N,)
        free = torch.ones(n, dtype=torch.bool, device=g.device)
        w = torch.zeros(n, dtype=g.dtype, device=g.device)
        scale = a.diagonal().mean().clamp_min(DIVISOR_F64)
        for _ in range(n):
            eye = torch.eye(n, dtype=g.dtype, device=g.device)
            # fixed lobes get an identity row and a zero right-hand side; a tiny ridge keeps
            # coincident lobes solvable
            sys_a = torch.where(free[:, None] & free[None], a, eye * scale) + _RIDGE * scale * eye
            w = torch.linalg.solve(sys_a, torch.where(free, b, torch.zeros_like(b)))
            if bool((w >= 0).all()):
                break
            free &= w > w.min()  # fix the most negative one at 0
        w = w.clamp_min(0)
        res2 = (self.energy - 2 * (w @ b) + w @ a @ w).clamp_min(0)
        return w, float((res2 / self.energy).sqrt())


def _new_lobe_starts(
    grid: _FullGrid, mu: torch.Tensor, lam: torch.Tensor, w: torch.Tensor, gen: torch.Generator
) -> list[tuple[torch.Tensor, float]]:
    """Starting mean and sharpness for one more lobe, from the positive residual of the mixture
    so far (mu (N, 3), lam (N,), w (N,); N may be 0): its peak at three widths, its centroid,
    and a seeded jitter of the peak."""
    resid = grid.f.clone()
    if mu.shape[0]:
        resid -= w.double() @ grid.lobes(mu, lam)
    pos = resid.clamp_min(0)
    peak_dir = grid.dirs[int(pos.argmax())]
    # moments of the squared residual: energy, not mass, so a small sharp peak left over is
    # found rather than the broad misfit around it; a Gaussian squared has twice the sharpness
    c_mu, c_lam, _ = sg.fit_from_samples(grid.dirs, pos * pos, grid.omega)
    lam0 = float((c_lam / 2).clamp(*_LAM_RANGE))
    sigma = 1 / math.sqrt(lam0)
    t, s, _ = sphere.frame(peak_dir)
    kick = torch.randn(2, generator=gen, dtype=torch.float64)
    jitter = torch.nn.functional.normalize(
        peak_dir + 0.5 * sigma * (kick[0] * t + kick[1] * s), dim=0
    )
    jitter_lam = lam0 * math.exp(float(torch.randn(1, generator=gen, dtype=torch.float64)))
    # the plain moment guesses first: fit_gaussians with fewer starts takes the first ones
    return [
        (peak_dir, lam0),
        (c_mu, lam0),
        (jitter, jitter_lam),
        (peak_dir, lam0 * 4),
        (peak_dir, lam0 / 4),
    ]


def _fit_data(samples, b: int) -> FitData:
    """FitData of ``b`` restarts x one view from (dirs, weights, values); grey -> 3 channels."""
    d, w, v = samples
    return FitData(
        d.expand(b, 1, -1, 3),
        w.expand(b, 1, -1),
        v[:, None].expand(-1, 3).expand(b, 1, -1, 3),
        torch.zeros(b, 1, dtype=torch.bool, device=d.device),
    )


def _lm(samples, mus: torch.Tensor, lams: torch.Tensor, iters: int):
    """Data-term-only LM from ``b`` starts: mus (b, K, 3), lams (b, K) -> the same, fitted."""
    b, k = lams.shape
    data = _fit_data(samples, b)
    # one view per "vertex": its own neighbour, so the alignment terms vanish (M = V = 0)
    nbr = torch.tensor([[0, -1, -1, -1, -1, -1]], device=mus.device)
    init = Gaussians(
        torch.zeros(b, 1, k, 3, device=mus.device), mus.float()[:, None], lams.float()[:, None]
    )
    g, _ = fit.fit_batch(
        data,
        k,
        nbr,
        weights=Weights(alpha=1.0, beta=0.0, gamma=0.0, delta=0.0),
        init=init,
        lam_range=_LAM_RANGE,
        iters=iters,
    )
    return g.mu[:, 0].double(), g.lam[:, 0].double()


def _best(grid: _FullGrid, mus: torch.Tensor, lams: torch.Tensor):
    """The candidate (error, mu, lam, w) with the lowest full-resolution error, or None."""
    best = None
    for i in range(mus.shape[0]):  # a few candidates, each scored on the whole cube map
        w_i, e_i = grid.nnls(grid.lobes(mus[i], lams[i]))
        if math.isfinite(e_i) and (best is None or e_i < best[0]):
            best = (e_i, mus[i], lams[i], w_i)
    return best


def fit_gaussians(
    cube: torch.Tensor,
    max_gaussians: int,
    *,
    seed: int = 0,
    starts: int = 5,
    iters: int = _LM_ITERS,
) -> list[dict[str, Any]]:
    """Fit 1 .. ``max_gaussians`` Gaussians to a function on a cube map (module docstring).

    For each K: ``starts`` starts (the K - 1 fit plus a new lobe, :func:`_new_lobe_starts`)
    fitted at once by LM on the 64^2 adaptive quadrature; the best on the full cube map is
    polished by LM on the full-resolution adaptive quadrature; the better of the two, or the
    K - 1 fit with an unused lobe if neither beats it, is kept.

    Parameters
    ----------
    cube : (6, R, R) float64 function at the texel centres
    max_gaussians : largest K
    seed : seeds the random start among the candidates for each new lobe
    starts : starts per K, 1 to 5 (fewer: faster, for tests)
    iters : LM iterations of the multi-start stage per K

    Returns
    -------
    one dict per K: ``error`` (relative L2 on the full cube map), ``mu`` (K, 3), ``lam`` (K,),
    ``w`` (K,) as lists, ``kept_previous`` (True when no candidate beat the K - 1 fit)
    """
    if int(max_gaussians) < 1:
        raise InputError("max_gaussians", f"must be >= 1, got {max_gaussians!r}")
    dev = cube.device
    gen = torch.Generator().manual_seed(int(seed))
    grid = _FullGrid(cube)
    coarse = _adaptive_samples(cube, _FIT_RES)
    fine = _adaptive_samples(cube, cube.shape[-1])
    mu = torch.zeros(0, 3, dtype=torch.float64, device=dev)
    lam = torch.zeros(0, dtype=torch.float64, device=dev)
    w = torch.zeros(0, dtype=torch.float64, device=dev)
    prev_err = 1.0  # the empty mixture
    out = []
    for k in range(1, int(max_gaussians) + 1):
        cand = _new_lobe_starts(grid, mu, lam, w, gen)[: max(1, int(starts))]
        mus = torch.stack([torch.cat([mu, m.to(mu)[None]]) for m, _ in cand])  # (B, K, 3)
        lams = torch.stack([torch.cat([lam, lam.new_tensor([lm])]) for _, lm in cand])  # (B, K)
        best = _best(grid, *_lm(coarse, mus, lams, iters))
        if best is not None:
            polished = _best(grid, *_lm(fine, best[1][None], best[2][None], _POLISH_ITERS))
            if polished is not None and polished[0] < best[0]:
                best = polished
        kept = best is None or best[0] >= prev_err
        if kept:
            # K - 1 lobes and an unused one (weight 0) are a K-lobe mixture too
            mu, lam = torch.cat([mu, cand[0][0].to(mu)[None]]), torch.cat([lam, lams[0, -1:]])
            w = torch.cat([w, w.new_zeros(1)])
        else:
            prev_err, mu, lam, w = best
        out.append(
            {
                "k": k,
                "error": prev_err,
                "mu": mu.tolist(),
                "lam": lam.tolist(),
                "w": w.tolist(),
                "kept_previous": kept,
            }
        )
    return out


# --------------------------------------------------------------------------------------------
# the figure


def _sh_full_orders(counts) -> list[int]:
    """For each coefficient count, the largest SH order with at most that many coefficients."""
    return [max(1, math.isqrt(int(c))) for c in counts]


def plot(result: dict[str, Any], path) -> None:
    """Three panels, relative L2 error (%) against the number of coefficients, log scale, as
    in the paper's Figure 5; written to ``path`` (PNG) through a temporary name."""
    import matplotlib  # optional: the plot extra

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # optional: the plot extra
    from matplotlib.ticker import FuncFormatter, NullFormatter  # optional: the plot extra

    plain = FuncFormatter(lambda v, _: f"{v:g}")  # 20, 0.1: not 2x10^1 on a log axis

    funcs = result["functions"]
    fig, axes = plt.subplots(1, len(funcs), figsize=(4.6 * len(funcs), 4.0), squeeze=False)
    for ax, (_, r) in zip(axes[0], funcs.items(), strict=True):
        n = r["coefficients"]
        ax.semilogy(n, [100 * e for e in r["gaussians"]], "o-", label="Gaussians (7 floats each)")
        ax.semilogy(n, [100 * e for e in r["haar"]], "s-", label="Haar, k largest")
        ax.semilogy(n, [100 * e for e in r["sh"]], "^-", label="SH, first k coefficients")
        ax.set_title(r["label"], fontsize=10)
        ax.set_xlabel("coefficients k (= 7 x number of Gaussians)")
        ax.set_ylabel("relative L2 error (%)")
        ax.set_xticks(n)
        ax.grid(True, which="both", alpha=0.3)
        ax.yaxis.set_major_formatter(plain)
        lo, hi = ax.get_ylim()
        if hi / lo < 12:  # less than a decade shown: label the minor ticks too
            ax.yaxis.set_minor_formatter(plain)
            ax.tick_params(axis="y", which="minor", labelsize=7)
        else:
            ax.yaxis.set_minor_formatter(NullFormatter())
        ax.legend(fontsize=8)
    fig.suptitle(f"Green et al. 2006, Figure 5: cube map {result['res']}^2 per face", fontsize=11)
    fig.tight_layout()
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def figure5(
    out=None,
    *,
    max_gaussians: int = 10,
    res: int = DEFAULT_RES,
    device="cpu",
    seed: int = 0,
    names=None,
) -> dict[str, Any]:
    """Compute the paper's Figure 5 (module docstring) and optionally write it.

    Parameters
    ----------
    out : folder for ``figure5.json`` and ``figure5.png`` (created; each written through a
        temporary name then renamed), or None to write nothing
    max_gaussians : K = 1 .. max_gaussians, compared at k = 7 K coefficients
    res : cube-map face resolution (power of two)
    device : torch device for the transport and the fits
    seed : seeds the random start of each new lobe
    names : optional subset of the functions (default all three)

    Returns
    -------
    JSON-serialisable dict: ``res``, ``floats_per_gaussian``, ``counting`` (in words),
    ``seconds``, and per function under ``functions``: ``label``, ``setup``, ``gaussians``
    (K) and the matching ``coefficients`` (7 K), ``haar`` and ``sh`` errors at those counts,
    ``haar_texel`` (Haar ranked by plain texel norm), ``sh_full_order`` (the largest full order
    with at most 7 K coefficients, and its errors), ``fits`` (the lobes per K).
    """
    t0 = time.perf_counter()
    kmax = int(max_gaussians)
    if kmax < 1:
        raise InputError("max_gaussians", f"must be >= 1, got {max_gaussians!r}")
    if 6 * res * res < FLOATS_PER_GAUSSIAN * kmax:
        raise InputError("res", f"a {res}^2 cube map has fewer than {7 * kmax} coefficients")
    ks = list(range(1, kmax + 1))
    counts = [FLOATS_PER_GAUSSIAN * k for k in ks]
    full_orders = _sh_full_orders(counts)
    cubes = transport_functions(res, device=device, names=names)
    funcs = {}
    for name, cube in cubes.items():
        t1 = time.perf_counter()
        fits = fit_gaussians(cube, kmax, seed=seed)
        funcs[name] = {
            "label": FUNCTIONS[name]["label"],
            "setup": {k: FUNCTIONS[name][k] for k in ("material", "vertex", "view")},
            "gaussians_k": ks,
            "coefficients": counts,
            "gaussians": [f["error"] for f in fits],
            "haar": haar_errors(cube, counts),
            "haar_texel": haar_errors(cube, counts, weighting="texel"),
            "sh": sh_errors(cube, counts),
            "sh_full_order": {
                "order": full_orders,
                "coefficients": [n * n for n in full_orders],
                "error": sh_order_errors(cube, full_orders),
            },
            "fits": fits,
            "seconds": time.perf_counter() - t1,
        }
    result = {
        "figure": "Green et al. 2006, Figure 5",
        "res": res,
        "floats_per_gaussian": FLOATS_PER_GAUSSIAN,
        "counting": (
            "K Gaussians (7 floats each: RGB weight, mean, sigma) against 7K Haar and 7K SH "
            "coefficients per colour channel; the functions are grey, so one channel"
        ),
        "error": "relative L2, solid-angle weighted over all cube-map texels",
        "seed": seed,
        "functions": funcs,
        "seconds": time.perf_counter() - t0,
    }
    if out is not None:
        folder = Path(out)
        folder.mkdir(parents=True, exist_ok=True)
        text = json.dumps(result, indent=1)
        with atomic_path(folder / "figure5.json") as tmp:
            tmp.write_text(text)
        plot(result, folder / "figure5.png")
    return result
