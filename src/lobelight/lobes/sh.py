"""Real, orthonormal spherical harmonics: evaluation, projection, rotation, zonal convolution.

Conventions
-----------
*Order.* "Order n" means bands ``l = 0 .. n-1``, ``n**2`` coefficients (conventions.md: 25).
Coefficient ``k`` holds band ``l`` and index ``m`` (``-l <= m <= l``) with ``k = l*l + l + m``.

*Axes.* Directions are unit vectors in the world frame (right-handed, +Y up, conventions.md). The SH
**polar axis is +Z** (world z), as in the mathematical literature, scipy and sphericart:
``cos(theta) = z`` and ``phi = atan2(y, x)``. The basis is just a set of polynomials in
``(x, y, z)``, so which axis is "up" in the scene does not matter for projection, rotation or
reconstruction; it only matters for *zonal* functions: :func:`sg_zonal` and
:func:`clamped_cosine_zonal` describe lobes symmetric about +Z, and :func:`zonal_to_sh` places
such a lobe about any other axis (for instance +Y for a sky).

*Sign.* No Condon–Shortley phase (the common graphics convention, as in Green's "Spherical
Harmonic Lighting: The Gritty Details"), so the first bands are::

    Y_00 = 1 / (2 sqrt(pi))
    (Y_1-1, Y_10, Y_11) = sqrt(3 / (4 pi)) * (y, z, x)
    (Y_2-2, Y_2-1, Y_20, Y_21, Y_22) = sqrt(15 / (4 pi)) * (x y, y z, (3 z^2 - 1) / (2 sqrt 3),
                                                          x z, (x^2 - y^2) / 2)

In general, with ``P_l^m`` the associated Legendre functions *without* the ``(-1)^m`` factor and
``K_l^m = sqrt((2l+1)/(4 pi) (l-m)!/(l+m)!)``::

    Y_lm  = sqrt(2) K_l^m P_l^m(cos theta) cos(m phi)        m > 0
    Y_l0  = K_l^0 P_l(cos theta)
    Y_l-m = sqrt(2) K_l^m P_l^m(cos theta) sin(m phi)        m > 0

Relative to scipy's complex ``sph_harm_y(l, m, theta, phi)`` (which includes the phase) this is
``sqrt(2) (-1)^m Re Y_l^m`` for ``m > 0`` and ``sqrt(2) (-1)^m Im Y_l^m`` for ``-m < 0``.

*Evaluation.* ``P_l^m(z) / sin^m(theta)`` is a polynomial in ``z``; it is computed with the
normalised three-term recurrence in ``l`` (stable to high orders, no factorials), and
``sin^m(theta) (cos m phi, sin m phi)`` are the real and imaginary parts of ``(x + i y)^m``.
There is no division by ``sin(theta)`` and no trigonometry, so the poles are exact. The work runs
in float64 (results are cast back to the input's dtype); loops run over bands, never directions.

*Rotation.* ``rotation_matrix(R, order)`` returns the block-diagonal ``D`` with
``D @ coeffs(f) = coeffs(f(R^T w))``. Each block ``D_l[j, k] = <Y_lj, Y_lk(R^T .)>`` is computed
with a product Gauss–Legendre (in ``z``) x uniform (in ``phi``) rule that integrates products of
two order-``n`` harmonics exactly, so ``D`` is exact to float64 rounding, batched over ``R`` and
differentiable in ``R``. :class:`Rotator` rotates one fixed expansion by one matrix after another
(a turning sky, every frame) with a few float64 products on the CPU.

*Zonal convolution* (Funk–Hecke): convolving ``f`` with a kernel ``k(w . a)`` whose zonal
coefficients about +Z are ``k_l`` scales coefficient ``(l, m)`` by ``sqrt(4 pi / (2l + 1)) k_l``.
"""

from __future__ import annotations

import functools
import math
import operator
from typing import Any

import numpy as np
import torch

from .._backend import as_tensor, dispatch
from .._checks import check_cube, check_directions
from ..errors import InputError
from ..geometry.cubemap import texel_directions, texel_solid_angles

__all__ = [
    "Rotator",
    "basis",
    "clamped_cosine_zonal",
    "num_coeffs",
    "order_of",
    "project",
    "project_cubemap",
    "project_envmap",
    "reconstruct",
    "rotate",
    "rotation_matrix",
    "sg_zonal",
    "zonal_convolve",
    "zonal_to_sh",
]

# Rows of basis values evaluated at once in projection / reconstruction, as a number of float64
# entries (2**22 entries = 32 MiB), so that high orders on big cube maps stay within memory.
_CHUNK_ENTRIES = 1 << 22

# Truncation of the spherical-Gaussian integral in units of 1/lam: exp(-50) ~ 2e-22 of the peak.
_SG_TAIL = 50.0
# Gauss–Legendre nodes for the SG integral beyond the band count: 24 already converge to the
# ~1e-12 z_0 floor (set by the rule's end weights) for lam in [0, 1e4], orders 1..40; 40 for margin.
_SG_EXTRA_NODES = 40


# ----------------------------------------------------------------------------------------------
# helpers


def num_coeffs(order: int) -> int:
    """Number of coefficients of an order-``order`` expansion: ``order**2``."""
    return _check_order(order) ** 2


def order_of(n_coeffs: int) -> int:
    """Order of an expansion with ``n_coeffs`` coefficients (must be a perfect square >= 1)."""
    n = int(n_coeffs)
    order = math.isqrt(n)
    if n < 1 or order * order != n:
        raise InputError("coeffs", f"needs a square number of coefficients (order**2), got {n}")
    return order


def _check_order(order: Any, name: str = "order") -> int:
    try:
        o = operator.index(order)
    except TypeError:
        raise InputError(name, f"must be an integer >= 1, got {order!r}") from None
    if o < 1:
        raise InputError(name, f"must be an integer >= 1, got {o}")
    return o


def _work_dtype(device: torch.device) -> torch.dtype:
    # float64 everywhere it exists (Apple's MPS has none).
    return torch.float32 if device.type == "mps" else torch.float64


def _float_dtype(t: torch.Tensor) -> torch.dtype:
    return t.dtype if t.is_floating_point() else torch.float32


def _band_index(order: int, *, device=None) -> torch.Tensor:
    """Band ``l`` of every coefficient, ``(order**2,)`` int64."""
    ls = torch.arange(order, device=device)
    return torch.repeat_interleave(ls, 2 * ls + 1)


def _check_coeffs(coeffs: torch.Tensor) -> int:
    if coeffs.ndim not in (1, 2):
        raise InputError(
            "coeffs", f"must be (order**2,) or (order**2, C), got shape {tuple(coeffs.shape)}"
        )
    return order_of(coeffs.shape[0])


# ----------------------------------------------------------------------------------------------
# evaluation


def _basis(d: torch.Tensor, order: int) -> torch.Tensor:
    """Basis values of unit directions ``d`` (..., 3) -> (..., order**2), in d's dtype."""
    x, y, z = d.unbind(-1)
    dev, dt = d.device, d.dtype
    # Real and imaginary parts of (x + i y)^m, m = 0 .. order-1: sin^m(theta) (cos, sin)(m phi).
    re, im = [torch.ones_like(x)], [torch.zeros_like(x)]
    for _ in range(1, order):
        r, i = re[-1], im[-1]
        re.append(x * r - y * i)
        im.append(x * i + y * r)
    cos_m = torch.stack(re, -1) * math.sqrt(2.0)  # (..., order), sqrt(2) of the real basis
    sin_m = torch.stack(im, -1) * math.sqrt(2.0)
    zc = z.unsqueeze(-1)  # (..., 1)

    # q[..., m] = K_l^m P_l^m(z) / sin^m(theta) for the current band l, m = 0 .. l.
    q_prev2 = None
    q_prev = torch.full_like(zc, 1.0 / math.sqrt(4.0 * math.pi))  # l = 0
    bands = [q_prev]
    for l in range(1, order):
        parts = []
        if l >= 2:
            # m = 0 .. l-2: q_l = a (z q_{l-1} - b q_{l-2}), the normalised three-term recurrence
            m = torch.arange(l - 1, device=dev, dtype=dt)
            a = torch.sqrt((4.0 * l * l - 1.0) / (l * l - m * m))
            b = torch.sqrt(((l - 1.0) ** 2 - m * m) / (4.0 * (l - 1.0) ** 2 - 1.0))
            parts.append(a * (zc * q_prev[..., : l - 1] - b * q_prev2))
        top = q_prev[..., l - 1 : l]  # q_{l-1}^{l-1}
        parts.append(math.sqrt(2.0 * l + 1.0) * zc * top)  # m = l - 1
        parts.append(math.sqrt((2.0 * l + 1.0) / (2.0 * l)) * top)  # m = l
        q = torch.cat(parts, -1)  # (..., l + 1)
        # band l in index order m = -l .. l
        neg = (q[..., 1:] * sin_m[..., 1 : l + 1]).flip(-1)
        pos = q[..., 1:] * cos_m[..., 1 : l + 1]
        bands.append(torch.cat([neg, q[..., :1], pos], -1))
        q_prev2, q_prev = q_prev, q  # band l+1 needs bands l and l-1 at m <= l-1
    return torch.cat(bands, -1)


@dispatch
def basis(dirs, order):
    """Real orthonormal SH basis evaluated at directions.

    Parameters
    ----------
    dirs : (..., 3) float, directions (normalised here; need not be unit)
    order : int >= 1, number of bands

    Returns
    -------
    (..., order**2) in the dtype of ``dirs`` (computed in float64), on its device.
    """
    dirs = as_tensor(dirs)
    check_directions(dirs)
    order = _check_order(order)
    out_dtype = _float_dtype(dirs)
    d = torch.nn.functional.normalize(dirs.to(_work_dtype(dirs.device)), dim=-1)
    return _basis(d, order).to(out_dtype)


# ----------------------------------------------------------------------------------------------
# projection and reconstruction


def _project(values: torch.Tensor, dirs: torch.Tensor, weights: torch.Tensor, order: int):
    """Quadrature sum: values (N, C), dirs (N, 3), weights (N,) -> (order**2, C), work dtype."""
    wd = _work_dtype(values.device)
    n2 = order * order
    out = torch.zeros(n2, values.shape[-1], device=values.device, dtype=wd)
    chunk = max(1, _CHUNK_ENTRIES // n2)
    for s in range(0, values.shape[0], chunk):
        d = torch.nn.functional.normalize(dirs[s : s + chunk].to(wd), dim=-1)
        b = _basis(d, order)  # (n, order**2)
        wv = weights[s : s + chunk].to(wd).unsqueeze(-1) * values[s : s + chunk].to(wd)  # (n, C)
        out = out + b.transpose(0, 1) @ wv
    return out


@dispatch
def project(values, dirs, weights, order):
    """Project a sampled function onto the SH basis by quadrature: ``sum_i w_i f(w_i) Y(w_i)``.

    Parameters
    ----------
    values : (...) or (..., C) samples of the function
    dirs : (..., 3) sample directions (same leading shape as ``values``)
    weights : (...) quadrature weights (solid angle per sample; they sum to 4 pi for the sphere)
    order : int >= 1

    Returns
    -------
    (order**2,) when ``values`` has no channel axis, else (order**2, C); dtype of ``values``
    (float32 for integer input), on its device. Accumulated in float64.
    """
    values, dirs, weights = as_tensor(values), as_tensor(dirs), as_tensor(weights)
    check_directions(dirs)
    order = _check_order(order)
    lead = dirs.shape[:-1]
    if tuple(weights.shape) != tuple(lead):
        raise InputError("weights", f"must have shape {tuple(lead)}, got {tuple(weights.shape)}")
    scalar = tuple(values.shape) == tuple(lead)
    if not scalar and tuple(values.shape[:-1]) != tuple(lead):
        raise InputError(
            "values", f"must have shape {tuple(lead)} or {(*lead, 'C')}, got {tuple(values.shape)}"
        )
    dev = values.device
    v = values.reshape(-1, 1) if scalar else values.reshape(-1, values.shape[-1])  # (N, C)
    out = _project(v, dirs.to(dev).reshape(-1, 3), weights.to(dev).reshape(-1), order)
    out = out.to(_float_dtype(values))
    return out[:, 0] if scalar else out


@dispatch
def project_cubemap(cube, order):
    """Project a cube map, each texel weighted by its exact solid angle.

    The cube map is treated as a piecewise-constant function sampled at texel centres (midpoint
    rule); the result is exact for that sum, so band ``l >= 4`` of a constant map shows the
    ``O(1/R^2)`` midpoint error while bands 1–3 vanish by the cube's symmetry.

    Parameters
    ----------
    cube : (6, R, R, C) cube map (conventions.md layout)
    order : int >= 1

    Returns
    -------
    (order**2, C) in the cube's dtype, on its device.
    """
    cube = as_tensor(cube)
    check_cube(cube)
    order = _check_order(order)
    res, dev = cube.shape[1], cube.device
    wd = _work_dtype(dev)
    dirs = texel_directions(res, device=dev, dtype=wd).reshape(-1, 3)  # (6 R R, 3)
    w = texel_solid_angles(res, device=dev, dtype=wd).reshape(-1)  # (6 R R,)
    out = _project(cube.reshape(-1, cube.shape[-1]), dirs, w, order)
    return out.to(_float_dtype(cube))


def project_envmap(env, order, *, res=64, cache=False):
    """Project an environment map through its cube-map form.

    Parameters
    ----------
    env : any object with ``to_cubemap(res) -> (6, res, res, C)`` (e.g. ``lobelight.envmap.EnvMap``)
    order : int >= 1
    res : cube face resolution used for the projection (exact solid angles; see
        :func:`project_cubemap` for the discretisation error)
    cache : when not False, passed on as ``to_cubemap(res, cache=cache)``: an EnvMap then keeps
        the resampled cube on disk (``lobelight.envmap.EnvMap.to_cubemap``), so that a process
        projecting the same map again reads it back instead of resampling

    Returns
    -------
    (order**2, C), numpy if ``to_cubemap`` returns numpy, else a tensor.
    """
    to_cube = getattr(env, "to_cubemap", None)
    if not callable(to_cube):
        raise InputError("env", f"needs a to_cubemap(res) method, got {type(env).__name__}")
    cube = to_cube(res) if cache is False else to_cube(res, cache=cache)
    return project_cubemap(cube, order)


@dispatch
def reconstruct(coeffs, dirs):
    """Evaluate an SH expansion at directions: ``sum_k c_k Y_k(w)``.

    Parameters
    ----------
    coeffs : (order**2,) or (order**2, C)
    dirs : (..., 3) directions (normalised here)

    Returns
    -------
    (...) or (..., C) in the dtype of ``coeffs``, on its device. Summed in float64.
    """
    coeffs, dirs = as_tensor(coeffs), as_tensor(dirs)
    order = _check_coeffs(coeffs)
    check_directions(dirs)
    dev = coeffs.device
    wd = _work_dtype(dev)
    lead = dirs.shape[:-1]
    c = coeffs.to(wd).reshape(order * order, -1)  # (n2, C)
    d = dirs.to(device=dev).reshape(-1, 3)  # (N, 3)
    chunk = max(1, _CHUNK_ENTRIES // (order * order))
    parts = [
        _basis(torch.nn.functional.normalize(d[s : s + chunk].to(wd), dim=-1), order) @ c
        for s in range(0, d.shape[0], chunk)
    ]
    out = torch.cat(parts, 0) if parts else c.new_zeros(0, c.shape[-1])  # (N, C)
    out = out.to(_float_dtype(coeffs))
    return out.reshape(*lead) if coeffs.ndim == 1 else out.reshape(*lead, c.shape[-1])


# ----------------------------------------------------------------------------------------------
# rotation


@functools.lru_cache(maxsize=16)
def _rotation_rule(order: int, device: torch.device, dtype: torch.dtype):
    """Quadrature exact for products of two order-``order`` harmonics.

    Gauss–Legendre with ``order`` nodes in z is exact to polynomial degree ``2 order - 1``, and
    ``2 order - 1`` equispaced azimuths integrate ``e^{i k phi}`` exactly for
    ``|k| <= 2 order - 2``.

    Returns
    -------
    dirs : (M, 3) nodes;  bw : (M, order**2) basis values times weights (M = order (2 order - 1))
    """
    z, wz = np.polynomial.legendre.leggauss(order)
    n_phi = 2 * order - 1
    phi = 2 * np.pi * np.arange(n_phi) / n_phi
    s = np.sqrt(1 - z * z)
    dirs = np.stack(
        [
            s[:, None] * np.cos(phi)[None, :],
            s[:, None] * np.sin(phi)[None, :],
            np.broadcast_to(z[:, None], (order, n_phi)),
        ],
        -1,
    ).reshape(-1, 3)  # (M, 3)
    w = np.repeat(wz * (2 * np.pi / n_phi), n_phi)  # (M,)
    dirs_t = torch.as_tensor(dirs, dtype=dtype, device=device)
    bw = _basis(dirs_t, order) * torch.as_tensor(w, dtype=dtype, device=device)[:, None]
    return dirs_t, bw


def _check_rotation(R: torch.Tensor) -> None:
    if R.ndim < 2 or tuple(R.shape[-2:]) != (3, 3):
        raise InputError("R", f"must be a (..., 3, 3) rotation matrix, got {tuple(R.shape)}")
    if R.numel() == 0:
        return
    eye = torch.eye(3, dtype=R.dtype, device=R.device)
    err = (R.transpose(-1, -2) @ R - eye).abs().amax()
    # float32 matrices built from a few products sit near 1e-6; 1e-3 only rejects non-rotations.
    if not bool(err <= 1e-3):
        raise InputError("R", f"must be orthogonal (max |R^T R - I| = {float(err):.2e})")


@dispatch
def rotation_matrix(R, order):
    """SH rotation matrix of a 3x3 rotation.

    ``D @ coeffs(f)`` are the coefficients of the rotated function ``f(R^T w)`` (the function
    carried along by ``R``: a lobe around ``a`` moves to ``R a``). ``D`` is block diagonal with one
    orthogonal ``(2l+1) x (2l+1)`` block per band, and ``D(R1 R2) = D(R1) D(R2)``. Orthogonal ``R``
    with determinant -1 (reflections) work the same way.

    Parameters
    ----------
    R : (..., 3, 3) orthogonal matrices
    order : int >= 1

    Returns
    -------
    (..., order**2, order**2) in R's dtype, on its device (computed in float64).
    """
    R = as_tensor(R)
    _check_rotation(R)
    order = _check_order(order)
    dev = R.device
    wd = _work_dtype(dev)
    nodes, bw = _rotation_rule(order, dev, wd)  # (M, 3), (M, n2)
    # Y_k(R^T p) for every node p: rows p^T R are the rotated nodes, (..., M, n2)
    brot = _basis(nodes @ R.to(wd), order)
    n2 = order * order
    out = torch.zeros(*R.shape[:-2], n2, n2, device=dev, dtype=wd)
    for l in range(order):
        sl = slice(l * l, (l + 1) * (l + 1))
        # D_l[j, k] = sum_p w_p Y_lj(p) Y_lk(R^T p), exact for this rule
        out[..., sl, sl] = bw[:, sl].transpose(0, 1) @ brot[..., :, sl]
    return out.to(_float_dtype(R))


@dispatch
def rotate(coeffs, R):
    """Coefficients of the rotated function ``f(R^T w)``: ``rotation_matrix(R) @ coeffs``.

    Parameters
    ----------
    coeffs : (order**2,) or (order**2, C)
    R : (..., 3, 3) orthogonal

    Returns
    -------
    (..., order**2) or (..., order**2, C), dtype of ``coeffs``.
    """
    coeffs, R = as_tensor(coeffs), as_tensor(R)
    order = _check_coeffs(coeffs)
    D = rotation_matrix(R.to(coeffs.device), order)  # (..., n2, n2)
    wd = _work_dtype(coeffs.device)
    c = coeffs.to(wd)
    out = D.to(wd) @ c if coeffs.ndim == 2 else (D.to(wd) @ c.unsqueeze(-1))[..., 0]
    return out.to(_float_dtype(coeffs))


class Rotator:
    """The coefficients of one fixed function, rotated by one matrix after another: cheap
    enough to do for every frame of an animation.

    :func:`rotate` builds the rotation matrix from the basis at rotated quadrature nodes, a few
    dozen small torch operations per call. Here a rotation is three small float64 numpy
    products on the CPU. Real SH of band ``l`` are polynomials of degree ``l`` in
    ``(x, y, z)``, so the function is one fixed polynomial ``f(x) = m(x) . Pc`` of the
    monomials ``m`` of degree ``< order`` (fitted once, here); its rotation evaluated at the
    nodes of the rule :func:`rotation_matrix` uses and projected with that rule's weights is
    exact (the rule integrates products of two order-``order`` harmonics), so
    ``rotator.rotate(R)`` equals ``rotate(coeffs, R)`` to float64 rounding.

    Parameters
    ----------
    coeffs : (order**2,) or (order**2, C) coefficients of the function, any device and dtype
        (kept in float64 on the CPU)

    Attributes
    ----------
    order : int, the expansion's order
    """

    def __init__(self, coeffs: torch.Tensor):
        c = coeffs.detach().cpu().to(torch.float64)
        order = math.isqrt(c.shape[0])
        if order * order != c.shape[0]:
            raise InputError("coeffs", f"needs a square number of rows, got {c.shape[0]}")
        self.order = order
        nodes, bw = _rotation_rule(order, torch.device("cpu"), torch.float64)
        self._nodes, self._bw_t = nodes.numpy(), bw.numpy().T.copy()  # (M, 3), (n2, M)
        self._exps = np.array(
            [
                (a, b, d - a - b)
                for d in range(order)
                for a in range(d + 1)
                for b in range(d - a + 1)
            ]
        )  # (P, 3) monomial exponents, total degree < order
        # the polynomial's coefficients, by least squares at enough points (the monomials are
        # dependent on the sphere, x^2 + y^2 + z^2 = 1, so take the minimum-norm solution)
        g = torch.Generator().manual_seed(0)
        pts = torch.nn.functional.normalize(
            torch.randn(4 * len(self._exps) + 16, 3, generator=g, dtype=torch.float64), dim=-1
        )
        f = (_basis(pts, order) @ c).numpy()  # (K, C)
        self._pc = np.linalg.lstsq(self._monomials(pts.numpy()), f, rcond=None)[0]  # (P, C)

    def _monomials(self, x: np.ndarray) -> np.ndarray:
        """``(K, 3) -> (K, P)``: ``x^a y^b z^c`` for each exponent triple."""
        pw = x[:, :, None] ** np.arange(max(self.order, 1))  # (K, 3, order)
        e = self._exps
        return pw[:, 0, e[:, 0]] * pw[:, 1, e[:, 1]] * pw[:, 2, e[:, 2]]

    def rotate(self, R) -> torch.Tensor:
        """Coefficients of the rotated function ``f(R^T w)``.

        Parameters
        ----------
        R : (3, 3) rotation, tensor (any device) or array

        Returns
        -------
        (order**2,) or (order**2, C) float64 on the CPU, as ``coeffs``
        """
        r = R.detach().cpu().numpy() if isinstance(R, torch.Tensor) else np.asarray(R)
        rn = self._nodes @ r.astype(np.float64)  # (M, 3) rows p^T R = (R^T p)^T
        return torch.from_numpy(self._bw_t @ (self._monomials(rn) @ self._pc))


# ----------------------------------------------------------------------------------------------
# zonal functions and convolution


@dispatch
def zonal_convolve(coeffs, zonal):
    """Convolve an SH expansion with a zonal kernel (Funk–Hecke).

    ``(f * k)(w) = integral f(v) k(w . v) dv`` has coefficients
    ``sqrt(4 pi / (2l + 1)) k_l f_lm``, with ``k_l`` the zonal coefficients of ``k`` about +Z
    (as returned by :func:`sg_zonal` or :func:`clamped_cosine_zonal`).

    Parameters
    ----------
    coeffs : (order**2,) or (order**2, C)
    zonal : (..., L) zonal coefficients, L >= order (extra bands are ignored); leading axes give
        a batch of kernels (e.g. one per prefilter sharpness)

    Returns
    -------
    (..., order**2) or (..., order**2, C), dtype of ``coeffs``.
    """
    coeffs, zonal = as_tensor(coeffs), as_tensor(zonal)
    order = _check_coeffs(coeffs)
    if zonal.ndim < 1 or zonal.shape[-1] < order:
        raise InputError(
            "zonal", f"needs at least {order} bands on its last axis, got {tuple(zonal.shape)}"
        )
    dev = coeffs.device
    l_idx = _band_index(order, device=dev)  # (n2,)
    wd = _work_dtype(dev)
    ls = torch.arange(order, device=dev, dtype=wd)
    k = zonal.to(device=dev, dtype=wd)[..., :order] * torch.sqrt(4 * math.pi / (2 * ls + 1))
    per_coeff = k[..., l_idx]  # (..., n2)
    if coeffs.ndim == 2:
        per_coeff = per_coeff.unsqueeze(-1)  # (..., n2, 1)
    return (per_coeff * coeffs.to(wd)).to(_float_dtype(coeffs))


def _legendre_table(t: torch.Tensor, order: int) -> torch.Tensor:
    """Legendre polynomials ``P_l(t)``, l = 0 .. order-1: (...) -> (..., order)."""
    p = [torch.ones_like(t)]
    if order > 1:
        p.append(t)
    for l in range(2, order):
        p.append(((2 * l - 1) * t * p[-1] - (l - 1) * p[-2]) / l)
    return torch.stack(p, -1)


@dispatch
def sg_zonal(lam, order, *, dtype=None, device=None):
    """Zonal SH coefficients of the spherical Gaussian ``exp(lam (cos(theta) - 1))`` about +Z.

    ``z_l = 2 pi sqrt((2l+1)/(4 pi)) integral_{-1}^{1} exp(lam (t - 1)) P_l(t) dt``, which equals
    ``sqrt(4 pi (2l+1)) e^{-lam} i_l(lam)`` (modified spherical Bessel ``i_l``). It is computed by
    Gauss–Legendre quadrature in float64 over ``t in [1 - min(2, 50/lam), 1]`` (the lobe decays by
    ``e^{-50}`` outside), with the exponent formed directly as ``-lam (1 - t)``, so it neither
    overflows nor loses the peak for lam up to 1e4 and beyond. ``lam = 0`` gives the constant 1.
    Accuracy is absolute, relative to ``z_0``: bands whose coefficient is far below
    ``1e-16 z_0`` come out as rounding noise of that size.

    Parameters
    ----------
    lam : (...) sharpness >= 0 (array, tensor or Python number)
    order : int >= 1
    dtype, device : for Python-number ``lam`` (default float32 on the CPU); tensors keep theirs

    Returns
    -------
    (..., order)
    """
    order = _check_order(order)
    lam = as_tensor(lam, dtype=dtype, device=device)
    out_dtype = _float_dtype(lam)
    wd = _work_dtype(lam.device)
    lam64 = lam.to(wd)
    if not bool(torch.isfinite(lam64).all()) or bool((lam64 < 0).any()):
        raise InputError("lam", "must be finite and >= 0")
    x, w = np.polynomial.legendre.leggauss(order + _SG_EXTRA_NODES)
    x = torch.as_tensor(x, device=lam.device, dtype=wd)
    w = torch.as_tensor(w, device=lam.device, dtype=wd)
    # width of the integration interval ending at t = 1; lam = 0 gives inf -> the whole [-1, 1]
    width = torch.clamp(_SG_TAIL / lam64, max=2.0).unsqueeze(-1)  # (..., 1)
    one_minus_t = width * (1 - x) / 2  # (..., Q)
    f = torch.exp(-lam64.unsqueeze(-1) * one_minus_t) * (w * width / 2)  # (..., Q)
    p = _legendre_table(1 - one_minus_t, order)  # (..., Q, order)
    ls = torch.arange(order, device=lam.device, dtype=wd)
    norm = 2 * math.pi * torch.sqrt((2 * ls + 1) / (4 * math.pi))
    return ((f.unsqueeze(-1) * p).sum(-2) * norm).to(out_dtype)


def clamped_cosine_zonal(order, *, dtype=torch.float32, device=None):
    """Zonal SH coefficients of ``max(cos(theta), 0)`` about +Z (the diffuse transfer kernel).

    ``z_l = 2 pi sqrt((2l+1)/(4 pi)) integral_0^1 t P_l(t) dt``, by Gauss–Legendre quadrature that
    is exact for the polynomial integrand. ``sqrt(4 pi/(2l+1)) z_l`` are Ramamoorthi and
    Hanrahan's ``A_l`` = pi, 2 pi/3, pi/4, 0, -pi/24, ...

    Parameters
    ----------
    order : int >= 1
    dtype, device : of the result

    Returns
    -------
    (order,) tensor
    """
    order = _check_order(order)
    x, w = np.polynomial.legendre.leggauss(order // 2 + 2)  # exact to degree order + 2
    t = torch.as_tensor((x + 1) / 2, dtype=torch.float64)
    p = _legendre_table(t, order)  # (Q, order)
    integral = (torch.as_tensor(w / 2 * (x + 1) / 2, dtype=torch.float64)[:, None] * p).sum(0)
    ls = torch.arange(order, dtype=torch.float64)
    z = 2 * math.pi * torch.sqrt((2 * ls + 1) / (4 * math.pi)) * integral
    return z.to(dtype=dtype, device=device)


@dispatch
def zonal_to_sh(zonal, axis):
    """SH coefficients of a zonal function turned to point along ``axis``.

    A function ``k(a . w)`` with zonal coefficients ``k_l`` about +Z has coefficients
    ``sqrt(4 pi/(2l+1)) k_l Y_lm(a)`` (addition theorem).

    Parameters
    ----------
    zonal : (..., order) zonal coefficients
    axis : (..., 3) lobe axes (normalised here); leading axes broadcast with ``zonal``'s

    Returns
    -------
    (..., order**2) in the dtype of ``zonal``.
    """
    zonal, axis = as_tensor(zonal), as_tensor(axis)
    check_directions(axis, "axis")
    if zonal.ndim < 1:
        raise InputError("zonal", "must have a band axis (..., order)")
    order = zonal.shape[-1]
    dev = zonal.device
    y = basis(axis.to(device=dev, dtype=_work_dtype(dev)), order)  # (..., n2)
    ls = torch.arange(order, device=dev, dtype=y.dtype)
    k = zonal.to(y.dtype) * torch.sqrt(4 * math.pi / (2 * ls + 1))  # (..., order)
    out = k[..., _band_index(order, device=dev)] * y  # (..., n2)
    return out.to(_float_dtype(zonal))
