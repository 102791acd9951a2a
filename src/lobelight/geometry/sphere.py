"""Directions on the unit sphere: the 92 geodesic views, quadrature sets, frames and rotations.

Conventions (conventions.md): directions are ``(..., 3)`` float arrays, unit length, world frame,
right-handed, +Y up. Array functions take numpy arrays or torch tensors (numpy in, numpy out;
tensors keep dtype and device, see :mod:`lobelight._backend`). Functions that take no array
(``geodesic_views``, ``fibonacci``, ``random_rotation``) return torch tensors and take
``dtype`` (float32 by default) and ``device`` keywords.

Spherical coordinates (+Y up)
    ``theta`` in ``[0, pi]`` is the polar angle from +Y; ``phi`` in ``(-pi, pi]`` is the azimuth,
    0 on the +Z side and ``pi/2`` on the +X side::

        d(theta, phi) = (sin(theta) sin(phi), cos(theta), sin(theta) cos(phi))

    This is the usual z-up convention with the axes cycled (x, y, z) -> (z, x, y), so it is
    right-handed: increasing ``phi`` turns counter-clockwise seen from above, and
    ``rotation_y(a)`` maps ``d(theta, phi)`` to ``d(theta, phi + a)``.

Rotations
    Matrices act on column vectors (``R @ v``), are right-handed (a positive angle turns
    counter-clockwise when the axis points at the viewer) and are batched as ``(..., 3, 3)``.

The 92 views (Green et al. 2006, section 3.2)
    The vertices of the frequency-3 geodesic icosahedron: every edge of an icosahedron cut in
    three, every face's centre added, all projected onto the sphere (10 * 3**2 + 2 = 92). The
    order is fixed and part of the model-file format:

    * ``0`` is +Y and ``11`` is -Y. ``1..5`` are the upper ring, at polar angle
      ``arctan(2)`` (``y = 1/sqrt(5)``) and azimuths ``phi = 72 k`` degrees (``k = 0..4``;
      view 1 lies in the +Z half of the YZ plane). ``6..10`` are the lower ring at
      ``y = -1/sqrt(5)``, azimuths ``72 k + 36`` degrees.
    * ``12..71``: two points per icosahedron edge. The 30 edges ``(i, j)``, ``i < j``, are sorted
      lexicographically; edge ``e`` gives view ``12 + 2 e`` = normalise(2 v_i + v_j) (the point
      nearer ``i``) and ``13 + 2 e`` = normalise(v_i + 2 v_j).
    * ``72..91``: the centre normalise(v_a + v_b + v_c) of icosahedron face ``f`` in the order of
      :data:`ICOSAHEDRON_FACES` (top cap, upper band, lower band, bottom cap, five each).

    The triangles (:func:`geodesic_faces`) are outward-oriented (counter-clockwise seen from
    outside), nine per icosahedron face, face-major. The view neighbours used by the coherence
    terms are the edges of that mesh (:func:`geodesic_neighbors`).
"""

from __future__ import annotations

import functools
import hashlib
import json
import logging
import math
from typing import Any

import numpy as np
import torch

from .._backend import as_float, dispatch
from .._cache import UNREADABLE, cache_dir
from .._checks import check_directions
from .._io import atomic_writer
from ..errors import InputError
from . import cubemap

__all__ = [
    "ICOSAHEDRON_FACES",
    "cap_grid",
    "direction_to_spherical",
    "euler_to_matrix",
    "face_planes",
    "fibonacci",
    "fibonacci_lattice",
    "frame",
    "gauss_legendre",
    "geodesic_edges",
    "geodesic_faces",
    "geodesic_neighbor_table",
    "geodesic_neighbors",
    "geodesic_views",
    "lobe_cap_angle",
    "local_grid",
    "locate_views",
    "normalize",
    "random_rotation",
    "rotation_between",
    "rotation_matrix",
    "rotation_y",
    "spherical_to_direction",
    "to_local",
    "to_world",
    "triangle_candidates",
]

logger = logging.getLogger(__name__)

N_VIEWS = 92

#: Version of what :func:`triangle_candidates` computes, part of its disk cache's key: bumped
#: whenever the computation changes (the geodesic triangles' planes and the tolerance are in
#: the key by value, so a change to them needs no bump).
CANDIDATES_VERSION = 1
#: How far outside a triangle (its smallest unnormalised barycentric) a grid point of a texel
#: may lie and still make the triangle a candidate: about 0.006 degrees.
_CANDIDATE_TOL = 1e-4

# Icosahedron faces over the 12 vertices above, outward (counter-clockwise seen from outside):
# top cap (0, u_k, u_k+1), upper band (u_k, l_k, u_k+1), lower band (l_k, l_k+1, u_k+1),
# bottom cap (11, l_k+1, l_k), with u_k = 1 + k and l_k = 6 + k (k mod 5).
ICOSAHEDRON_FACES: tuple[tuple[int, int, int], ...] = (
    tuple((0, 1 + k, 1 + (k + 1) % 5) for k in range(5))
    + tuple((1 + k, 6 + k, 1 + (k + 1) % 5) for k in range(5))
    + tuple((6 + k, 6 + (k + 1) % 5, 1 + (k + 1) % 5) for k in range(5))
    + tuple((11, 6 + (k + 1) % 5, 6 + k) for k in range(5))
)


# --------------------------------------------------------------------------------------------
# helpers


def normalize(v: torch.Tensor) -> torch.Tensor:
    norm = torch.linalg.vector_norm(v, dim=-1, keepdim=True)
    return v / norm.clamp_min(torch.finfo(v.dtype).tiny)


def _new(t: torch.Tensor, dtype: torch.dtype, device: Any) -> torch.Tensor:
    # Always a copy, so that a caller writing into the result cannot corrupt a cache.
    return t.to(dtype=dtype, device=device, copy=True)


# --------------------------------------------------------------------------------------------
# the 92 geodesic views


@functools.lru_cache(maxsize=1)
def _geodesic() -> dict[str, Any]:
    """Build the frequency-3 geodesic icosahedron once, in float64 on the CPU."""
    f64 = torch.float64
    # 12 icosahedron vertices, +Y up (see module docstring)
    cos_a, sin_a = 1 / math.sqrt(5), 2 / math.sqrt(5)
    k = torch.arange(5, dtype=f64)
    phi_u = 2 * math.pi * k / 5
    phi_l = phi_u + math.pi / 5
    ring_u = torch.stack([sin_a * phi_u.sin(), torch.full_like(k, cos_a), sin_a * phi_u.cos()], -1)
    ring_l = torch.stack([sin_a * phi_l.sin(), torch.full_like(k, -cos_a), sin_a * phi_l.cos()], -1)
    pole = torch.tensor([[0.0, 1.0, 0.0]], dtype=f64)
    ico = torch.cat([pole, ring_u, ring_l, -pole])  # (12, 3)

    ico_faces = torch.tensor(ICOSAHEDRON_FACES, dtype=torch.int64)  # (20, 3)
    # 30 unique edges (i < j), sorted lexicographically
    pairs = torch.cat([ico_faces[:, [0, 1]], ico_faces[:, [1, 2]], ico_faces[:, [2, 0]]])
    pairs = torch.sort(pairs, dim=1).values
    edges = torch.unique(pairs, dim=0)  # (30, 2), unique sorts rows lexicographically
    assert edges.shape == (30, 2)

    vi, vj = ico[edges[:, 0]], ico[edges[:, 1]]
    edge_pts = torch.stack([2 * vi + vj, vi + 2 * vj], 1).reshape(60, 3)  # (60, 3) interleaved
    centres = ico[ico_faces].sum(1)  # (20, 3)
    views = torch.nn.functional.normalize(torch.cat([ico, edge_pts, centres]), dim=-1)  # (92, 3)

    # Index of the lattice point with integer barycentrics (a, b, c), a + b + c = 3, on
    # icosahedron face f = (A, B, C).
    edge_id = {(int(i), int(j)): e for e, (i, j) in enumerate(edges.tolist())}

    def point(f: int, a: int, b: int, c: int) -> int:
        A, B, C = ICOSAHEDRON_FACES[f]
        w = {A: a, B: b, C: c}
        if 3 in (a, b, c):
            return (A, B, C)[(a, b, c).index(3)]
        if 0 in (a, b, c):
            p, q = sorted(v for v in (A, B, C) if w[v] > 0)
            return 12 + 2 * edge_id[(p, q)] + (0 if w[p] == 2 else 1)
        return 72 + f

    # Nine sub-triangles per face: six "up" triangles at lattice points with a + b + c = 2,
    # three "down" ones at a + b + c = 1. Both keep the orientation of (A, B, C): a down
    # triangle is an up triangle turned by 180 degrees in the face plane.
    tris = []
    for f in range(20):
        for a in range(3):
            for b in range(3 - a):
                c = 2 - a - b
                tris.append((point(f, a + 1, b, c), point(f, a, b + 1, c), point(f, a, b, c + 1)))
        for a in range(2):
            for b in range(2 - a):
                c = 1 - a - b
                tris.append(
                    (
                        point(f, a, b + 1, c + 1),
                        point(f, a + 1, b, c + 1),
                        point(f, a + 1, b + 1, c),
                    )
                )
    faces = torch.tensor(tris, dtype=torch.int64)  # (180, 3)

    # Neighbours: edges of the mesh, each ring sorted counter-clockwise about the view seen
    # from outside, starting at its lowest index (deterministic and useful for ring stencils).
    mesh_pairs = torch.cat([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    mesh_edges = torch.unique(torch.sort(mesh_pairs, dim=1).values, dim=0)  # (270, 2)
    t, b, _ = frame(views)
    nbrs: list[list[int]] = [[] for _ in range(N_VIEWS)]
    for i, j in mesh_edges.tolist():
        nbrs[i].append(j)
        nbrs[j].append(i)
    for v in range(N_VIEWS):
        ring = torch.tensor(nbrs[v])
        d = views[ring] - views[v]
        ang = torch.atan2(d @ b[v], d @ t[v])
        ring = ring[torch.argsort(ang)].tolist()
        s = ring.index(min(ring))
        nbrs[v] = ring[s:] + ring[:s]
    table = torch.full((N_VIEWS, 6), -1, dtype=torch.int64)
    for v, ring in enumerate(nbrs):
        table[v, : len(ring)] = torch.tensor(ring)

    return {"views": views, "faces": faces, "edges": mesh_edges, "nbrs": nbrs, "table": table}


def geodesic_views(*, dtype: torch.dtype = torch.float32, device: Any = None) -> torch.Tensor:
    """The 92 view directions, ``(92, 3)`` unit vectors in the documented order (module docstring).

    Built once in float64 and cached; each call returns a fresh tensor of ``dtype`` on ``device``.
    """
    return _new(_geodesic()["views"], dtype, device)


def geodesic_faces(*, device: Any = None) -> torch.Tensor:
    """Triangles of the geodesic mesh, ``(180, 3)`` int64 view indices, outward-oriented."""
    return _new(_geodesic()["faces"], torch.int64, device)


def geodesic_edges(*, device: Any = None) -> torch.Tensor:
    """Edges of the geodesic mesh, ``(270, 2)`` int64 ``(i, j)`` with ``i < j``, sorted."""
    return _new(_geodesic()["edges"], torch.int64, device)


def geodesic_neighbors() -> list[list[int]]:
    """Neighbours of each view: ``92`` lists (12 of length 5, 80 of length 6).

    Each ring is ordered counter-clockwise about the view seen from outside, starting at its
    lowest index. A fresh copy on each call.
    """
    return [list(r) for r in _geodesic()["nbrs"]]


def geodesic_neighbor_table(*, device: Any = None) -> torch.Tensor:
    """:func:`geodesic_neighbors` as a ``(92, 6)`` int64 table, padded with -1 (rows 0..11)."""
    return _new(_geodesic()["table"], torch.int64, device)


@functools.lru_cache(maxsize=16)
def face_planes(dtype: torch.dtype, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """The edge planes of the 180 geodesic triangles, for :func:`locate_views`'s test.

    Returns ``planes (3, 540)``: column ``3 t + k`` is the normal of the great circle through
    the edge of triangle ``t`` opposite its corner ``k`` (so ``planes.T @ d`` gives every
    triangle's unnormalised barycentrics of ``d``), and ``faces (180, 3)``: each triangle's
    three views. The GL renderers upload the same planes.
    """
    g = _geodesic()
    tri = g["views"][g["faces"]]  # (180, 3 corners, 3)
    a, b, c = tri.unbind(1)
    # Row k is the normal of the great circle through the edge opposite corner k, so that
    # (n_k . d) = det(other two corners, d): the unnormalised barycentric of corner k.
    planes = torch.stack(
        [torch.cross(b, c, dim=-1), torch.cross(c, a, dim=-1), torch.cross(a, b, dim=-1)], 1
    )
    return planes.reshape(540, 3).T.to(dtype=dtype, device=device), g["faces"].to(device)


@dispatch
def locate_views(dirs, /, *, chunk: int = 16384):
    """The geodesic triangle containing each direction, and barycentric weights.

    The weights are those of the gnomonic (central) projection of the direction onto the plane
    of the triangle: ``sum_k bary_k * views[idx_k]`` is parallel to ``dirs``. They are
    non-negative, sum to one, equal 1 at a view, and are continuous across triangle edges (on an
    edge the opposite corner's weight is 0 in both triangles), so interpolating per-view values
    with them is continuous over the sphere.

    Each direction is tested against all 180 triangles in chunks (one matrix product); the
    triangle whose smallest barycentric is largest wins, which is robust to rounding on edges.

    Parameters
    ----------
    dirs : (..., 3) directions (need not be unit)
    chunk : directions per chunk, bounds memory at ``chunk * 540`` values

    Returns
    -------
    idx : (..., 3) int64 view indices;  bary : (..., 3) weights, dtype of ``dirs``
    """
    dirs = as_float(dirs)
    check_directions(dirs, "dirs")
    planes, faces = face_planes(dirs.dtype, dirs.device)
    flat = dirs.reshape(-1, 3)  # (M, 3)
    idx_out, bary_out = [], []
    for d in flat.split(chunk):
        det = (d @ planes).reshape(-1, 180, 3)  # (m, 180, 3) unnormalised barycentrics
        best = det.amin(-1).argmax(-1)  # (m,)
        bary = det.gather(1, best.view(-1, 1, 1).expand(-1, 1, 3))[:, 0].clamp_min(0)  # (m, 3)
        bary = bary / bary.sum(-1, keepdim=True).clamp_min(torch.finfo(d.dtype).tiny)
        idx_out.append(faces[best])
        bary_out.append(bary)
    shape = (*dirs.shape[:-1], 3)
    if not idx_out:  # no directions at all
        return torch.zeros(shape, dtype=torch.int64, device=dirs.device), torch.zeros_like(dirs)
    return torch.cat(idx_out).reshape(shape), torch.cat(bary_out).reshape(shape)


@functools.lru_cache(maxsize=4)
def triangle_candidates(res: int = 32, *, sub: int = 8, cache: bool = True) -> torch.Tensor:
    """For each texel of a cube map, the geodesic triangles a direction in it may fall in.

    A renderer that locates many directions (a vertex shader, per frame) tests only these few
    triangles instead of all 180: the triangle :func:`locate_views` picks is always among them.
    Built by locating a grid of ``sub + 1`` points per texel side (edges included) with a
    tolerance, so triangles that only touch the texel count, then widened by the 8 neighbouring
    texels of the same face, so that a thin corner of a triangle between grid points is not
    missed (triangles span ~15 degrees, a texel 2.8 degrees at ``res = 32``).

    The table is the same in every process: with ``cache`` (the default) it is kept on disk,
    ``lobelight._cache.cache_dir() / "geometry"``, one small file per ``(res, sub)`` keyed by a
    hash of :data:`CANDIDATES_VERSION`, the settings and the triangles' planes. Reading checks
    the key, shape, dtype, range and a hash of the values; an entry that fails, or cannot be
    read, is computed again and rewritten (atomically: a reader never sees half a file).

    Returns
    -------
    (6, res, res, K) int64 triangle indices (rows of :func:`geodesic_faces`), ``-1`` padded;
    ``[face, row (t), col (s)]`` as :func:`lobelight.geometry.cubemap.texel_directions`
    """
    if not cache:
        return _compute_candidates(res, sub)
    key = _candidates_key(res, sub)
    path = cache_dir() / "geometry" / f"triangle-candidates-{res}-{sub}-{key[:16]}.npz"
    table = _read_candidates(path, key, res)
    if table is None:
        table = _compute_candidates(res, sub)
        try:
            _write_candidates(path, key, table)
        except OSError as exc:  # a cache that cannot be written only costs the next run time
            logger.warning("could not write the triangle candidates to %s: %s", path, exc)
    return table


def _compute_candidates(res: int, sub: int) -> torch.Tensor:
    """:func:`triangle_candidates` computed afresh."""
    g = res * sub + 1
    c = torch.linspace(-1.0, 1.0, g, dtype=torch.float64)
    v, u = torch.meshgrid(c, c, indexing="ij")  # (G, G): rows follow v (t), columns u (s)
    face = torch.arange(6).reshape(6, 1, 1).expand(6, g, g)
    d = torch.nn.functional.normalize(
        cubemap.face_uv_to_direction(face, u.expand(6, g, g), v.expand(6, g, g)), dim=-1
    ).reshape(-1, 3)
    planes, _ = face_planes(torch.float64, torch.device("cpu"))
    hit = torch.zeros(6 * g * g, 180, dtype=torch.bool)
    for s0 in range(0, d.shape[0], 16384):  # bounded memory: chunk x 540 values
        det = (d[s0 : s0 + 16384] @ planes).reshape(-1, 180, 3)
        hit[s0 : s0 + 16384] = det.amin(-1) >= -_CANDIDATE_TOL  # in it, or within the tolerance
    hit = hit.reshape(6, g, g, 180)
    # texel (i, j) owns grid points i*sub .. (i+1)*sub in each direction (shared edges)
    own = torch.zeros(6, res, res, 180, dtype=torch.bool)
    for a in range(sub + 1):  # (sub + 1)^2 strided views, not a loop over texels
        for b in range(sub + 1):
            own |= hit[:, a : a + res * sub : sub, b : b + res * sub : sub]
    pad = torch.nn.functional.pad(own.permute(0, 3, 1, 2).float(), (1, 1, 1, 1))
    wide = torch.nn.functional.max_pool2d(pad, 3, stride=1) > 0  # (6, 180, res, res)
    wide = wide.permute(0, 2, 3, 1)  # (6, res, res, 180)
    k = int(wide.sum(-1).max())
    # the candidates of each texel first, in triangle order; -1 after them
    order = torch.argsort((~wide).to(torch.int8), dim=-1, stable=True)[..., :k]
    ok = torch.gather(wide, -1, order)
    return torch.where(ok, order, torch.full_like(order, -1))


def _candidates_key(res: int, sub: int) -> str:
    """Hex sha256 naming the candidate table at ``(res, sub)`` of today's code and triangles."""
    head = {"version": CANDIDATES_VERSION, "res": res, "sub": sub, "tol": _CANDIDATE_TOL}
    planes, faces = face_planes(torch.float64, torch.device("cpu"))
    h = hashlib.sha256(json.dumps(head, sort_keys=True).encode())
    h.update(planes.contiguous().numpy().tobytes())
    h.update(faces.contiguous().numpy().tobytes())
    return h.hexdigest()


def _values_digest(table: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(table).tobytes()).hexdigest()


def _read_candidates(path, key: str, res: int) -> torch.Tensor | None:
    """The table stored at ``path`` as an int64 tensor, or None when the file is missing,
    unreadable, or not exactly a whole table named ``key`` (the docstring's checks)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            head = json.loads(str(z["header"][()]))
            table = z["table"]
    except FileNotFoundError:
        return None
    except (*UNREADABLE, TypeError, AttributeError, IndexError) as exc:
        logger.info("ignoring the unreadable candidate table %s (%r)", path, exc)
        return None
    ok = (
        isinstance(head, dict)
        and head.get("key") == key
        and table.dtype == np.int16
        and table.ndim == 4
        and table.shape[:3] == (6, res, res)
        and table.shape[3] >= 1
        and head.get("values") == _values_digest(table)
        and bool(((table >= -1) & (table < 180)).all())
    )
    if not ok:
        logger.info("ignoring the candidate table %s: not the table asked for", path)
        return None
    return torch.from_numpy(table.astype(np.int64))


def _write_candidates(path, key: str, table: torch.Tensor) -> None:
    """Store a table as ``path`` (atomically; the folder is created). Raises OSError."""
    arr = table.numpy().astype(np.int16)  # triangle indices < 180 and -1
    header = json.dumps({"key": key, "values": _values_digest(arr)}, sort_keys=True)
    with atomic_writer(path) as f:
        np.savez(f, header=np.array(header), table=arr)


# --------------------------------------------------------------------------------------------
# quadrature sets


def fibonacci(
    n: int, *, hemisphere: bool = False, dtype: torch.dtype = torch.float32, device: Any = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Fibonacci-lattice directions with equal quadrature weights.

    Point ``i`` has ``y = 1 - (2 i + 1)/n`` (``1 - (i + 1/2)/n`` for the hemisphere ``y > 0``)
    and azimuth ``i`` times the golden angle ``pi (3 - sqrt 5)``: equal-area bands, so the equal
    weights are the right ones, and the spiral spreads points evenly within and across bands.

    Returns
    -------
    dirs : (n, 3);  weights : (n,) all ``4 pi / n`` (``2 pi / n`` for the hemisphere)
    """
    if n < 1:
        raise InputError("n", f"must be a positive number of directions, got {n}")
    i = torch.arange(n, dtype=torch.float64, device=device)
    y = 1 - (i + 0.5) / n if hemisphere else 1 - (2 * i + 1) / n
    phi = i * (math.pi * (3 - math.sqrt(5)))
    r = torch.sqrt((1 - y) * (1 + y))  # sin(theta) without cancellation near the poles
    dirs = torch.stack([r * phi.sin(), y, r * phi.cos()], -1)
    w = torch.full((n,), (2 if hemisphere else 4) * math.pi / n, dtype=dtype, device=device)
    return dirs.to(dtype), w


def fibonacci_lattice(
    n: int, *, dtype: torch.dtype = torch.float32, device: Any = None
) -> torch.Tensor:
    """The ``n``-point Fibonacci lattice of the unit square, ``(n, 2)``:
    ``((i + 1/2) / n, frac(i / phi))`` with ``phi`` the golden ratio (computed in float64), the
    fixed, evenly spread points that map to :func:`fibonacci`'s directions and drive the
    deterministic quadratures of the SG-BRDF fit and the renderers' lobe visibility."""
    if n < 1:
        raise InputError("n", f"must be a positive number of points, got {n}")
    i = torch.arange(n, dtype=torch.float64, device=device)
    return torch.stack([(i + 0.5) / n, torch.frac(i * ((math.sqrt(5) - 1) / 2))], -1).to(dtype)


@dispatch
def lobe_cap_angle(lam, /, *, eps: float = 1e-6):
    """Half-angle of the cap outside which ``exp(lam (mu.w - 1)) < eps``, capped at ``pi``.

    ``theta = arccos(1 - ln(1/eps)/lam)``, about ``sqrt(2 ln(1/eps)/lam)`` for sharp lobes. The
    lobe's mass outside the cap is ``eps`` times its total (exactly, for ``lam (1 - cos) >> 1``).

    Parameters
    ----------
    lam : (...) sharpness, > 0

    Returns
    -------
    (...) angle in radians, dtype of ``lam``
    """
    lam = as_float(lam)
    s = (math.log(1 / eps) / lam).clamp(max=2.0)  # 1 - cos(theta)
    return 2 * torch.asin(torch.sqrt(s / 2))  # = arccos(1 - s), accurate for small s


@dispatch
def cap_grid(mu, theta_max, /, *, n_theta: int = 16, n_phi: int | None = None):
    """Quadrature directions and solid-angle weights over the cap of half-angle ``theta_max``
    around each centre.

    Product rule: Gauss-Legendre in ``s = 1 - cos(theta)`` on ``[0, 1 - cos(theta_max)]`` times
    the trapezoid rule in ``phi`` (``n_phi`` equal steps). Since ``d omega = ds dphi``, the
    weights need no Jacobian. Why this rule: the trapezoid rule integrates every azimuthal
    Fourier mode ``m`` with ``0 < |m| < n_phi`` exactly to zero, and what is left of a polynomial
    in (x, y, z) is a polynomial in ``s``, which Gauss-Legendre integrates exactly; so the rule is
    exact for polynomials of degree ``<= min(2 n_theta - 1, n_phi - 1)`` on any cap. A spherical
    Gaussian centred on the cap is ``exp(-lam s)``, whose integral on ``[0, ln(1/eps)/lam]``
    looks the same for every ``lam``: a fixed ``n_theta`` gives the same accuracy at every width.
    Nodes are built in float64 and in ``s`` (not ``cos``), so sharp caps keep their precision.

    Parameters
    ----------
    mu : (..., 3) unit cap centres
    theta_max : (...) or scalar half-angles in ``(0, pi]`` (broadcast with ``mu[..., 0]``)
    n_theta, n_phi : nodes in ``s`` and in ``phi`` (default ``n_phi = 2 n_theta``)

    Returns
    -------
    dirs : (..., n_theta * n_phi, 3), ``theta``-major, local frame :func:`frame` of ``mu``;
    weights : (..., n_theta * n_phi) solid angles, summing to the cap area
    ``2 pi (1 - cos theta_max)``
    """
    mu = as_float(mu)
    check_directions(mu, "mu")
    tmax = as_float(theta_max, like=mu).double().clamp(0.0, math.pi)
    s_max = 2 * torch.sin(tmax / 2) ** 2  # 1 - cos(theta_max) without cancellation
    return _cap_from_s(mu, s_max, n_theta=n_theta, n_phi=n_phi)


@dispatch
def local_grid(mu, lam, /, *, eps: float = 1e-6, n_theta: int = 16, n_phi: int | None = None):
    """Quadrature directions sized to a spherical Gaussian of sharpness ``lam`` around ``mu``.

    The cap is where ``G = exp(lam (mu.w - 1)) >= eps`` (see :func:`lobe_cap_angle`), so a lobe
    is sampled where it lives: with ``lam = 1e4`` the cap is about 0.05 rad wide, far finer than
    any global set. The rule is :func:`cap_grid`'s; with the defaults it integrates such an SG to
    about ``eps`` relative (the mass outside the cap) at any ``lam``.

    Parameters
    ----------
    mu : (..., 3) unit centres
    lam : (...) or scalar sharpness per centre (broadcast with ``mu[..., 0]``)

    Returns
    -------
    dirs : (..., n_theta * n_phi, 3);  weights : (..., n_theta * n_phi) solid angles
    """
    mu = as_float(mu)
    check_directions(mu, "mu")
    lam = as_float(lam, like=mu)
    s_max = (math.log(1 / eps) / lam.double()).clamp(max=2.0)  # 1 - cos(theta_max)
    return _cap_from_s(mu, s_max, n_theta=n_theta, n_phi=n_phi)


@functools.lru_cache(maxsize=32)
def gauss_legendre(n: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Gauss-Legendre nodes and weights on [-1, 1], ``(n,)`` float64 each."""
    # Golub-Welsch: nodes are the eigenvalues of the Jacobi matrix, weights 2 v_0^2.
    k = torch.arange(1, n, dtype=torch.float64)
    off = k / torch.sqrt(4 * k * k - 1)
    jac = torch.diag(off, 1) + torch.diag(off, -1)
    x, v = torch.linalg.eigh(jac)
    return x, 2 * v[0] ** 2


def _cap_from_s(mu: torch.Tensor, s_max: torch.Tensor, *, n_theta: int, n_phi: int | None):
    if n_phi is None:
        n_phi = 2 * n_theta
    if n_theta < 1 or n_phi < 1:
        raise InputError("n_theta/n_phi", f"must be positive, got {n_theta}, {n_phi}")
    dev = mu.device
    x, wx = gauss_legendre(n_theta)
    x, wx = x.to(dev), wx.to(dev)
    batch = torch.broadcast_shapes(mu.shape[:-1], s_max.shape)
    s_max = s_max.to(dev).expand(batch).unsqueeze(-1)  # (..., 1)
    s = 0.5 * (x + 1) * s_max  # (..., n_theta)
    ws = 0.5 * wx * s_max  # (..., n_theta)
    sin_t = torch.sqrt(s * (2 - s))  # (..., n_theta)
    cos_t = 1 - s
    phi = (torch.arange(n_phi, dtype=torch.float64, device=dev) + 0.5) * (2 * math.pi / n_phi)
    # local coordinates along (t, b, mu), (..., n_theta, n_phi)
    lx = sin_t.unsqueeze(-1) * phi.cos()
    ly = sin_t.unsqueeze(-1) * phi.sin()
    lz = cos_t.unsqueeze(-1).expand(lx.shape)
    t, b, n = frame(mu.double().expand(*batch, 3))
    t, b, n = (v.reshape(*batch, 1, 1, 3) for v in (t, b, n))
    dirs = lx.unsqueeze(-1) * t + ly.unsqueeze(-1) * b + lz.unsqueeze(-1) * n  # (..., nt, np, 3)
    w = (ws * (2 * math.pi / n_phi)).unsqueeze(-1).expand(*batch, n_theta, n_phi)
    m = n_theta * n_phi
    return dirs.reshape(*batch, m, 3).to(mu.dtype), w.reshape(*batch, m).to(mu.dtype)


# --------------------------------------------------------------------------------------------
# frames and rotations


@dispatch
def frame(n, /):
    """Orthonormal tangent frame ``(t, b, n)`` of unit normals, right-handed (``t x b = n``).

    Branchless construction of Duff et al. 2017 ("Building an orthonormal basis, revisited"),
    which fixes the precision loss of Frisvad 2012 near ``n = -Z``. ``t`` and ``b`` are
    continuous except across ``n_z = 0`` where the sign switches.

    Parameters
    ----------
    n : (..., 3) unit normals

    Returns
    -------
    t, b, n : (..., 3) each
    """
    n = as_float(n)
    check_directions(n, "n")
    x, y, z = n.unbind(-1)
    sign = torch.copysign(torch.ones_like(z), z)
    a = -1 / (sign + z)
    c = x * y * a
    t = torch.stack([1 + sign * x * x * a, sign * c, -sign * x], -1)
    b = torch.stack([c, sign + y * y * a, -y], -1)
    return t, b, n


@dispatch
def to_local(v, n, /):
    """Coordinates of ``v`` in the frame :func:`frame` of ``n``: ``(v.t, v.b, v.n)``.

    The normal is the local **z** axis (shading-frame habit), not +Y.

    Parameters
    ----------
    v : (..., 3);  n : (..., 3) unit normals (broadcast)

    Returns
    -------
    (..., 3)
    """
    v = as_float(v)
    check_directions(v, "v")
    t, b, n = frame(as_float(n, like=v))
    return torch.stack([(v * t).sum(-1), (v * b).sum(-1), (v * n).sum(-1)], -1)


@dispatch
def to_world(v, n, /):
    """Inverse of :func:`to_local`: ``v_x t + v_y b + v_z n``.

    Parameters
    ----------
    v : (..., 3) local coordinates;  n : (..., 3) unit normals (broadcast)

    Returns
    -------
    (..., 3)
    """
    v = as_float(v)
    check_directions(v, "v")
    t, b, n = frame(as_float(n, like=v))
    return v[..., :1] * t + v[..., 1:2] * b + v[..., 2:] * n


@dispatch
def rotation_matrix(axis, angle, /):
    """Right-handed rotation by ``angle`` about ``axis`` (Rodrigues' formula).

    Parameters
    ----------
    axis : (..., 3) axes (normalised here);  angle : (...) radians (broadcast)

    Returns
    -------
    (..., 3, 3)
    """
    axis = as_float(axis)
    check_directions(axis, "axis")
    angle = as_float(angle, like=axis)
    k = normalize(axis)
    batch = torch.broadcast_shapes(k.shape[:-1], angle.shape)
    k = k.expand(*batch, 3)
    c, s = angle.cos().expand(batch), angle.sin().expand(batch)
    kx, ky, kz = k.unbind(-1)
    zero = torch.zeros_like(kx)
    cross = torch.stack(
        [
            torch.stack([zero, -kz, ky], -1),
            torch.stack([kz, zero, -kx], -1),
            torch.stack([-ky, kx, zero], -1),
        ],
        -2,
    )  # (..., 3, 3) the matrix of k x .
    eye = torch.eye(3, dtype=k.dtype, device=k.device)
    outer = k.unsqueeze(-1) * k.unsqueeze(-2)
    c, s = c[..., None, None], s[..., None, None]
    return c * eye + s * cross + (1 - c) * outer


@dispatch
def rotation_y(angle, /):
    """Rotation by ``angle`` about +Y (the up axis): turns lighting about the vertical.

    ``rotation_y(a) @ spherical_to_direction(t, p) == spherical_to_direction(t, p + a)``.

    Parameters
    ----------
    angle : (...) radians

    Returns
    -------
    (..., 3, 3)
    """
    angle = as_float(angle)
    c, s = angle.cos(), angle.sin()
    one, zero = torch.ones_like(c), torch.zeros_like(c)
    return torch.stack(
        [
            torch.stack([c, zero, s], -1),
            torch.stack([zero, one, zero], -1),
            torch.stack([-s, zero, c], -1),
        ],
        -2,
    )


_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


@dispatch
def euler_to_matrix(angles, /, *, order: str = "xyz"):
    """Rotation from three angles about the fixed world axes, applied in ``order``.

    ``order = "xyz"`` rotates first about X by ``angles[..., 0]``, then about Y, then about Z:
    ``R = Rz(a2) @ Ry(a1) @ Rx(a0)`` (extrinsic; the same as intrinsic rotations in the reverse
    order). Any order of the letters x, y, z (repeats allowed, e.g. ``"yxy"``).

    Parameters
    ----------
    angles : (..., 3) radians

    Returns
    -------
    (..., 3, 3)
    """
    angles = as_float(angles)
    order = order.lower()
    if len(order) != 3 or any(ch not in _AXES for ch in order):
        raise InputError("order", f"must be three of the letters x, y, z, got {order!r}")
    if angles.shape[-1:] != (3,):
        raise InputError("angles", f"must be a (..., 3) array of angles, got {tuple(angles.shape)}")
    out = None
    for i, ch in enumerate(order):
        axis = torch.tensor(_AXES[ch], dtype=angles.dtype, device=angles.device)
        r = rotation_matrix(axis, angles[..., i])
        out = r if out is None else r @ out
    return out


@dispatch
def rotation_between(a, b, /):
    """The minimal rotation taking direction ``a`` to direction ``b``.

    Axis ``a x b`` and angle ``atan2(|a x b|, a.b)``: accurate at every angle, including nearly
    opposite directions (a small ``|a x b|`` then multiplies its own rounding error). For exactly
    opposite (or equal) directions the axis is the frame tangent of ``a`` — any axis
    perpendicular to ``a`` gives a half-turn, the choice is arbitrary but deterministic.

    Parameters
    ----------
    a, b : (..., 3) directions (normalised here; broadcast)

    Returns
    -------
    (..., 3, 3) with ``R @ a == b``
    """
    a, b = as_float(a), as_float(b)
    check_directions(a, "a")
    check_directions(b, "b")
    a, b = torch.broadcast_tensors(normalize(a), normalize(b.to(a.device)))
    v = torch.cross(a, b, dim=-1)
    sin = torch.linalg.vector_norm(v, dim=-1)
    cos = (a * b).sum(-1)
    tangent = frame(a)[0]
    degenerate = (sin <= 8 * torch.finfo(a.dtype).eps).unsqueeze(-1)
    axis = torch.where(degenerate, tangent, v)
    return rotation_matrix(axis, torch.atan2(sin, cos))


def random_rotation(
    n: int,
    *,
    generator: torch.Generator | None = None,
    dtype: torch.dtype = torch.float32,
    device: Any = None,
) -> torch.Tensor:
    """``n`` rotations drawn uniformly (Haar measure) from SO(3).

    A normalised 4-D standard normal is a uniform unit quaternion, and the quaternion-to-matrix
    map carries the uniform measure on the 3-sphere to the Haar measure on SO(3).

    Returns
    -------
    (n, 3, 3)
    """
    gdev = generator.device if generator is not None else device
    q = torch.randn(n, 4, generator=generator, dtype=torch.float64, device=gdev)
    q = normalize(q)
    w, x, y, z = q.unbind(-1)
    R = torch.stack(
        [
            torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            torch.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            torch.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )
    return R.to(dtype=dtype, device=device if device is not None else gdev)


# --------------------------------------------------------------------------------------------
# spherical coordinates


@dispatch
def spherical_to_direction(theta, phi, /):
    """Unit direction of polar angle ``theta`` (from +Y) and azimuth ``phi`` (0 at +Z, pi/2 at +X).

    Parameters
    ----------
    theta, phi : (...) radians (broadcast)

    Returns
    -------
    (..., 3) ``(sin theta sin phi, cos theta, sin theta cos phi)``
    """
    theta = as_float(theta)
    phi = as_float(phi, like=theta)
    st = theta.sin()
    return torch.stack(torch.broadcast_tensors(st * phi.sin(), theta.cos(), st * phi.cos()), -1)


@dispatch
def direction_to_spherical(dirs, /):
    """Polar angle from +Y and azimuth of directions (inverse of :func:`spherical_to_direction`).

    Parameters
    ----------
    dirs : (..., 3) directions (need not be unit)

    Returns
    -------
    theta : (...) in ``[0, pi]``;  phi : (...) in ``(-pi, pi]`` (0 at the poles)
    """
    dirs = as_float(dirs)
    check_directions(dirs, "dirs")
    x, y, z = dirs.unbind(-1)
    # atan2 rather than acos: full precision near the poles
    theta = torch.atan2(torch.sqrt(x * x + z * z), y)
    return theta, torch.atan2(x, z)
