"""Which triangle lies across each edge of a triangle mesh.

A mesh's vertices are often split where its normals, UVs or patches change (a scanned mesh's
seams, the Utah teapot's Bezier patches): two triangles that meet there share no vertex index,
though they share an edge in space. Edges are therefore matched by their corners' positions:
vertices at the same position count as one.
"""

from __future__ import annotations

import numpy as np

__all__ = ["encloses_outward", "face_neighbours"]


def _welded_corners(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, int]:
    """The triangles' corners ``(F, 3)`` as indices of the distinct positions (vertices equal
    in every coordinate are one), and how many distinct positions there are."""
    _, weld = np.unique(np.asarray(vertices), axis=0, return_inverse=True)
    weld = weld.reshape(-1)
    return weld[faces], int(weld.max()) + 1


def face_neighbours(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The triangle across each triangle's edges: ``(F, 3)`` int32, entry ``(f, i)`` the triangle
    sharing the edge opposite corner ``i`` of triangle ``f`` (its corners ``i + 1`` and
    ``i + 2``, mod 3), -1 where no other triangle has that edge or more than two have it (a
    boundary, or a non-manifold edge: no one triangle is across it).

    Parameters
    ----------
    vertices : (V, 3) positions; those equal in every coordinate are one vertex here
    faces : (F, 3) vertex indices
    """
    f = np.asarray(faces, np.int64)
    if f.shape[0] == 0:
        return np.zeros((0, 3), np.int32)
    w, n = _welded_corners(vertices, f)
    a, b = w[:, [1, 2, 0]], w[:, [2, 0, 1]]  # the edge opposite each corner
    key = (np.minimum(a, b) * n + np.maximum(a, b)).reshape(-1)  # (3F,)
    order = np.argsort(key, kind="stable")  # slots (3 f + i) by edge
    ks = key[order]
    start = np.r_[True, ks[1:] != ks[:-1]]
    run = np.cumsum(start) - 1  # each slot's edge, in sorted order
    first = np.flatnonzero(start)
    count = np.bincount(run)
    at = np.arange(ks.shape[0])
    # an edge two triangles share: each slot's partner is the other slot of its run
    two = count[run] == 2
    partner = np.where(at == first[run], at + 1, at - 1)
    out = np.full(ks.shape[0], -1, np.int64)
    out[order[two]] = order[partner[two]] // 3
    return out.reshape(-1, 3).astype(np.int32)


def encloses_outward(vertices: np.ndarray, faces: np.ndarray) -> bool:
    """Whether the mesh is a closed surface wound outward: once its vertices equal in every
    coordinate are one, every edge is used once in each direction by the triangles' corner
    order (watertight, consistently wound, no edge of three triangles), no triangle has two
    corners at one point, and the volume it encloses is positive (counter-clockwise seen from
    outside). Then from any viewpoint outside it a triangle seen from behind lies behind
    another one, and a rasteriser may leave such triangles out (back-face culling).
    ``vertices (V, 3)``, ``faces (F, 3)``. Hand-written, as :func:`face_neighbours`: a
    render's start calls it, and importing trimesh for it would cost that start more than the
    check."""
    f = np.asarray(faces, np.int64)
    if f.shape[0] == 0:
        return False
    w, n = _welded_corners(vertices, f)
    a, b = w.reshape(-1), w[:, [1, 2, 0]].reshape(-1)  # each triangle's directed edges a -> b
    if bool((a == b).any()):
        return False
    fwd = np.sort(a * n + b)
    if bool((fwd[1:] == fwd[:-1]).any()):  # an edge used twice the same way
        return False
    rev = b * n + a
    at = np.searchsorted(fwd, rev).clip(max=fwd.shape[0] - 1)
    if not bool((fwd[at] == rev).all()):  # an edge used one way only: a boundary
        return False
    p = np.asarray(vertices, np.float64)[f]
    volume = float(np.einsum("ij,ij->", p[:, 0], np.cross(p[:, 1], p[:, 2]))) / 6.0
    return volume > 0.0
