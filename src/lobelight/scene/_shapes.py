"""Procedural geometry for the built-in scenes: torus knot, ground plane, sphere.

Everything is generated from grids (``meshgrid`` and index arithmetic), so the built-in scenes
need no files and any tessellation is one argument away.
"""

from __future__ import annotations

import math

import numpy as np

from ._mesh import _trimesh

__all__ = ["ground_plane", "icosphere", "torus_knot", "uv_sphere"]


def _grid_faces(nu: int, nv: int, *, wrap_u: bool, wrap_v: bool) -> np.ndarray:
    """Two triangles per cell of an ``nu x nv`` vertex grid (index ``i * nv + j``), ``(F, 3)``."""
    cu = nu if wrap_u else nu - 1
    cv = nv if wrap_v else nv - 1
    i, j = np.meshgrid(np.arange(cu), np.arange(cv), indexing="ij")
    i, j = i.reshape(-1), j.reshape(-1)
    i1, j1 = (i + 1) % nu, (j + 1) % nv
    a, b, c, d = i * nv + j, i1 * nv + j, i1 * nv + j1, i * nv + j1
    return np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def torus_knot(
    p: int = 2, q: int = 3, *, radius: float = 1.0, tube: float = 0.28, nu: int = 256, nv: int = 24
) -> tuple[np.ndarray, np.ndarray]:
    """A (p, q) torus knot tube, symmetry axis +Y, centred at the origin.

    The centre curve is ``((R + r cos q t) cos p t, -r sin q t, (R + r cos q t) sin p t)`` with
    ``R = radius``, ``r = radius / 2``, swept by a circle of radius ``tube`` in the curve's
    Frenet frame (its curvature never vanishes, so the frame is smooth and closes on itself).

    Returns
    -------
    vertices : (nu * nv, 3);  faces : (2 nu nv, 3), outward-facing
    """
    t = np.linspace(0, 2 * math.pi, nu, endpoint=False)
    big, small = radius, radius / 2

    def curve(t):
        rr = big + small * np.cos(q * t)
        return np.stack([rr * np.cos(p * t), -small * np.sin(q * t), rr * np.sin(p * t)], -1)

    h = 1e-4
    c = curve(t)
    d1 = (curve(t + h) - curve(t - h)) / (2 * h)
    d2 = (curve(t + h) - 2 * c + curve(t - h)) / (h * h)
    tang = d1 / np.linalg.norm(d1, axis=1, keepdims=True)
    nrm = d2 - (d2 * tang).sum(1, keepdims=True) * tang
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    bin_ = np.cross(tang, nrm)
    phi = np.linspace(0, 2 * math.pi, nv, endpoint=False)
    ring = np.cos(phi)[None, :, None] * nrm[:, None] + np.sin(phi)[None, :, None] * bin_[:, None]
    v = (c[:, None] + tube * ring).reshape(-1, 3)
    f = _grid_faces(nu, nv, wrap_u=True, wrap_v=True)
    # orientation: the ring's (nrm, bin) turn with the tangent; flip if the faces point inward
    centre = v[f].mean(1)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    axis_pt = np.repeat(c, nv, axis=0)[f[:, 0]]
    if float(((centre - axis_pt) * fn).sum()) < 0:
        f = f[:, ::-1].copy()
    return v, f


def ground_plane(size: float, y: float, *, n: int = 48) -> tuple[np.ndarray, np.ndarray]:
    """A square ``size`` wide at height ``y``, ``n x n`` vertices, facing +Y."""
    s = np.linspace(-size / 2, size / 2, n)
    x, z = np.meshgrid(s, s, indexing="ij")
    v = np.stack([x, np.full_like(x, y), z], -1).reshape(-1, 3)
    f = _grid_faces(n, n, wrap_u=False, wrap_v=False)
    return v, f[:, ::-1].copy()  # (i, j) = (x, z) grid: reversed winding faces +Y


def uv_sphere(n_lat: int = 32, n_lon: int = 64, radius: float = 1.0):
    """Latitude-longitude sphere (poles are single vertices), outward faces."""
    theta = np.linspace(0, math.pi, n_lat + 1)[1:-1]
    phi = np.linspace(0, 2 * math.pi, n_lon, endpoint=False)
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    ring = np.stack([np.sin(th) * np.cos(ph), np.cos(th), -np.sin(th) * np.sin(ph)], -1)
    v = np.concatenate([[[0, 1, 0]], ring.reshape(-1, 3), [[0, -1, 0]]]) * radius
    body = _grid_faces(n_lat - 1, n_lon, wrap_u=False, wrap_v=True) + 1
    k = np.arange(n_lon)
    top = np.stack([np.zeros(n_lon, int), 1 + k, 1 + (k + 1) % n_lon], 1)
    last = 1 + (n_lat - 2) * n_lon
    bot = np.stack([np.full(n_lon, len(v) - 1), last + (k + 1) % n_lon, last + k], 1)
    f = np.concatenate([top, body, bot])
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    if float((fn * v[f].mean(1)).sum()) < 0:
        f = f[:, ::-1].copy()
    return v, f


def icosphere(subdivisions: int = 3, radius: float = 1.0):
    """Geodesic sphere (trimesh's subdivided icosahedron), ``10 * 4^s + 2`` vertices."""
    m = _trimesh().creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(m.vertices), np.asarray(m.faces)
