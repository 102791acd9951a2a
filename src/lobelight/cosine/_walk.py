"""The visibility quad-tree walked point by point, compiled by numba (CPU only).

:func:`~._visibility.shadow_leaves` builds the masks of all points level by level over flat
lists of (cell, occluder) pairs, which suits a GPU. On a CPU that form is bound by memory
traffic, not arithmetic, even fused by TorchInductor: every level gathers each pair's cell and
cone, scatters its results back to the cells and writes the next level's lists
(docs/cosine-lobes.md). Walked depth-first
per point, a point's cones, its current cell and the occluders still in play stay in
registers and L1 cache, and nothing but the leaves' cells is written.

The tests are :mod:`._visibility`'s (clip, cones, covered, touched, subdivide), computed in
float64 and without roots where squares compare exactly; they find the same cells as the flat
lists run in float64 (tested). Two shortcuts change the work, not the result: a cell's bounding
cap is computed only when a touch test needs it, and in aggressive mode the children of a cell
one level above the last are tested together on the 3 x 3 corners they share (only covered
cells count there). A point's useful depth (:func:`~._visibility.useful_depth`: below it every
product would fall under the shading's threshold) ends its walk early, that level then playing
the last level's part. Leaves come out grouped by point (the flat lists group them by depth);
shading sums over them, so the order does not matter. Their lobes are built afterwards in torch
(:meth:`~._visibility.Leaves.geometry`), vectorised.

Each point is walked once, keeping its first ``_ROOM`` leaves in a fixed slot of a scratch
buffer (parallel writes never collide); a pass then moves them to their final rows. The few
points with more leaves are walked a second time straight into theirs. numba compiles the walk
on first use and caches it on disk (``cache=True``).
"""

from __future__ import annotations

import math

import numpy as np
import torch

try:  # optional: without numba the flat-list walk runs everywhere
    import numba as _nb
except ImportError:  # pragma: no cover - numba is a dependency; kept optional for source builds
    _nb = None

__all__ = ["available", "walk_leaves"]

_prange = _nb.prange if _nb is not None else range


def available() -> bool:
    """Whether the compiled walk can run (numba importable)."""
    return _nb is not None


def _njit(**kw):
    """numba's njit, cached on disk; ``error_model="numpy"`` drops the per-division zero
    checks of the default (the divisors here are never 0), fastmath lets LLVM vectorise."""

    def deco(fn):
        if _nb is None:
            return fn
        return _nb.njit(cache=True, fastmath=True, error_model="numpy", **kw)(fn)

    return deco


@_njit()
def _cones(x, t, b, a, light_dist, span, spheres_t, exclude, ok, out):
    """The occluders that may block one point's square and their cones, as
    :func:`~._visibility._clip` and :func:`~._visibility._pair_cones`.

    x, t, b, a : (3,) the point and its light frame;  light_dist, span : floats
    spheres_t : (4, N) occluders, one row per coordinate (so that the test loop vectorises)
    exclude : sphere index to ignore (-1: none);  ok : (N,) bool scratch
    out : (N, 5) written with ``(ox, oy, oz, cos phi, sin phi)`` of the kept occluders
    Returns how many were kept.
    """
    # the square's corner angle r0; an occluder of angular radius phi whose centre is at the
    # angle g from the axis can reach the square iff g < phi + r0 (both below pi/2), tested as
    # cos g > cos(phi + r0), times the distance: along > sqrt(d^2 - r^2) cos r0 - r sin r0
    r0 = math.atan(span * math.sqrt(2.0))
    cos_r0, sin_r0 = math.cos(r0), math.sin(r0)
    N = spheres_t.shape[1]
    sx, sy, sz, sr = spheres_t[0], spheres_t[1], spheres_t[2], spheres_t[3]
    for s in range(N):  # branch-free: SIMD
        dx, dy, dz, rad = sx[s] - x[0], sy[s] - x[1], sz[s] - x[2], sr[s]
        along = dx * a[0] + dy * a[1] + dz * a[2]
        d2 = dx * dx + dy * dy + dz * dz
        tangent = math.sqrt(max(d2 - rad * rad, 0.0))  # distance to the occluder's outline
        ok[s] = (
            (along - rad < light_dist)  # not behind the light
            & (d2 > rad * rad)  # the point is outside the occluder
            & (along > tangent * cos_r0 - rad * sin_r0)  # in the square's cone
        )
    if 0 <= exclude < N:
        ok[exclude] = False
    n = 0
    for s in range(N):
        if ok[s]:
            dx, dy, dz = sx[s] - x[0], sy[s] - x[1], sz[s] - x[2]
            dn = math.sqrt(dx * dx + dy * dy + dz * dz)
            sin_phi = min(sr[s] / dn, 1.0)
            out[n, 0] = (dx * t[0] + dy * t[1] + dz * t[2]) / dn
            out[n, 1] = (dx * b[0] + dy * b[1] + dz * b[2]) / dn
            out[n, 2] = (dx * a[0] + dy * a[1] + dz * a[2]) / dn
            out[n, 3] = math.sqrt(max(1.0 - sin_phi * sin_phi, 0.0))
            out[n, 4] = sin_phi
            n += 1
    return n


@_njit()
def _inside(x, y, ox, oy, oz, cp2):
    """Whether the direction ``(x, y, 1)`` lies in the cone ``(o, phi)``: ``c . o >= 0`` and
    ``(c . o)^2 >= cos^2(phi) |c|^2`` (``cos phi >= 0``; no root)."""
    c = x * ox + y * oy + oz
    return c >= 0.0 and c * c >= cp2 * (1.0 + x * x + y * y)


@_njit()
def _covered_children(x0, y0, dx, lists, row, npart, cones):
    """Bit ``c`` set: child ``c`` of the cell ``(x0, y0, dx)`` (tangent-plane centre and
    half-size; children in the order (-,-), (+,-), (-,+), (+,+)) lies in one of the cones
    ``lists[row, :npart]`` (a row index, not a row view: views cost reference counting). The
    children's 16 corners are 9 points, each tested once per cone."""
    xa, xb = x0 - dx, x0 + dx
    ya, yb = y0 - dx, y0 + dx
    mask = 0
    for q in range(npart):
        o = lists[row, q]
        ox, oy, oz, cp2 = cones[o, 0], cones[o, 1], cones[o, 2], cones[o, 3] * cones[o, 3]
        # the 3 x 3 corners, row by row in y
        i00, i10, i20 = (
            _inside(xa, ya, ox, oy, oz, cp2),
            _inside(x0, ya, ox, oy, oz, cp2),
            _inside(xb, ya, ox, oy, oz, cp2),
        )
        i01, i11, i21 = (
            _inside(xa, y0, ox, oy, oz, cp2),
            _inside(x0, y0, ox, oy, oz, cp2),
            _inside(xb, y0, ox, oy, oz, cp2),
        )
        i02, i12, i22 = (
            _inside(xa, yb, ox, oy, oz, cp2),
            _inside(x0, yb, ox, oy, oz, cp2),
            _inside(xb, yb, ox, oy, oz, cp2),
        )
        if i00 and i10 and i01 and i11:
            mask |= 1
        if i10 and i20 and i11 and i21:
            mask |= 2
        if i01 and i11 and i02 and i12:
            mask |= 4
        if i11 and i21 and i12 and i22:
            mask |= 8
        if mask == 15:
            break
    return mask


@_njit()
def _bounding_cap(x0, y0, dx):
    """Cosine and sine of the bounding cap's radius of the cell ``(x0, y0, dx)``, and
    ``1 / |(x0, y0, 1)|``.

    The radius as :func:`~._visibility._cap_tan2` (the largest corner angle, ``tan^2 =
    |m x c|^2 / (m . c)^2``), with one division: the corners (-,-) and (+,+) share
    ``|m x c|^2 = t1``, and (+,-) and (-,+) share ``t2``; of each pair the one with the smaller
    ``m . c`` (``d1, d2 > 0``) is the farther.
    """
    r2 = 1.0 + x0 * x0 + y0 * y0
    xpy, xmy = x0 + y0, x0 - y0
    t1 = dx * dx * (2.0 + xmy * xmy)
    t2 = dx * dx * (2.0 + xpy * xpy)
    d1 = r2 - dx * abs(xpy)
    d2 = r2 - dx * abs(xmy)
    if t1 * d2 * d2 >= t2 * d1 * d1:
        cross2, dot = t1, d1
    else:
        cross2, dot = t2, d2
    inv = 1.0 / math.sqrt(dot * dot + cross2)
    return dot * inv, math.sqrt(cross2) * inv, 1.0 / math.sqrt(r2)


@_njit()
def _test_cell(x0, y0, dx, lists, level, nk, cones):
    """Test the cell ``(x0, y0, dx)`` (tangent-plane centre and half-size) against the cones
    ``lists[level, :nk]``: whether one of them covers it, and how many touch it (those are
    written to ``lists[level + 1]``, the list of its children, and are meaningful only if it is
    not covered). Returns ``(covered, npart)``."""
    xa, xb, ya, yb = x0 - dx, x0 + dx, y0 - dx, y0 + dx  # the corners' coordinates
    # squared lengths of the corner directions (x, y, 1), corners in the order (-,-),
    # (+,-), (-,+), (+,+); the tests below compare squares, so no root per corner
    n0 = 1.0 + xa * xa + ya * ya
    n1 = 1.0 + xb * xb + ya * ya
    n2 = 1.0 + xa * xa + yb * yb
    n3 = 1.0 + xb * xb + yb * yb
    cap = False  # the bounding cap, computed when a touch test first needs it
    cos_rad = sin_rad = inv_m = 0.0
    npart = 0
    for q in range(nk):
        o = lists[level, q]
        ox, oy, oz = cones[o, 0], cones[o, 1], cones[o, 2]
        cos_phi, sin_phi = cones[o, 3], cones[o, 4]
        base = x0 * ox + y0 * oy + oz
        ex, ey = dx * ox, dx * oy
        # a corner c is in the cone iff c . o >= cos(phi) |c|, i.e. c . o >= 0 and
        # (c . o)^2 >= cos^2(phi) |c|^2 (cos phi >= 0)
        cp2 = cos_phi * cos_phi
        c0, c1 = base - ex - ey, base + ex - ey
        c2, c3 = base - ex + ey, base + ex + ey
        if (
            c0 >= 0.0 and c1 >= 0.0 and c2 >= 0.0 and c3 >= 0.0
            and c0 * c0 >= cp2 * n0 and c1 * c1 >= cp2 * n1
            and c2 * c2 >= cp2 * n2 and c3 * c3 >= cp2 * n3
        ):  # fmt: skip
            return True, npart
        if not cap:
            cos_rad, sin_rad, inv_m = _bounding_cap(x0, y0, dx)
            cap = True
        if base * inv_m > cos_phi * cos_rad - sin_phi * sin_rad:  # touched
            # the next level's list (depth + 2 rows): used only if this cell is subdivided
            lists[level + 1, npart] = o
            npart += 1
    return False, npart


@_njit()
def _walk_point(
    p, points, t, b, a, light_dist, span, spheres_t, exclude, last, depth, conservative, start,
    limit, leaf_u, leaf_v, leaf_level, ok, cones, lists, nlist, su, sv, sl, halves,
):  # fmt: skip
    """Walk one point's quad-tree depth-first; write its first ``limit`` leaves' square
    coordinates and depths to rows ``start...`` of ``leaf_u``, ``leaf_v``, ``leaf_level``.

    ``last[p]`` (<= depth) is the point's deepest useful level (-1: none): below it nothing is
    built, and at it only covered cells count (as at an aggressive mask's last level).
    Returns the number of leaves (all of them, also past ``limit``). Scratch (a lane's, reused
    point after point): ok (N,), cones (N, 5), lists (depth + 2, N), nlist (depth + 2,), the
    stack su, sv, sl (4 depth + 5,); halves (depth + 2,) the cells' half-size per level.
    The children of a subdivided cell share one list of the occluders that touched it
    (``lists[level + 1]``): a depth-first walk finishes a cell's subtree before it reaches the
    cell's next sibling, the only other writer of that list.
    """
    final = min(last[p], depth)
    if final < 0:
        return 0
    # only covered cells count at the last level built: aggressive, or cut short of depth
    only_covered = not conservative or final < depth
    nk = _cones(
        points[p], t[p], b[p], a[p], light_dist[p], span[p], spheres_t, exclude[p], ok, cones
    )
    if nk == 0:
        return 0
    kk = 2.0 * span[p]
    for q in range(nk):
        lists[0, q] = q
    nlist[0] = nk
    su[0], sv[0], sl[0] = 0.0, 0.0, 0
    sp = 1
    count = 0
    while sp > 0:
        sp -= 1
        u, v, level = su[sp], sv[sp], sl[sp]
        h = halves[level]
        x0, y0, dx = kk * u, kk * v, kk * h
        covered, npart = _test_cell(x0, y0, dx, lists, level, nlist[level], cones)
        leaf = covered or (npart > 0 and level == depth and conservative)
        if leaf:
            if count < limit:
                leaf_u[start + count] = u
                leaf_v[start + count] = v
                leaf_level[start + count] = level
            count += 1
        elif npart > 0 and level + 1 == final and only_covered:
            # the children are the last level, where only covered cells count: test them here,
            # on the 3 x 3 corners they share, rather than one by one
            mask = _covered_children(x0, y0, dx, lists, level + 1, npart, cones)
            hh = 0.5 * h
            for c in range(4):
                if mask & (1 << c):
                    if count < limit:
                        leaf_u[start + count] = u + (hh if c & 1 else -hh)
                        leaf_v[start + count] = v + (hh if c & 2 else -hh)
                        leaf_level[start + count] = level + 1
                    count += 1
        elif npart > 0 and level < final:
            nlist[level + 1] = npart
            hh = 0.5 * h
            # pushed in reverse so that they pop in the flat lists' child order
            sl[sp : sp + 4] = level + 1
            su[sp + 3], sv[sp + 3] = u - hh, v - hh
            su[sp + 2], sv[sp + 2] = u + hh, v - hh
            su[sp + 1], sv[sp + 1] = u - hh, v + hh
            su[sp], sv[sp] = u + hh, v + hh
            sp += 4
    return count


_BLOCK = 16  # points dealt to a lane at a time
_LANES = 64  # parallel tasks; each allocates its scratch once
_ROOM = 64  # leaves kept per point by the first walk: a few times a typical point's count


@_njit(parallel=True)
def _walk_all(
    points, t, b, a, light_dist, span, spheres_t, exclude, last, depth, conservative, limit,
    leaf_u, leaf_v, leaf_level, fixed,
):  # fmt: skip
    """Walk every point (its leaves to rows ``p * limit...``, or to ``fixed[p]...`` where
    ``fixed[p] >= 0``: a second walk of the points that had more than ``limit``). Returns the
    leaf count of every point, (P,)."""
    P, N = points.shape[0], spheres_t.shape[1]
    counts = np.zeros(P, dtype=np.int64)
    blocks = (P + _BLOCK - 1) // _BLOCK
    # blocks dealt round-robin to the lanes: shadows are spatially coherent, so contiguous
    # halves of the points carry unequal work
    lanes = min(blocks, _LANES)
    for lane in _prange(lanes):
        ok = np.empty(N, dtype=np.bool_)
        cones = np.empty((N, 5))
        lists = np.empty((depth + 2, N), dtype=np.int64)
        nlist = np.zeros(depth + 2, dtype=np.int64)
        top = 4 * depth + 5
        su, sv = np.empty(top), np.empty(top)
        sl = np.empty(top, dtype=np.int64)
        halves = np.empty(depth + 2)  # a cell's half-size per level (no division per cell)
        for lv in range(depth + 2):
            halves[lv] = 0.5 / (1 << lv)
        for blk in range(lane, blocks, lanes):
            for p in range(blk * _BLOCK, min(P, (blk + 1) * _BLOCK)):
                if fixed.shape[0] and fixed[p] < 0:
                    continue
                start, room = (p * limit, limit) if not fixed.shape[0] else (fixed[p], 1 << 62)
                counts[p] = _walk_point(
                    p, points, t, b, a, light_dist, span, spheres_t, exclude, last, depth,
                    conservative, start, room, leaf_u, leaf_v, leaf_level, ok, cones, lists,
                    nlist, su, sv, sl, halves,
                )  # fmt: skip
    return counts


@_njit(parallel=True)
def _gather(counts, offsets, limit, leaf_u, leaf_v, leaf_level, out_point, out_u, out_v, out_level):
    """Leaves from the first walk's rows (``p * limit...``) to their final rows (``offsets``);
    points with more than ``limit`` leaves were walked again straight into theirs."""
    P = counts.shape[0]
    for blk in _prange((P + _BLOCK - 1) // _BLOCK):
        for p in range(blk * _BLOCK, min(P, (blk + 1) * _BLOCK)):
            n, o = counts[p], offsets[p]
            for r in range(n):
                out_point[o + r] = p
            if n <= limit:
                for r in range(n):
                    out_u[o + r] = leaf_u[p * limit + r]
                    out_v[o + r] = leaf_v[p * limit + r]
                    out_level[o + r] = leaf_level[p * limit + r]


def walk_leaves(
    points, t, b, a, light_dist, span, spheres, exclude, last=None, *, depth, conservative
):
    """Shadow leaves of all points, walked per point (module docstring).

    Each point is walked once, keeping up to ``_ROOM`` leaves; the few points with more are
    walked again straight into their final rows, so memory stays ``O(P * _ROOM + L)``.

    Parameters
    ----------
    points, t, b, a : (P, 3) CPU tensors, the points and their light frames
    light_dist, span : (P,) distance to the light, half-width of the square (tangent units)
    spheres : (N, 4);  exclude : (P,) int64 (-1: none)
    last : optional (P,) int64, each point's deepest useful level (-1: none; default: depth;
        :func:`~._visibility.useful_depth`)
    depth : maximal depth;  conservative : keep partly covered cells of the last level

    Returns
    -------
    point (L,) int64, depth (L,) int64, and the leaves' centres in square coordinates u (L,),
    v (L,) float32 (multiples of ``2^-(depth + 1)``: exact), grouped by point; the leaf count
    of every point (P,) int64
    """
    f64 = [np.ascontiguousarray(z.detach().cpu().numpy(), dtype=np.float64)
           for z in (points, t, b, a, light_dist, span, spheres.T)]  # fmt: skip
    ex = np.ascontiguousarray(exclude.detach().cpu().numpy(), dtype=np.int64)
    P = points.shape[0]
    if last is None:
        lim = np.full(P, int(depth), dtype=np.int64)
    else:
        lim = np.ascontiguousarray(last.detach().cpu().numpy(), dtype=np.int64)
    args = (*f64, ex, lim, int(depth), bool(conservative))
    leaf_u, leaf_v = np.empty(P * _ROOM, np.float32), np.empty(P * _ROOM, np.float32)
    leaf_level = np.empty(P * _ROOM, dtype=np.int8)
    counts = _walk_all(*args, _ROOM, leaf_u, leaf_v, leaf_level, np.empty(0, dtype=np.int64))
    offsets = np.zeros(P, dtype=np.int64)
    np.cumsum(counts[:-1], out=offsets[1:])
    L = int(counts.sum())
    out_point = np.empty(L, dtype=np.int64)
    out_u, out_v = np.empty(L, np.float32), np.empty(L, np.float32)
    out_level = np.empty(L, dtype=np.int8)
    big = counts > _ROOM
    if big.any():  # walked again, straight into their rows
        _walk_all(*args, 0, out_u, out_v, out_level, np.where(big, offsets, -1))
    _gather(counts, offsets, _ROOM, leaf_u, leaf_v, leaf_level, out_point, out_u, out_v, out_level)
    return (
        torch.from_numpy(out_point),
        torch.from_numpy(out_level).long(),
        torch.from_numpy(out_u),
        torch.from_numpy(out_v),
        torch.from_numpy(counts),
    )
