"""Cube maps: face conventions, texel directions, exact solid angles, seamless sampling.

Layout (docs/conventions.md): a cube map is a ``(6, R, R, C)`` array in OpenGL face order
+X, -X, +Y, -Y, +Z, -Z. Row ``i`` of a face is the GL texture coordinate ``t`` and column ``j``
is ``s``, so a face uploads to ``glTexImage2D(GL_TEXTURE_CUBE_MAP_POSITIVE_X + f, ...)`` as it is.
With face coordinates ``u = 2 s - 1`` and ``v = 2 t - 1`` in ``[-1, 1]`` the direction of a point
on face ``f`` is (GL 4.5 spec, table 8.19, inverted)::

    +X: ( 1, -v, -u)    -X: (-1, -v,  u)
    +Y: ( u,  1,  v)    -Y: ( u, -1, -v)
    +Z: ( u, -v,  1)    -Z: (-u, -v, -1)

Texel ``(i, j)`` of a face of resolution ``R`` has its centre at ``u = (2 j + 1)/R - 1``,
``v = (2 i + 1)/R - 1``. Solid angles are exact: the area of the spherical projection of a
texel, from the closed form of the solid angle of a rectangle on the plane ``z = 1``.

Sampling is bilinear and seamless, as GL's ``TEXTURE_CUBE_MAP_SEAMLESS``: a texel needed across
an edge comes from the neighbouring face, and a corner texel (which has no unique neighbour)
is the average of the three texels that meet there, the value the GL spec recommends.

Points on a face's extended plane (:func:`face_point`, :func:`components_to_face_uv`,
:func:`face_plane_texels`) and the padding's index plan (:func:`seamless_pad_plan`) are public
for the prefilter's tiled convolutions, which build their own borders from them.
"""

from __future__ import annotations

from functools import lru_cache

import torch

from .._backend import as_tensor, dispatch
from .._checks import check_cube
from ..errors import InputError

__all__ = [
    "FACE_NAMES",
    "components_to_face_uv",
    "direction_to_face_uv",
    "downsample",
    "face_plane_texels",
    "face_point",
    "face_uv_to_direction",
    "pad_seamless",
    "sample",
    "seamless_pad_plan",
    "texel_directions",
    "texel_solid_angles",
    "texel_uv",
]

FACE_NAMES = ("+x", "-x", "+y", "-y", "+z", "-z")


def face_uv_to_direction(face: torch.Tensor, u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Unnormalised direction of face coordinates.

    Parameters
    ----------
    face : (...) int64 in 0..5
    u, v : (...) float, face coordinates (may lie outside [-1, 1] on the extended face plane)

    Returns
    -------
    (..., 3) direction, not normalised (its major axis has magnitude 1).
    """
    one = torch.ones_like(u)
    # (6, ..., 3) candidate directions, one per face, then pick by face index
    cand = torch.stack(
        [
            torch.stack([one, -v, -u], -1),
            torch.stack([-one, -v, u], -1),
            torch.stack([u, one, v], -1),
            torch.stack([u, -one, -v], -1),
            torch.stack([u, -v, one], -1),
            torch.stack([-u, -v, -one], -1),
        ]
    )
    idx = face.long().reshape(1, *face.shape, 1).expand(1, *u.shape, 3)
    return torch.gather(cand, 0, idx)[0]


@dispatch
def direction_to_face_uv(dirs):
    """Face index and face coordinates of directions (the GL major-axis rule).

    Parameters
    ----------
    dirs : (..., 3) directions (need not be unit)

    Returns
    -------
    face : (...) int64 in 0..5;  u, v : (...) in [-1, 1]
    """
    return components_to_face_uv(*dirs.unbind(-1))


def components_to_face_uv(
    x: torch.Tensor, y: torch.Tensor, z: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Face index and face coordinates of directions given by their components (the GL
    major-axis rule): :func:`direction_to_face_uv` without stacking the components.

    Parameters
    ----------
    x, y, z : (...) float, the directions' components (need not be unit)

    Returns
    -------
    face : (...) int64 in 0..5;  u, v : (...) in [-1, 1]
    """
    ax, ay, az = x.abs(), y.abs(), z.abs()
    is_x = (ax >= ay) & (ax >= az)
    is_y = ~is_x & (ay >= az)
    face = torch.where(
        is_x,
        torch.where(x >= 0, 0, 1),
        torch.where(is_y, torch.where(y >= 0, 2, 3), torch.where(z >= 0, 4, 5)),
    ).long()
    ma = torch.where(is_x, ax, torch.where(is_y, ay, az)).clamp_min(torch.finfo(x.dtype).tiny)
    # sc, tc per face from GL table 8.19
    sc = torch.where(
        is_x, torch.where(x >= 0, -z, z), torch.where(is_y, x, torch.where(z >= 0, x, -x))
    )
    tc = torch.where(is_x, -y, torch.where(is_y, torch.where(y >= 0, z, -z), -y))
    return face, sc / ma, tc / ma


#: Where face ``f``'s coordinates go in its directions (the table in the module docstring):
#: ``(axis, sign)`` of the normal, of ``u`` and of ``v``.
_FACE_AXES = (
    ((0, 1), (2, -1), (1, -1)),
    ((0, -1), (2, 1), (1, -1)),
    ((1, 1), (0, 1), (2, 1)),
    ((1, -1), (0, 1), (2, -1)),
    ((2, 1), (0, 1), (1, -1)),
    ((2, -1), (0, -1), (1, -1)),
)


def face_point(face: int, n: torch.Tensor, u: torch.Tensor, v: torch.Tensor) -> list[torch.Tensor]:
    """Components ``[x, y, z]`` of the point ``n`` along face ``face``'s normal, at ``(u, v)``.

    Each component is ``n``, ``u`` or ``v`` up to its sign, so with ``n = 1`` this equals
    :func:`face_uv_to_direction` for one face bit for bit, without building the other five
    faces' candidates.

    Parameters
    ----------
    face : int in 0..5
    n, u, v : (...) float tensors (broadcasting), the distance along the normal and the face
        coordinates (which may lie outside [-1, 1], on the extended face plane)

    Returns
    -------
    list of three tensors ``[x, y, z]``, each one of ``n``, ``u``, ``v`` or its negation
    """
    comp: list[torch.Tensor] = [n, n, n]
    for (axis, sign), val in zip(_FACE_AXES[face], (n, u, v), strict=True):
        comp[axis] = val if sign > 0 else -val
    return comp


def _nearest_texel(x: torch.Tensor, y: torch.Tensor, z: torch.Tensor, res: int) -> torch.Tensor:
    """Flat index into ``(6, res, res)`` of the texel each direction falls in, ``(...)`` int64."""
    face, u, v = components_to_face_uv(x, y, z)
    # |u|, |v| <= 1 (a minor component over the major one), so rounding toward zero is the
    # floor (and torch's floor goes to the thread pool even for small tensors)
    col = ((u + 1) * 0.5 * res).long().clamp_(0, res - 1)
    row = ((v + 1) * 0.5 * res).long().clamp_(0, res - 1)
    return (face * res + row) * res + col


def face_plane_texels(
    face: int, n: torch.Tensor, u: torch.Tensor, v: torch.Tensor, res: int
) -> torch.Tensor:
    """Texel (flat index into ``(6, res, res)``) that each point of face ``face``'s frame falls in.

    The point is ``n`` along the face's normal at face coordinates ``(u, v)`` (``n = 1``: the
    face's plane, extended past the face). ``n, u, v`` broadcast to ``(...)``; returns ``(...)``
    int64.

    The work is a few dozen elementwise operations per point, done in pieces of ``2^14`` points:
    small enough to stay in cache (the work is bound by memory traffic, not arithmetic) and to
    keep torch's elementwise operations on the calling thread (below its parallel grain size of
    ``2^15`` elements), since on a busy machine waiting for a pool thread can cost far more than
    the operation itself.
    """
    n, u, v = torch.broadcast_tensors(n, u, v)
    shape = u.shape
    n, u, v = n.reshape(-1), u.reshape(-1), v.reshape(-1)
    out = torch.empty(u.numel(), dtype=torch.long, device=u.device)
    step = 1 << 14
    for a in range(0, u.numel(), step):
        sl = slice(a, a + step)
        out[sl] = _nearest_texel(*face_point(face, n[sl], u[sl], v[sl]), res)
    return out.reshape(shape)


def texel_uv(res: int, *, device=None, dtype=torch.float32) -> torch.Tensor:
    """Face coordinates of texel centres: ``(R,)`` values ``(2 k + 1)/R - 1``."""
    return ((2 * torch.arange(res, device=device, dtype=torch.float64) + 1) / res - 1).to(dtype)


def texel_directions(res: int, *, device=None, dtype=torch.float32) -> torch.Tensor:
    """Unit directions of all texel centres, ``(6, R, R, 3)`` indexed ``[face, row(t), col(s)]``."""
    c = texel_uv(res, device=device, dtype=torch.float64)
    v, u = torch.meshgrid(c, c, indexing="ij")  # (R, R) rows follow v (= t), columns u (= s)
    face = torch.arange(6, device=device).reshape(6, 1, 1).expand(6, res, res)
    d = face_uv_to_direction(face, u.expand(6, res, res), v.expand(6, res, res))
    return torch.nn.functional.normalize(d, dim=-1).to(dtype)


def _rect_solid_angle_corner(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    # Solid angle of the rectangle [0, x] x [0, y] on the plane z = 1 seen from the origin.
    return torch.atan2(x * y, torch.sqrt(x * x + y * y + 1))


def texel_solid_angles(res: int, *, device=None, dtype=torch.float32) -> torch.Tensor:
    """Exact solid angle of every texel, ``(6, R, R)``; they sum to 4 pi.

    Computed in float64 from the closed form for a rectangle on a tangent plane, then cast.
    """
    e = torch.linspace(-1, 1, res + 1, device=device, dtype=torch.float64)  # texel edges
    y, x = torch.meshgrid(e, e, indexing="ij")
    a = _rect_solid_angle_corner(x, y)  # (R+1, R+1)
    omega = a[1:, 1:] - a[:-1, 1:] - a[1:, :-1] + a[:-1, :-1]  # (R, R)
    return omega.abs().expand(6, res, res).to(dtype).contiguous()


@lru_cache(maxsize=64)
def seamless_pad_plan(res: int, pad: int, device: torch.device) -> tuple[torch.Tensor, ...]:
    """The index plan of :func:`pad_seamless`: border texels of the padded faces, the texels
    they copy, and the corner texels.

    Returns ``dst, src`` ``(B,)`` int64: flat indices into the padded faces ``(6, n, n)``
    (n = res + 2 pad) and into the faces ``(6, res, res)``; ``rows, cols`` ``(4, 4)`` int64: the
    four corner texels of the border (column 0) and the three texels each averages (columns 1
    to 3: the face's own corner texel and the two across its edges). Depends on the resolution
    only, so it is kept between calls. Built in float64 on the CPU (``O(6 n pad)`` elementwise
    work), then moved to ``device``.
    """
    n = res + 2 * pad
    k = torch.arange(-pad, res + pad)
    inside = (k >= 0) & (k < res)
    rows, cols = (~(inside[:, None] & inside[None, :])).nonzero(as_tuple=True)  # (B/6,)
    v = (2 * rows.double() - 2 * pad + 1) / res - 1  # extended texel centres
    u = (2 * cols.double() - 2 * pad + 1) / res - 1
    one = torch.ones((), dtype=torch.float64)
    src = torch.stack([face_plane_texels(f, one, u, v, res) for f in range(6)])
    dst = torch.arange(6)[:, None] * (n * n) + rows * n + cols
    lo, hi = pad - 1, res + pad
    ci = torch.tensor([lo, lo, hi, hi])
    cj = torch.tensor([lo, hi, lo, hi])
    di = torch.tensor([1, 1, -1, -1])
    dj = torch.tensor([1, -1, 1, -1])
    corner_rows = torch.stack([ci, ci + di, ci, ci + di], 1)  # corner, own, across i, across j
    corner_cols = torch.stack([cj, cj + dj, cj + dj, cj], 1)
    return tuple(t.to(device) for t in (dst.reshape(-1), src.reshape(-1), corner_rows, corner_cols))


def pad_seamless(cube: torch.Tensor, pad: int = 1) -> torch.Tensor:
    """Add a border of ``pad`` texels taken from the neighbouring faces.

    Border texels are the texels of the neighbouring faces that a GL seamless lookup would use:
    the direction of a border texel centre on the extended face plane is looked up with nearest
    filtering (for ``pad = 1`` this selects exactly the neighbour's edge texel). The corner
    border texels (no unique neighbour) average the three texels meeting at the cube corner.

    Parameters
    ----------
    cube : (6, R, R, C)

    Returns
    -------
    (6, R + 2 pad, R + 2 pad, C)
    """
    res = check_cube(cube)
    n = res + 2 * pad
    out = cube.new_empty(6, n, n, *cube.shape[3:])
    out[:, pad : pad + res, pad : pad + res] = cube
    if pad < 1:
        return out
    dst, src, rows, cols = seamless_pad_plan(res, pad, cube.device)
    flat = cube.reshape(6 * res * res, -1)
    out.view(6 * n * n, -1).index_copy_(0, dst, flat.index_select(0, src))
    # Corner blocks of the border have no unique neighbour face: use the GL-recommended
    # average of the three texels that meet at the corner (own corner + two across edges).
    three = out[:, rows[:, 1:], cols[:, 1:]]  # (6, 4, 3, C)
    out[:, rows[:, 0], cols[:, 0]] = (three[:, :, 0] + three[:, :, 1] + three[:, :, 2]) / 3
    return out


def sample(
    cube: torch.Tensor, dirs: torch.Tensor, *, padded: torch.Tensor | None = None
) -> torch.Tensor:
    """Bilinear, seamless lookup of a cube map in directions.

    Parameters
    ----------
    cube : (6, R, R, C)
    dirs : (..., 3) directions (need not be unit), any device (moved to the cube's)
    padded : optional result of ``pad_seamless(cube)`` to reuse across calls

    Returns
    -------
    (..., C) values, dtype of ``cube``.
    """
    res = check_cube(cube)
    dirs = as_tensor(dirs, device=cube.device)
    if padded is None:
        padded = pad_seamless(cube)
    face, u, v = direction_to_face_uv(dirs)
    # padded texel coordinates: texel k centre sits at k + 1 (one border texel)
    x = ((u.to(torch.float64) + 1) * 0.5 * res + 0.5).clamp(0.5, res + 0.5)
    y = ((v.to(torch.float64) + 1) * 0.5 * res + 0.5).clamp(0.5, res + 0.5)
    x0 = x.floor().clamp(0, res).long()
    y0 = y.floor().clamp(0, res).long()
    fx = (x - x0).to(cube.dtype).unsqueeze(-1)
    fy = (y - y0).to(cube.dtype).unsqueeze(-1)
    p = padded
    c00 = p[face, y0, x0]
    c01 = p[face, y0, x0 + 1]
    c10 = p[face, y0 + 1, x0]
    c11 = p[face, y0 + 1, x0 + 1]
    return (c00 * (1 - fx) + c01 * fx) * (1 - fy) + (c10 * (1 - fx) + c11 * fx) * fy


def downsample(cube: torch.Tensor) -> torch.Tensor:
    """Halve the resolution, averaging 2 x 2 texels weighted by their exact solid angles.

    Power (sum of value x solid angle) is preserved exactly.

    Parameters
    ----------
    cube : (6, R, R, C) with R even

    Returns
    -------
    (6, R/2, R/2, C)
    """
    res = check_cube(cube)
    if res % 2:
        raise InputError("cube", f"resolution must be even to downsample, got {res}")
    w = texel_solid_angles(res, device=cube.device, dtype=cube.dtype).unsqueeze(-1)
    h = res // 2
    num = (cube * w).reshape(6, h, 2, h, 2, -1).sum((2, 4))
    den = w.reshape(6, h, 2, h, 2, 1).sum((2, 4))
    return num / den
