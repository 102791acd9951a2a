"""Visibility as cosine lobes: the paper's hierarchical visibility mask (its section 5.3).

For a point ``x`` and a spherical light seen as the cap ``(h, theta)``, a square ``S_unit`` of
side 1 is placed facing the light at the distance ``dist = 0.5 / tan(margin theta)`` from
``x``, so that it surrounds the cap's cone (``margin = 1`` is the paper's). A point ``(u, v)``
of the square, ``|u|, |v| <= 1/2``, is the direction ``normalise(h + 2 span (u t + v b))``
with ``span = 1 / (2 dist)`` and ``(t, b)`` a frame around ``h``: a gnomonic projection, which
maps straight lines to great circles.

Occluders are spheres. Those that cannot block the square are clipped (behind the light, not
overlapping the square's cone, containing ``x``, or the point's own sphere), the rest are
"splatted": each quad-tree cell is tested against the cone ``(o, phi)`` that a sphere
subtends from ``x``, ``phi = asin(radius / distance)``.

* **covered**: all four corners of the cell lie in one occluder's cone. This test is exact:
  the cell is a geodesic quadrilateral (gnomonic projection) and a cap with ``phi < pi/2`` is
  geodesically convex, so it holds the cell iff it holds its corners. Covered cells are
  shadow leaves (the paper's green leaves), frozen at their depth.
* **touched**: the cell's bounding cap (centre direction, radius the largest corner angle)
  meets an occluder's cone (conservative). Touched, uncovered cells are subdivided into four
  (red); at the maximal depth they are dropped (``mode="aggressive"``, the paper's choice) or
  kept as shadow leaves (``"conservative"``). A cell covered only by the union of several
  cones, and by none alone, is subdivided too.

Each shadow leaf becomes one cap lobe around the centre of its bounding cap (the paper's
bounding sphere of the leaf, Figure 11), with the integral-preserving scale of
:func:`~._light.cap_lobe`. Nearby lobes overlap and a lobe is not a cap, so visibility is
``V = 1 - sum_k w(depth_k, dist) c_k`` (eq. 39) with weights per leaf depth and per ``dist``,
linearly interpolated in ``dist`` between the paper's nodes ``{0.25, 0.5, 1, 2, ..., 10}``.

The weights are calibrated once, as the paper describes, on a single scene (a plane, an
object made of spheres, one light at distances that cover the ``dist`` nodes), and stored in
the package data file ``weights.json`` (:mod:`._calibration` reads it). The paper sets them by
hand, level by level ("first level weight ... perfect dark in the umbra; each successive level
... to avoid shadow sharpness"); the source tree's ``tools/calibrate_cosine_weights.py`` does
the same thing by least squares: the rendered radiance is linear in the weights
(:func:`~._shade.shadow_features`), so all weights of a ``(mode, max depth)`` are fitted at
once against Monte Carlo radiance on that scene (non-negative, lightly regularised towards their
neighbours in ``dist``).

Everything is vectorised over flat lists of (cell, occluder) pairs; only the ``depth + 1``
levels of the tree are a Python loop. The work per level is proportional to the number of
cells that an occluder's outline crosses (penumbra), not to ``4^depth``. Given the shading's
threshold and a bound of the lobes the leaves will multiply, a point's tree stops at the
deepest level whose products can pass the threshold (:func:`useful_depth`): the result is the
same, and a dim light's penumbra costs a fraction of the cells. With fusion on and
on the CPU, the same tree is walked point by point instead, compiled by numba
(:mod:`._walk`: the flat lists' memory traffic is what bounds them there).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch

from .._tol import DIVISOR_F32, DIVISOR_F64
from ..errors import InputError
from ..geometry.sphere import frame
from . import _walk
from ._fused import fusion_enabled, kernel

__all__ = ["DIST_NODES", "MASK_MODES", "Leaves", "leaf_weights", "shadow_leaves"]

#: The paper's distances at which the weights are set (eq. 39 and Figure 12).
DIST_NODES = (0.25, 0.5, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0)
#: The masks' treatment of a cell still partly covered at the maximal depth: dropped
#: ("aggressive", the paper's choice) or kept as a shadow leaf ("conservative").
MASK_MODES = ("aggressive", "conservative")
_MAX_SQUARE_ANGLE = 1.35  # radians: past ~77 degrees the gnomonic square degenerates


class Leaves(NamedTuple):
    """Shadow leaves of all points for one light, as flat lists of quad-tree cells.

    The leaves' lobes are built on demand (:meth:`geometry`, one fused loop): the walk and the
    flat lists write only cells, and the solid angles (four arc tangents per leaf) are skipped
    where the shading does not use them.

    Attributes
    ----------
    point : (L,) int64 index of the shaded point
    depth : (L,) int64 depth of the leaf (0: the whole square)
    u, v : (L,) the leaf cell's centre in square coordinates (``|u|, |v| < 1/2``)
    dist : (P,) the paper's ``dist`` of each point's square
    scale : (P,) square coordinates to tangent-plane coordinates, ``2 tan(margin theta)``
    t, b, a : (P, 3) each point's light frame (``a`` towards the light's centre)
    count : (P,) int64 leaves per point
    grouped : whether the leaves come grouped by point in point order (the per-point walk):
        then per-point sums are segment sums over ``count``
    """

    point: torch.Tensor
    depth: torch.Tensor
    u: torch.Tensor
    v: torch.Tensor
    dist: torch.Tensor
    scale: torch.Tensor
    t: torch.Tensor
    b: torch.Tensor
    a: torch.Tensor
    count: torch.Tensor
    grouped: bool = False

    def geometry(self, *, solid_angle: bool = True):
        """``axis`` (L, 3) unit direction of the centre of each leaf's bounding cap, ``theta``
        (L,) its half-angle and ``omega`` (L,) the cell's exact solid angle
        (:func:`cell_solid_angle`; NaN unless ``solid_angle``)."""
        return _leaf_geometry(
            self.u, self.v, self.depth, self.point, self.scale, self.t, self.b, self.a,
            bool(solid_angle),
        )  # fmt: skip


def _check_spheres(spheres: torch.Tensor) -> None:
    if spheres.ndim != 2 or spheres.shape[-1] != 4:
        raise InputError(
            "spheres", f"must be (N, 4) rows (x, y, z, radius), got {tuple(spheres.shape)}"
        )
    if not bool(torch.isfinite(spheres).all()):
        raise InputError("spheres", "must be finite (NaN or Inf found)")
    if not bool((spheres[:, 3] > 0).all()):
        raise InputError("spheres", "radii must be > 0")


def _corner_signs(like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(4,) signs of the corners (and children) of a cell, ``u`` and ``v``: the order
    (-,-), (+,-), (-,+), (+,+) used throughout the quad-tree."""
    kw = {"dtype": like.dtype, "device": like.device}
    return torch.tensor([-1.0, 1.0, -1.0, 1.0], **kw), torch.tensor([-1.0, -1.0, 1.0, 1.0], **kw)


def shadow_leaves(
    points: torch.Tensor,
    light_axis: torch.Tensor,
    light_theta: torch.Tensor,
    light_dist: torch.Tensor,
    spheres: torch.Tensor,
    *,
    depth: int = 5,
    mode: str = "aggressive",
    margin: float = 1.0,
    exclude: torch.Tensor | None = None,
    peak: torch.Tensor | None = None,
    threshold: float = 0.0,
) -> Leaves:
    """Build the visibility masks of ``P`` points for one light and return their shadow leaves.

    Parameters
    ----------
    points : (P, 3)
    light_axis : (P, 3) unit directions to the light's centre
    light_theta : (P,) the light's cap half-angles;  light_dist : (P,) distances to its centre
    spheres : (N, 4) occluders ``(x, y, z, radius)``
    depth : maximal depth of the quad-tree (the paper: 4-5; leaves of depth ``depth`` are
        ``2^-depth`` of the square's side)
    mode : "aggressive" (drop partly covered cells at the maximal depth) or "conservative"
    margin : the square surrounds the cone of half-angle ``margin * theta``
    exclude : optional (P,) int64 index of a sphere each point must ignore (its own; -1: none)
    peak, threshold : optional (P,) bound of the lobes that the leaves will multiply (their
        largest scale) and the shading's threshold ``t``: cells whose every product is
        certainly below ``t`` are not built (:func:`useful_depth`; the shading culls those
        products anyway, so its result is the same)

    Returns
    -------
    :class:`Leaves`
    """
    if mode not in MASK_MODES:
        raise InputError("mode", f"must be one of {MASK_MODES}, got {mode!r}")
    if not 0 <= int(depth) <= 8:
        raise InputError("depth", f"must be in 0..8, got {depth!r}")
    if not margin > 0:
        raise InputError("margin", f"must be > 0, got {margin!r}")
    dev, dt = points.device, points.dtype
    P = points.shape[0]
    square = (margin * light_theta).clamp(max=_MAX_SQUARE_ANGLE)
    span = torch.tan(square)  # (P,) half-width of the square, in tangent units
    k = 2 * span  # square coordinates (u, v) -> tangent-plane coordinates k (u, v)
    dist = 0.5 / span
    t, b, a = frame(light_axis)
    none_i = torch.zeros(0, dtype=torch.long, device=dev)
    none_f = torch.zeros(0, dtype=dt, device=dev)
    empty = Leaves(none_i, none_i, none_f, none_f, dist, k, t, b, a, points.new_zeros(P).long())
    N = spheres.shape[0]
    if N == 0 or P == 0:
        return empty
    ex = exclude if exclude is not None else torch.full((P,), -1, dtype=torch.long, device=dev)
    last = torch.full((P,), int(depth), dtype=torch.long, device=dev)
    if peak is not None and threshold > 0:
        last = useful_depth(peak, span, float(threshold), int(depth))
    if dev.type == "cpu" and fusion_enabled() and _walk.available():
        # compiled on the CPU: walked per point, depth-first (module _walk: the same tests)
        lp, ld, lu, lv, count = _walk.walk_leaves(
            points, t, b, a, light_dist, span, spheres, ex, last,
            depth=int(depth), conservative=mode == "conservative",
        )  # fmt: skip
        if lp.numel() == 0:
            return empty
        return Leaves(lp, ld, lu.to(dt), lv.to(dt), dist, k, t, b, a, count, grouped=True)
    # ---- clipping: dense (P, N) test, then a flat list of (point, occluder) pairs
    keep = _clip(points, a, light_dist, span, spheres, ex) & (last >= 0).unsqueeze(1)  # (P, N)
    pp, pn = keep.nonzero(as_tuple=True)  # (Q,) pairs
    if pp.numel() == 0:
        return empty
    # per pair: the occluder's unit direction in the light frame and its cone, (Q, 5)
    pq = _pair_cones(points[pp], spheres[pn], t[pp], b[pp], a[pp])
    # ---- the quad-tree, level by level over the flat lists
    cell_pt = torch.arange(P, device=dev)  # (C,) point of each live cell
    cu = torch.zeros(P, dtype=dt, device=dev)
    cv = torch.zeros(P, dtype=dt, device=dev)
    pair_cell = pp  # (Q,) live cell of each pair (at level 0 the cell id is the point id)
    pair_src = torch.arange(pp.numel(), device=dev)  # (Q,) the pair's row of pq
    leaves_pt, leaves_depth, leaves_u, leaves_v = [], [], [], []
    for level in range(int(depth) + 1):
        covered, partial, partial_pair = _cell_tests(
            cu, cv, k, cell_pt, 0.5 / 2**level, pair_cell, pq, pair_src
        )  # (C,), (C,), (Q,)
        # a point's cells below its useful depth are not built; at that depth (short of the
        # maximal one) only covered cells count, as at an aggressive mask's last level
        lim = last[cell_pt]  # (C,)
        final = level == int(depth)
        leaf = covered | partial if (final and mode == "conservative") else covered
        partial = partial & (lim > level)
        partial_pair = partial_pair & partial[pair_cell]
        ids = (leaf & (lim >= level)).nonzero(as_tuple=True)[0]
        if ids.numel():
            leaves_pt.append(cell_pt[ids])
            leaves_depth.append(torch.full((ids.numel(),), level, dtype=torch.long, device=dev))
            leaves_u.append(cu[ids])
            leaves_v.append(cv[ids])
        if final:
            break
        # ---- subdivide the partly covered cells; carry their touching pairs to the children
        parents = partial.nonzero(as_tuple=True)[0]  # (C',)
        if parents.numel() == 0:
            break
        moved = partial_pair.nonzero(as_tuple=True)[0]  # (Q',) pairs that go on
        cu, cv, cell_pt, pair_cell, pair_src = _subdivide(
            cu, cv, cell_pt, partial, parents, 0.25 / 2**level, pair_cell, pair_src, moved
        )
    if not leaves_pt:
        return empty
    lp = torch.cat(leaves_pt)
    ld = torch.cat(leaves_depth)
    lu, lv = torch.cat(leaves_u), torch.cat(leaves_v)
    return Leaves(lp, ld, lu, lv, dist, k, t, b, a, torch.bincount(lp, minlength=P))


def useful_depth(peak: torch.Tensor, span: torch.Tensor, threshold: float, depth: int):
    """The deepest level whose shadow leaves can pass the shading's threshold, per point.

    A leaf's product with a lobe ``m`` (``m <= peak`` everywhere) is ``∫ m c_k <= peak ∫ c_k``,
    and ``∫ c_k`` is at most its bounding cap's solid angle (the scale of
    :func:`~._light.cap_lobe`; the cell's own is smaller). The cap's radius is at most the
    cell's half-diagonal on the tangent plane, ``sqrt(2) span 2^-d`` at level ``d`` (the
    gnomonic map from the plane at distance 1 to the sphere shortens every length), so
    ``∫ c_k <= pi rho^2 = 2 pi span^2 4^-d``. Where twice that bound is below the threshold
    every product of the level is culled, whatever the table's rounding (the factor 2 covers
    its error, a small fraction of an integral), and so is every product below it: those
    cells need not be built. The paper culls products after computing them and finds the
    masks' construction then bounds the frame rate (its Figure 16); this bound culls the
    construction too.

    Parameters
    ----------
    peak : (P,) the largest colour scale of the lobes the leaves multiply (0: all culled)
    span : (P,) the square's half-width in tangent units;  threshold : ``t`` > 0

    Returns
    -------
    (P,) int64 in ``-1..depth`` (-1: not even the whole square can pass)
    """
    bound = (4 * math.pi) * peak.double() * span.double() ** 2 / float(threshold)  # at d = 0
    d = torch.floor(torch.log2(bound.clamp_min(DIVISOR_F64)) / 2)  # 4^d <= bound
    return d.clamp(-1, int(depth)).long()


@kernel
def _clip(points, a, light_dist, span, spheres, exclude):
    """(P, N) bool: the occluders that may block each point's square (module docstring).

    points (P, 3), a (P, 3) unit axis to the light, light_dist (P,), span (P,) the square's
    half-width in tangent units, spheres (N, 4), exclude (P,) int64 (-1: none).
    """
    d = spheres[:, :3].unsqueeze(0) - points.unsqueeze(1)  # (P, N, 3)
    dn = torch.linalg.vector_norm(d, dim=-1)
    rad = spheres[:, 3].unsqueeze(0)
    along = (d * a.unsqueeze(1)).sum(-1)  # (P, N) distance along the light's axis
    cos_g = along / dn.clamp_min(DIVISOR_F32)  # angle between the light and the occluder's centre
    phi = torch.asin((rad / dn.clamp_min(DIVISOR_F32)).clamp(max=1.0))
    reach = phi + torch.atan(span * math.sqrt(2)).unsqueeze(1)  # the square's corner angle
    keep = (dn > rad) & (along - rad < light_dist.unsqueeze(1))
    keep &= cos_g > torch.cos(reach.clamp(max=math.pi))
    ids = torch.arange(spheres.shape[0], device=points.device)
    return keep & (ids.unsqueeze(0) != exclude.unsqueeze(1))


@kernel
def _pair_cones(x, sphere, t, b, a):
    """Per (point, occluder) pair (Q rows of each input): the occluder's unit direction in the
    point's light frame ``(t, b, a)`` and its cone, ``(ox, oy, oz, cos phi, sin phi)``, (Q, 5)."""
    d = sphere[:, :3] - x
    dn = torch.linalg.vector_norm(d, dim=-1, keepdim=True)
    dl = d / dn
    o = torch.stack([(dl * t).sum(-1), (dl * b).sum(-1), (dl * a).sum(-1)], -1)
    sin_phi = (sphere[:, 3:] / dn).clamp(max=1.0)
    cos_phi = torch.sqrt((1 - sin_phi * sin_phi).clamp_min(0))
    return torch.cat([o, cos_phi, sin_phi], -1)


def _cell_tests(cu, cv, k, cell_pt, h: float, pair_cell, pq, pair_src):
    """One level of the quad-tree: which cells are covered and which are partly covered.

    Parameters
    ----------
    cu, cv : (C,) cell centres in square coordinates;  cell_pt : (C,) their points
    k : (P,) each point's square scale;  h : the cells' half-size (the same on a level)
    pair_cell : (Q,) the cell of each (cell, occluder) pair
    pq : (Q0, 5) the occluder cones of the level-0 pairs;  pair_src : (Q,) each pair's row

    Returns
    -------
    covered : (C,) bool, all four corners inside one occluder's cone
    partial : (C,) bool, touched by a cone but not covered (to subdivide)
    partial_pair : (Q,) bool, the pairs that carry on to the children of a partial cell
    """
    # two kernels: per cell, then per pair; one would recompute each cell for each of its pairs
    cells = _cell_bounds(cu, cv, k, cell_pt, h)
    return _pair_tests(cells, pair_cell, pq, pair_src)


@kernel
def _cell_bounds(cu, cv, k, cell_pt, h: float):
    """Per cell (C, 10): centre ``(x0, y0)`` on the tangent plane, half-size ``dx``, ``1/|centre|``,
    cosine and sine of the bounding cap's radius, ``1/|corner|`` of the four corners."""
    # tangent-plane coordinates of the cell's centre (x0, y0) and corners (x0 +- dx,
    # y0 +- dx); a direction is (x, y, 1) / norm, so its dot with an occluder's unit
    # direction o is linear in (x, y): no (pairs, 4, 3) tensors are formed
    kc = k[cell_pt]
    x0, y0, dx = kc * cu, kc * cv, kc * h  # (C,)
    sgn_u, sgn_v = _corner_signs(cu)
    cxs = x0.unsqueeze(-1) + dx.unsqueeze(-1) * sgn_u  # (C, 4)
    cys = y0.unsqueeze(-1) + dx.unsqueeze(-1) * sgn_v
    inv_c = torch.rsqrt(1 + cxs * cxs + cys * cys)  # (C, 4) 1 / |corner|
    inv_m = torch.rsqrt(1 + x0 * x0 + y0 * y0)  # (C,) 1 / |centre|
    # the cell's bounding cap: its radius is the largest corner angle (:func:`_cap_tan2`)
    t2 = _cap_tan2(x0, y0, dx)
    cos_rad = torch.rsqrt(1 + t2)
    sin_rad = torch.sqrt(t2) * cos_rad
    return torch.cat([torch.stack([x0, y0, dx, inv_m, cos_rad, sin_rad], -1), inv_c], -1)


def _cap_tan2(x0, y0, dx):
    """``tan^2`` of the largest angle between a cell's centre direction ``(x0, y0, 1)`` and its
    corners ``(x0 +- dx, y0 +- dx, 1)`` (all (...)): the bounding cap's radius.

    From ``|m x c|^2 / (m . c)^2``, whose cross product has the exact components
    ``(-ey, ex, x0 ey - y0 ex)`` (``ex, ey = +-dx``): well conditioned for small cells, where
    ``1 - cos`` or ``acos`` of a cosine near 1 loses most digits in float32. ``m . c > 0``
    (a cell off the square's centre has ``|x0|, |y0| >= dx``), so ``tan`` grows with the angle.
    """
    t2 = None
    for su, sv in ((-1, -1), (1, -1), (-1, 1), (1, 1)):
        ex, ey = su * dx, sv * dx
        d = 1 + (x0 + ex) * x0 + (y0 + ey) * y0  # m . c
        cz = x0 * ey - y0 * ex
        c2 = (ex * ex + ey * ey + cz * cz) / (d * d)
        t2 = c2 if t2 is None else torch.maximum(t2, c2)
    return t2


@kernel
def _pair_tests(cells, pair_cell, pq, pair_src):
    """:func:`_cell_tests` from :func:`_cell_bounds`'s (C, 10) rows."""
    C = cells.shape[0]
    cell = cells[pair_cell]  # (Q, 10)
    ox, oy, oz, cos_phi, sin_phi = pq[pair_src].unbind(-1)  # (Q,) occluder direction, cone
    x0, y0, dx, inv_m, cos_rad, sin_rad = cell[:, :6].unbind(-1)
    base = x0 * ox + y0 * oy + oz  # (Q,) centre . o, unnormalised
    sgn_u, sgn_v = _corner_signs(cells)
    dots = base.unsqueeze(-1) + (dx * ox).unsqueeze(-1) * sgn_u + (dx * oy).unsqueeze(-1) * sgn_v
    inside = (dots * cell[:, 6:]).amin(-1) >= cos_phi  # (Q,) all four corners in the cone
    # touch: the angle between the cell's centre and the occluder is below phi + radius, as
    # cosines (both angles are below pi/2, so their sum is below pi, where cos decreases)
    touch = base * inv_m > cos_phi * cos_rad - sin_phi * sin_rad
    zeros = cells.new_zeros(C)
    covered = zeros.index_add(0, pair_cell, inside.to(cells.dtype)) > 0
    partial_pair = touch & ~inside & ~covered[pair_cell]
    partial = (zeros.index_add(0, pair_cell, partial_pair.to(cells.dtype)) > 0) & ~covered
    return covered, partial, partial_pair & partial[pair_cell]


@kernel
def _subdivide(cu, cv, cell_pt, partial, parents, hh: float, pair_cell, pair_src, moved):
    """Split the ``parents`` (C',) of the partly covered cells (``partial``, (C,)) into four
    children of half-size ``hh`` each, and hand the ``moved`` (Q',) pairs to all four.

    Returns the children's cu, cv, cell_pt (4 C',) and the pairs' cell and row (4 Q',).
    """
    dev = cu.device
    su, sv = _corner_signs(cu)
    cu2 = (cu[parents].unsqueeze(1) + hh * su).reshape(-1)
    cv2 = (cv[parents].unsqueeze(1) + hh * sv).reshape(-1)
    pt2 = cell_pt[parents].unsqueeze(1).expand(-1, 4).reshape(-1)
    rank = torch.cumsum(partial.long(), 0) - 1  # (C,) new index of a subdivided cell
    pc = rank[pair_cell[moved]]  # (Q',) the parent's new index
    four = torch.arange(4, device=dev)
    cell2 = (4 * pc.unsqueeze(1) + four).reshape(-1)
    src2 = pair_src[moved].unsqueeze(1).expand(-1, 4).reshape(-1)
    return cu2, cv2, pt2, cell2, src2


@kernel
def _leaf_geometry(lu, lv, depth, point, k, t, b, a, solid_angle: bool):
    """World axis (L, 3), bounding-cap half-angle (L,) and solid angle (L,; NaN unless
    ``solid_angle``) of the leaves at square coordinates ``(lu, lv)`` of depth ``depth`` of the
    points ``point`` (all (L,)); ``k`` (P,) and the frames ``t, b, a`` (P, 3) are the points'
    (gathered here, inside the fused loop)."""
    kl = k[point]
    h = torch.exp2(-1.0 - depth.to(lu.dtype))  # the cell's half-size, 2^-(depth + 1)
    x0, y0, dx = kl * lu, kl * lv, kl * h  # tangent-plane centre and half-size
    m2 = 1 + x0 * x0 + y0 * y0  # |centre|^2 of the direction (x0, y0, 1)
    theta = torch.atan(torch.sqrt(_cap_tan2(x0, y0, dx)))  # the bounding cap's radius
    inv_m = torch.rsqrt(m2).unsqueeze(-1)
    axis = (x0.unsqueeze(-1) * t[point] + y0.unsqueeze(-1) * b[point] + a[point]) * inv_m
    if solid_angle:
        omega = cell_solid_angle(x0 - dx, x0 + dx, y0 - dx, y0 + dx)
    else:
        omega = torch.full_like(theta, math.nan)
    return axis, theta, omega


def cell_solid_angle(x1, x2, y1, y2):
    """Solid angle of the rectangle ``[x1, x2] x [y1, y2]`` of the plane at unit distance.

    ``F(x2, y2) - F(x1, y2) - F(x2, y1) + F(x1, y1)`` with ``F(x, y) = atan(x y / sqrt(1 + x^2
    + y^2))``, the solid angle of ``[0, x] x [0, y]`` (signed). All (...,).
    """

    def f(x, y):
        return torch.atan(x * y / torch.sqrt(1 + x * x + y * y))

    return f(x2, y2) - f(x1, y2) - f(x2, y1) + f(x1, y1)


def leaf_weights(weights: torch.Tensor, depth: torch.Tensor, dist: torch.Tensor) -> torch.Tensor:
    """``w(depth, dist)``: per-depth weights linearly interpolated in ``dist`` (clamped).

    Parameters
    ----------
    weights : (D + 1, len(DIST_NODES)) table of one (mode, max depth)
    depth : (L,) int64;  dist : (L,)

    Returns
    -------
    (L,)
    """
    i0, i1, lam = interp_coefficients(dist)
    w = weights.to(device=dist.device, dtype=dist.dtype)
    return (1 - lam) * w[depth, i0] + lam * w[depth, i1]


def depth_weights(weights: torch.Tensor, dist: torch.Tensor) -> torch.Tensor:
    """:func:`leaf_weights` of every depth at each ``dist``: (P, D + 1), for ``dist`` (P,).

    Shading interpolates once per point and gathers per leaf (a leaf's weight is
    ``depth_weights(...)[point, depth]``) rather than interpolating per leaf.
    """
    i0, i1, lam = interp_coefficients(dist)
    w = weights.to(device=dist.device, dtype=dist.dtype)
    lam = lam.unsqueeze(-1)
    return (1 - lam) * w[:, i0].T + lam * w[:, i1].T


def interp_coefficients(dist: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Node indices ``i``, ``i + 1`` and ``lam`` of :func:`leaf_weights` (for calibration)."""
    nodes = torch.tensor(DIST_NODES, dtype=dist.dtype, device=dist.device)
    x = dist.clamp(nodes[0], nodes[-1])
    i = (torch.searchsorted(nodes, x.contiguous(), right=True) - 1).clamp(0, len(DIST_NODES) - 2)
    lam = (x - nodes[i]) / (nodes[i + 1] - nodes[i])
    return i, i + 1, lam
