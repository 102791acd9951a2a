"""Spherical convolution of cube maps with von Mises-Fisher kernels: the prefilter's engine.

Four operators, each exact or controlled to well under the prefilter's 2 % budget:

``anisotropic_increment``  (fine levels, ``R >= SEPARABLE_MIN_RES`` of :mod:`._prefilter`)
    A narrow vMF ``exp(lam (mu.w - 1))`` seen on a face's gnomonic plane is, to third order in
    the offset, a 2-D Gaussian whose covariance in texel units is ``C = sigma^2 rho^2
    [[1 + u^2, u v], [u v, 1 + v^2]]`` (``rho^2 = 1 + u^2 + v^2``, ``sigma^2 = (R/2)^2 / lam``:
    the inverse of the plane's metric). Any such covariance with ``u v >= 0`` splits into three
    non-negative 1-D variances along the columns, the rows and the diagonal ``(1, 1)``:
    ``C = a e_c e_c' + b e_r e_r' + c d d'`` with ``c = C_rc``, ``a = C_cc - c``, ``b = C_rr - c``,
    and three 1-D passes with per-texel Gaussian weights compose to it. Each face is cut into its
    four quadrants, mirrored so that ``u v >= 0`` everywhere (the metric is symmetric under
    the mirrors), and all 24 quadrant tiles share one set of weights. The tiles carry a border
    from the neighbouring faces on the extended gnomonic plane (area-averaged, see
    :func:`_halo_plan`), so the passes see real texels across edges and corners. Radiance is
    weighted by exact texel solid angles and the result divided by the same passes applied to
    the solid angles, so the measure is right and a constant map stays constant.
``windowed_increment``  (fine levels below that, down to ``SH_MAX_RES``)
    The exact kernel between each texel and a window of real texels around it, the face's and
    its neighbours'.
``dense_increment``  (small maps; the tests' reference)
    The exact kernel between every pair of texels.
``sh_levels``  (the widest lobes)
    Exact Funk-Hecke band factors ``i_l(lam) / i_0(lam)`` applied to spherical-harmonic
    coefficients of a 64^2 area-averaged copy of the map. Cascading many narrow increments
    composes to a heat-kernel-like profile, not a vMF, which for ``lam < 20`` is off by several
    per cent in band 2 and up; computing the wide levels directly removes that error.

``sharpen`` is the reconstruction prefilter for bilinear lookup: bilinear interpolation of
point samples blurs by ``h^2 / 6`` on average and misses a Gaussian of 2.5 texels by 2.0 %
(relative L2); a separable ``[-a, 1 + 2 a, -a]`` with ``a = 0.09`` on the stored texels brings
that to 0.77 % (least squares over sub-texel offsets, see docs/results.md).

Data layout
    The tiled operators work on a tile stack ``(n, n, K)``: texel ``(i, j)`` of every tile side
    by side in the last axis (24 tiles x 3 channels, plus the solid angle where a normalisation
    rides along), so one weight per texel serves all ``K`` values: a 1-D pass is one batched
    matrix product over the texels (:class:`_Pass`), a windowed sum one per group of blocks, and
    the same code runs on the CPU and on a GPU. Weights, windows and gather indices depend only
    on the resolution and the sharpness, never on the map: they are built once per level shape
    and kept in memory (:func:`lobelight.envmap.clear_memory_caches` forgets them).
"""

from __future__ import annotations

import math
import warnings
from functools import lru_cache

import numpy as np
import torch

from .._tol import SMALL
from ..geometry import cubemap

#: Window half-width of a 1-D Gaussian pass, in its standard deviations (mass outside 0.14 %).
PASS_SIGMAS = 3.2
#: Extent of an exact kernel window, in standard deviations (weight exp(-4.3**2/2) < 1e-4).
WINDOW_SIGMAS = 4.3
#: Sharpening tap of the bilinear reconstruction prefilter.
SHARPEN = 0.09
#: Highest band factor dropped by the spherical-harmonic path.
SH_BAND_EPS = 1e-5
#: Sub-samples per axis when area-averaging a border texel from a neighbouring face.
HALO_SUBSAMPLES = 4
#: Border widths for which the halo's sources are computed: pads rounded up to a multiple.
HALO_PAD_STEP = 16


# --------------------------------------------------------------------------------------------
# geometry of the extended gnomonic plane


def _coords(res: int, lo: int, hi: int, device, dtype=torch.float64) -> torch.Tensor:
    """Face coordinates of texel centres ``lo <= k < hi`` (may run past the face), ``(hi-lo,)``."""
    k = torch.arange(lo, hi, device=device, dtype=dtype)
    return (2 * k + 1) / res - 1


def _halo_sources(res: int, pad: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Border texels of the extended faces and the sub-samples' source texels, on the CPU.

    A sub-sample at face coordinates ``(u, v)`` of face ``f``'s plane falls in the texel that
    :func:`lobelight.geometry.cubemap.face_plane_texels` gives. Off one edge (``|u| > 1 >= |v|``
    or the other way round) the point's major axis is the outer coordinate's, so the neighbour
    face and which of ``1`` and the inner coordinate becomes each of its coordinates, with what
    sign, are fixed per edge; these strips take that closed form (one probe point per edge
    finds it; the arithmetic is the general path's, so the texels are the same), and only the
    border's corner blocks the general path.

    Returns
    -------
    rows, cols : (B,) int64 border texels of the ``(n, n)`` grid, ``n = res + 2 pad``, row-major
    src : (6, B, S*S) int64 flat indices into ``(6, res, res)``
    """
    n = res + 2 * pad
    k = torch.arange(-pad, res + pad)
    inside = (k >= 0) & (k < res)
    border = ~(inside[:, None] & inside[None, :])  # (n, n)
    rows, cols = border.nonzero(as_tuple=True)
    where = torch.full((n, n), -1, dtype=torch.long)
    where[rows, cols] = torch.arange(rows.numel())  # each border texel's place in the list
    s = HALO_SUBSAMPLES
    sub = (torch.arange(s, dtype=torch.float64) + 0.5) / s  # (S,)
    line = 2 * (k[:, None] + sub[None, :]) / res - 1  # (n, S) sub-sample coordinates of a line
    one = torch.ones((), dtype=torch.float64)
    out = torch.empty(6, rows.numel(), s, s, dtype=torch.long)
    lo, mid, hi = slice(0, pad), slice(pad, pad + res), slice(pad + res, n)
    # the four strips: (rows, cols, whether v is the outer coordinate, its sign)
    strips = ((lo, mid, True, -1), (hi, mid, True, 1), (mid, lo, False, -1), (mid, hi, False, 1))
    for f in range(6):
        for r, c, outer_v, sign in strips:
            probe = (0.25, 1.5 * sign) if outer_v else (1.5 * sign, 0.25)
            u0, v0 = torch.tensor(probe, dtype=torch.float64)
            g, a0, b0 = cubemap.components_to_face_uv(*cubemap.face_point(f, one, u0, v0))
            v = line[r][:, :, None, None]  # (rows, S, 1, 1)
            u = line[c][None, None]  # (1, 1, cols, S)
            outer, inner = (v, u) if outer_v else (u, v)
            ma = outer.abs()
            texel = []
            for x0 in (a0, b0):  # the face coordinate is (+-1 or +-inner) / |outer|
                num = one if abs(abs(float(x0)) - 1 / 1.5) < 1e-9 else inner
                x = (num if float(x0) > 0 else -num) / ma
                texel.append(((x + 1) * 0.5 * res).long().clamp_(0, res - 1))
            idx = (int(g) * res + texel[1]) * res + texel[0]  # (rows, S, cols, S)
            place = where[r, c]  # (rows, cols)
            out[f, place.reshape(-1)] = idx.permute(0, 2, 1, 3).reshape(-1, s, s)
        # the corner blocks: the general path
        for r in (lo, hi):
            for c in (lo, hi):
                v = line[r][:, None, :, None]  # (rows, 1, S, 1)
                u = line[c][None, :, None, :]  # (1, cols, 1, S)
                idx = cubemap.face_plane_texels(f, one, u, v, res)  # (rows, cols, S, S)
                out[f, where[r, c].reshape(-1)] = idx.reshape(-1, s, s)
    return rows, cols, out.reshape(6, rows.numel(), s * s)


@lru_cache(maxsize=8)
def _halo_plan(
    res: int, pad: int, device: torch.device, dtype: torch.dtype
) -> tuple[torch.Tensor, torch.Tensor]:
    """Where each border texel of the extended faces takes its value from.

    A border texel (outside its face, on the face's gnomonic plane) covers a patch of the sphere
    that lies on neighbouring faces. Its value is the average over ``HALO_SUBSAMPLES^2``
    sub-samples of the texels they fall in: an area average, without the blur of a bilinear
    resampling (which smears a bright texel across the border by a third of a texel). Sub-samples
    that fall in the same texel are merged into one weighted entry (a handful per border texel
    remain), and all the averages are one sparse matrix product or one gather.

    ``pad`` must be a multiple of ``HALO_PAD_STEP`` (:func:`extend` rounds up and slices).

    Returns
    -------
    dst : (H,) int64 flat indices into ``(6, n, n)`` with ``n = res + 2 pad``
    avg : the averages, weights that are multiples of ``1 / HALO_SUBSAMPLES^2``, each border
        texel's summing to 1, over the flat texels of ``(6, res, res)``: an ``(H, 6 res^2)``
        sparse CSR matrix, or (:func:`_sparse_halo`) a pair ``(src (H, M) int32, w (H, M, 1))``
        of each border texel's ``M`` sources and weights (padded with zero weights)
    """
    n = res + 2 * pad
    rows, cols, src = _halo_sources(res, pad)
    dst = (torch.arange(6)[:, None] * (n * n) + rows * n + cols).reshape(-1)
    s = src.shape[-1]
    src = src.reshape(-1, s).sort(-1).values  # (H, S*S), equal sources adjacent
    new = torch.ones_like(src, dtype=torch.bool)
    new[:, 1:] = src[:, 1:] != src[:, :-1]
    # A run of equal sources is one entry weighted by its length. Every row starts a run, so
    # in row-major order a run ends where the next one starts.
    start = new.reshape(-1).nonzero().squeeze(1)
    length = torch.diff(start, append=start.new_full((1,), src.numel()))
    counts = new.sum(-1)  # (H,) entries per border texel
    col, weight = src.reshape(-1)[start], (length / s).to(dtype)
    if _sparse_halo(device):
        crow = torch.cat([torch.zeros(1, dtype=torch.long), counts.cumsum(0)])
        avg = _csr(crow, col, weight, (dst.numel(), 6 * res * res))
        return dst.to(device), avg.to(device)
    # padded rows: entry e of border texel h sits at column e; the padding reads texel 0 at
    # weight 0
    row = torch.repeat_interleave(torch.arange(dst.numel()), counts)
    slot = torch.arange(col.numel()) - (counts.cumsum(0) - counts)[row]
    width = int(counts.max())
    idx = torch.zeros(dst.numel(), width, dtype=torch.int32)
    w = torch.zeros(dst.numel(), width, dtype=dtype)
    idx[row, slot], w[row, slot] = col.int(), weight
    return dst.to(device), (idx.to(device), w[..., None].to(device))


def _sparse_halo(device: torch.device) -> bool:
    """Whether the halo's averages are a sparse matrix product (the CPU: the fewest operations)
    or a padded gather and weighted sum (elsewhere: three dense kernels, which a CUDA graph can
    capture and which run on any device, including ``meta``)."""
    return device.type == "cpu"


def _csr(crow, col, vals, size) -> torch.Tensor:
    """A sparse CSR matrix with int32 indices (torch flags its CSR support as beta)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return torch.sparse_csr_tensor(
            crow.to(torch.int32), col.to(torch.int32), vals, size, check_invariants=False
        )


def _halo_pad(pad: int) -> int:
    """Border width whose halo plan serves ``pad``: rounded up to a multiple of the step."""
    return max(HALO_PAD_STEP, -(-pad // HALO_PAD_STEP) * HALO_PAD_STEP)


def _extend_full(level: torch.Tensor, pad: int) -> torch.Tensor:
    """:func:`extend` for a ``pad`` that is a multiple of ``HALO_PAD_STEP``, ``(6, n, n, C)``."""
    res, ch = level.shape[1], level.shape[-1]
    n = res + 2 * pad
    dst, avg = _halo_plan(res, pad, level.device, level.dtype)
    out = level.new_empty(6, n, n, ch)
    out[:, pad : pad + res, pad : pad + res] = level
    flat = level.reshape(-1, ch)
    if isinstance(avg, tuple):
        idx, w = avg
        border = (flat.index_select(0, idx.view(-1)).view(*idx.shape, ch) * w).sum(1)
    else:
        border = avg @ flat
    out.view(-1, ch).index_copy_(0, dst, border)
    return out


def extend(level: torch.Tensor, pad: int) -> torch.Tensor:
    """Faces extended by ``pad`` texels on their gnomonic planes, ``(6, n, n, C)``.

    Parameters
    ----------
    level : (6, R, R, C)
    """
    big = _halo_pad(pad)
    off = big - pad
    out = _extend_full(level, big)
    if off:
        out = out[:, off : out.shape[1] - off, off : out.shape[2] - off]
    return out


@lru_cache(maxsize=32)
def _unfold_plan(res: int, pad: int, device: torch.device) -> torch.Tensor:
    """Texel indices of each face padded with its neighbours' real texels, ``(6, n, n)`` int64.

    The border is the neighbouring face folded flat along the shared edge (the cube's net), so
    border texel ``k`` rows past an edge is the neighbour's ``k``-th texel from that edge, whole
    and unresampled. The four corner blocks, which no face occupies (three faces, not four, meet
    at a cube corner), get -1. Every texel within ``pad`` texels of a face thus appears once.
    """
    c = _coords(res, -pad, res + pad, torch.device("cpu"))
    v, u = c[:, None], c[None, :]  # (n, 1), (1, n)
    ex_u = (u.abs() - 1).clamp_min(0)
    ex_v = (v.abs() - 1).clamp_min(0)
    corner = (ex_u > 0) & (ex_v > 0)  # (n, n)
    # folding onto the neighbour's plane: the point on the face's edge, moved in along the normal
    depth = 1 - (ex_u + ex_v)
    uc, vc = u.clamp(-1, 1), v.clamp(-1, 1)
    out = [cubemap.face_plane_texels(f, depth, uc, vc, res) for f in range(6)]
    return torch.stack(out).masked_fill_(corner, -1).to(device)


# --------------------------------------------------------------------------------------------
# quadrant tiles


def _tile_lines(half: int, n: int, device) -> torch.Tensor:
    """Row (or column) of an extended face, ``(2, n)`` int64, of each line of a quadrant tile.

    The extended face has ``2 half + 2 pad`` lines and a tile ``n = half + 2 pad``; side 1 (the
    ``+`` half of the face) is the tile as it lies, side 0 (the ``-`` half) is mirrored, so that
    tile line ``pad + k`` is face line ``half + k`` or ``half - 1 - k``.
    """
    i = torch.arange(n, device=device)
    return torch.stack([n - 1 - i, half + i])


def _tile_index(half: int, n: int, big: int, off: int, device) -> torch.Tensor:
    """Flat texel index, into ``(6, big, big)``, of each tile texel: ``(n, n, 2, 2, 6)`` int32.

    The tile stack's texel ``(i, j)`` holds tile ``(side_r, side_c, face)`` in the order of the
    last three axes; the extended faces have ``big`` lines, of which the tiles use the
    ``2 half + 2 pad`` starting at ``off``.
    """
    lines = _tile_lines(half, n, device).int() + off  # (2, n); int32 indices gather faster
    face = torch.arange(6, device=device, dtype=torch.int32) * (big * big)
    return (
        lines.T[:, None, :, None, None] * big + lines.T[None, :, None, :, None] + face
    )  # (n, n, 2, 2, 6)


def _untile_index(half: int, stride: int, off: int, device) -> torch.Tensor:
    """Where each texel of ``(6, R, R)`` is in the core of a stack of the 24 quadrant tiles.

    The core is ``(half, stride, 4, 6)`` (tile row, tile column, quadrant ``2 side_r + side_c``
    and face, the order of :func:`_tile_index`), its columns from ``off`` on. Returns flat row
    indices into it, ``(6, R, R)`` int32.
    """
    r = torch.arange(2 * half, device=device, dtype=torch.int32)
    side = (r >= half).int()
    k = torch.where(side == 1, r - half, half - 1 - r)  # tile line within the core
    rpart = k * (stride * 24) + side * 12
    cpart = (k + off) * 24 + side * 6
    face = torch.arange(6, device=device, dtype=torch.int32)
    return face[:, None, None] + rpart[None, :, None] + cpart[None, None, :]


# --------------------------------------------------------------------------------------------
# 1-D passes


def _half_taps(var: torch.Tensor, half: int) -> torch.Tensor:
    """Taps ``t = 0 .. half`` of normalised symmetric 1-D Gaussians: ``(half + 1, *var.shape)``.

    ``var`` is each kernel's variance in texels^2; the kernel is ``w[|t|]`` for ``-half <= t <=
    half``. The window cuts the tails (up to 1.5 % of the variance at ``PASS_SIGMAS``); the
    Gaussian is widened once so the truncated, normalised kernel keeps the variance asked for.
    Below 0.3 texel^2, where a sampled Gaussian no longer holds its variance, the 3-tap
    ``[v/2, 1 - v, v/2]``, whose variance is exactly ``v``.
    """
    dev, dt = var.device, var.dtype
    t = torch.arange(half + 1, device=dev, dtype=dt)
    t2 = (t * t).reshape(-1, *([1] * var.ndim))
    # both sides of the window: tap 0 once, the others twice
    twice = torch.full((half + 1,), 2.0, device=dev, dtype=dt)
    twice[0] = 1
    moments = torch.stack([twice, twice * t * t])  # (2, half + 1): mass and second moment
    v = var.clamp_min(1e-6)
    q = -0.5 / v
    # exponents below -80 (weights under 2e-35, nothing next to tap 0's 1) are held there: past
    # -87 float32 exp underflows, and its underflowing path is several times slower
    w = torch.exp((t2 * q).clamp_min_(-80))
    m = moments @ w.reshape(half + 1, -1)  # (2, N)
    got = (m[1] / m[0]).reshape(var.shape)
    q = q / (v / got.clamp_min(SMALL)).clamp(1, 1.1)
    w = torch.exp((t2 * q).clamp_min_(-80))
    w /= (moments[0] @ w.reshape(half + 1, -1)).reshape(var.shape)
    if half >= 1:
        small = var < 0.3
        w[0] = torch.where(small, 1 - var, w[0])
        w[1] = torch.where(small, var / 2, w[1])
        if half >= 2:
            w[2:] *= ~small
    return w


class _Pass:
    """One 1-D pass of :func:`anisotropic_increment` on a tile stack with rows ``n`` wide.

    ``out[i, j] = sum_t w[t, i, j] x[i + t step_r, j + t step_c]`` for ``|t| <= h`` and the
    output texels ``rows x cols`` (tile coordinates). Arrays hold whole rows of the tile,
    ``(rows, n, K)`` from a first row on; the texels between the end of the window on one row
    and its start on the next ride along (finite values nobody reads), so that the output is one
    run of consecutive texels, and the pass one batched matrix product: for output texel ``p``,
    ``(1, 2h + 1) @ (2h + 1, K)``, its taps against the ``2h + 1`` input texels ``p + t step``,
    whose ``K`` values are contiguous and which, for consecutive ``p``, are strided views of the
    same array (no copy).

    ``taps`` ``(B, 2h + 1)``, one row per texel of the run (``B`` of them), are the Gaussian
    taps (:func:`_half_taps`), times ``scale`` ``(n, n)`` at the texel each tap reads when given.
    """

    def __init__(self, step, rows, cols, n: int, var: torch.Tensor, h: int, scale=None):
        """``var`` ``(n, n)``: the tile's variances along the pass; ``h``: the window."""
        self.step, self.rows, self.cols, self.n = step, rows, cols, n
        (r0, r1), (c0, c1) = rows, cols
        #: texels from the window's first to its last, row-major: the batch of the product
        self.run = (r1 - r0 - 1) * n + (c1 - c0)
        start = r0 * n + c0
        half = _half_taps(var.reshape(-1)[start : start + self.run], h)  # (h + 1, B)
        mirror = torch.cat([torch.arange(h, 0, -1), torch.arange(h + 1)]).to(var.device)
        self.taps = half.index_select(0, mirror).T.contiguous()  # (B, 2h + 1), t = -h .. h
        if scale is not None:
            dev, i32 = var.device, torch.int32
            offset = (step[0] * n + step[1]) * torch.arange(-h, h + 1, device=dev, dtype=i32)
            texel = torch.arange(start, start + self.run, device=dev, dtype=i32)[:, None]
            read = scale.reshape(-1).index_select(0, (texel + offset).reshape(-1))
            self.taps *= read.view(self.taps.shape)

    def __call__(self, x: torch.Tensor, x_row: int) -> torch.Tensor:
        """Apply to ``x`` ``(rows_x, n, K)`` whose row 0 is tile row ``x_row``; returns the
        output rows ``(r1 - r0, n, K)``, valid in the window's columns."""
        k = x.shape[-1]
        n, b, w = self.n, self.run, self.taps
        (r0, r1), (c0, _) = self.rows, self.cols
        h = w.shape[1] // 2
        s = (self.step[0] * n + self.step[1]) * k  # elements between taps
        first = ((r0 - x_row) * n + c0) * k - h * s  # first tap of the run's first texel
        x = x.contiguous()
        view = x.as_strided((b, 2 * h + 1, k), (k, s, 1), x.storage_offset() + first)
        out = x.new_empty(r1 - r0, n, k)
        flat = out.view(-1, k)
        torch.bmm(w.view(b, 1, -1), view, out=flat[c0 : c0 + b].view(b, 1, k))
        flat[:c0] = 0  # the run's outside, so that every value of the array is finite
        flat[c0 + b :] = 0
        return out


def _tile_geometry(res: int, lam: float) -> tuple[float, int, int, int, int]:
    """Variance scale, pad and window half-widths of the three passes on a quadrant tile.

    The row pass runs on the core (face coordinates ``u, v`` in ``[0, 1]``), the column pass on
    rows extended by the row window, the diagonal pass on both extended. The diagonal variance
    ``rho^2 u v`` grows fast off the face; its window is sized at half the border and its kernel
    truncated (renormalised) beyond, which only touches the outermost, least-weighted texels.
    """
    sig2 = (res / 2) ** 2 / lam

    def var_max(f, u_hi, v_hi):  # maximum over a grid of [0, u_hi] x [0, v_hi]
        u = np.linspace(0, u_hi, 65)[None, :]
        v = np.linspace(0, v_hi, 65)[:, None]
        return float(f(u, v).max())

    def a_var(u, v):
        return (1 + u * u + v * v) * (1 + u * u - u * v)

    def c_var(u, v):
        return (1 + u * u + v * v) * u * v

    hb = math.ceil(PASS_SIGMAS * math.sqrt(sig2 * var_max(a_var, 1, 1)))  # b(u, v) = a(v, u)
    ha = math.ceil(PASS_SIGMAS * math.sqrt(sig2 * var_max(a_var, 1, 1 + 2 * hb / res)))
    far = 1 + max(ha, hb) / res
    hc = math.ceil(PASS_SIGMAS * math.sqrt(sig2 * var_max(c_var, far, far)))
    return sig2, max(ha, hb) + hc, ha, hb, hc


@lru_cache(maxsize=16)
def _anisotropic_plan(res: int, lam: float, device: torch.device, dtype: torch.dtype) -> tuple:
    """The tile border and the three passes of :func:`anisotropic_increment` for one level
    shape, ``(pad, passes, indices)``: the first pass weights what it reads by the texels'
    measure, the last one's taps are divided by the passes applied to a constant (the measure
    itself), which normalises the result; ``indices`` are :func:`_tile_indices` or None
    (:func:`_keep_indices`)."""
    sig2, pad, ha, hb, hc = _tile_geometry(res, lam)
    if pad > res:
        raise ValueError(f"vMF of sharpness {lam} too wide for the tiled path at resolution {res}")
    half = res // 2
    n = half + 2 * pad
    # canonical tile: face texels [res/2 - pad, res + pad) on both axes, u, v >= 0 at the core
    c = _coords(res, half - pad, res + pad, device)
    vv, uu = c[:, None], c[None, :]
    r2 = 1 + uu * uu + vv * vv
    # past the quadrant (u v < 0: the mirror tile's territory, needed only as intermediate
    # values near the core) the diagonal variance would be negative; there it is dropped and
    # the row and column passes carry the whole (nearly diagonal) covariance
    c_rc = sig2 * r2 * (uu * vv).clamp_min(0)
    a = sig2 * r2 * (1 + uu * uu) - c_rc
    b = sig2 * r2 * (1 + vv * vv) - c_rc
    # Measure: the exact kernel times the texel solid angle (prop. to rho^-3) is, in texel
    # coordinates, the Gaussian of covariance C tilted by rho^+1 to first order (Laplace's method
    # on the gnomonic plane), which moves its mean by C grad log rho (0.06 texel at u = v = 0.27
    # for sigma = 2.5 texels, as a dense exact sum confirms). Weighting texels by rho, not by
    # their solid angle, reproduces that drift; by solid angle it would be -3x it, the wrong way.
    # What this leaves out is the kernel's skew, a relative error of order sigma (in radians),
    # which grows as lobes widen: that is why coarse resolutions take the exact windowed path.
    om = torch.sqrt(r2).to(dtype)  # (n, n)

    # output windows of the passes in tile coordinates: diagonal, then columns, then rows
    core = (pad, pad + half)
    windows = (
        ((1, 1), (pad - hb, pad + half + hb), (pad - ha, pad + half + ha), c_rc, hc),
        ((0, 1), (pad - hb, pad + half + hb), core, a, ha),
        ((1, 0), core, core, b, hb),
    )
    # the first pass weights each texel it reads by om, the solid-angle measure above
    passes = [
        _Pass(step, rows, cols, n, var.to(dtype), h, om if i == 0 else None)
        for i, (step, rows, cols, var, h) in enumerate(windows)
    ]
    norm = _run_passes(torch.ones_like(om)[..., None], passes)  # (half, n, 1), valid in the core
    last = passes[-1]
    last.taps /= norm.view(-1)[core[0] : core[0] + last.run, None]
    return pad, passes, _tile_indices(res, pad, device) if _keep_indices(device) else None


def _keep_indices(device: torch.device) -> bool:
    """Whether plans keep the tile gather indices (tens of MB at 512^2) rather than rebuild them
    per call: on a GPU, where memory is plentiful and each rebuild is a dozen kernel launches;
    on the CPU a rebuild is a few cheap operations."""
    return device.type != "cpu"


def _tile_indices(res: int, pad: int, device) -> tuple[torch.Tensor, torch.Tensor]:
    """Gather indices of :func:`anisotropic_increment`: tile texels in the extended faces
    ``(n n 24,)`` and output texels in the passes' output ``(6 R^2,)``, int32."""
    half, big = res // 2, _halo_pad(pad)
    n = half + 2 * pad
    tiles = _tile_index(half, n, res + 2 * big, big - pad, device).reshape(-1)
    return tiles, _untile_index(half, n, pad, device).reshape(-1)


def _run_passes(x: torch.Tensor, passes, row: int = 0) -> torch.Tensor:
    """The passes of a plan on a tile stack ``(n, n, K)`` -> ``(half, n, K)``, valid in the
    core's columns."""
    for p in passes:
        x, row = p(x, row), p.rows[0]
    return x


def anisotropic_increment(level: torch.Tensor, lam: float) -> torch.Tensor:
    """Convolve a cube map with the normalised vMF of sharpness ``lam`` (narrow: a few texels).

    Parameters
    ----------
    level : (6, R, R, 3) radiance, R even

    Returns
    -------
    (6, R, R, 3), same dtype and device
    """
    res, ch = level.shape[1], level.shape[-1]
    dev = level.device
    pad, passes, indices = _anisotropic_plan(res, float(lam), dev, level.dtype)
    n = res // 2 + 2 * pad
    tiles, untile = indices or _tile_indices(res, pad, dev)
    ext = _extend_full(level, _halo_pad(pad))  # (6, R + 2 big, R + 2 big, C)
    x = ext.reshape(-1, ch).index_select(0, tiles).reshape(n, n, 24 * ch)  # the tiles' radiance
    y = _run_passes(x, passes)  # (half, n, 24 C), normalised in the core
    return y.reshape(-1, ch).index_select(0, untile).reshape(6, res, res, ch)


# --------------------------------------------------------------------------------------------
# exact paths for coarse resolutions


def _one_window_group(device: torch.device) -> bool:
    """Whether :func:`windowed_increment` sums all blocks in one product, windows padded to the
    widest: one kernel launch per level on a GPU, where launches cost more than the padding;
    on the CPU one product per window size, which wastes no work."""
    return device.type != "cpu"


@lru_cache(maxsize=16)
def _windowed_plan(res: int, lam: float, block: int, device: torch.device) -> tuple:
    """Tiles, windows and kernel geometry of :func:`windowed_increment` for one level shape.

    The face is cut into quadrant tiles as the separable path does when its block grid splits
    evenly (each tile mirrored into the ``u, v >= 0`` orientation, the net's geometry being
    symmetric under the mirrors), else into whole-face tiles. Blocks of the canonical tile with
    the same window size form a group (or all blocks, :func:`_one_window_group`).

    Returns ``(n, src, om, groups, untile)``:

    - ``src`` (n n T,) int32 source texel of each tile texel in ``(6 R^2 + 1)`` (the extra
      last texel is zero, for the net's empty corners), ``T`` tiles;
    - ``om`` (n, n) float32 solid angles of the canonical tile (0 in the corners);
    - ``groups``: ``(mu (G, P, 3), win (G Q,) int32, dirs (G, Q, 3), dst (G P,) int64)`` per
      group: the block texels' directions, the flat tile indices (``n^2``, a zero row, past a
      block's own window) and directions of their windows, and where the block's texels go in
      the flat ``(h, h)`` output core;
    - ``untile`` (6 R^2,) int32 index into the output core's ``(h h T)`` rows, or None when
      the tiles are whole faces (then the core is ``(R, R, 6)`` in face order).
    """
    sigma = 1 / math.sqrt(lam)
    bs = min(block, res)
    blocks = res // bs
    # radial angular size of a texel at face point p: (2/R) / (1 + |p|^2); per block use the
    # block's outer corner (its smallest texels) to size the window in texels
    edges = torch.linspace(-1, 1, blocks + 1, dtype=torch.float64)
    far = torch.maximum(edges[:-1].abs(), edges[1:].abs()) ** 2  # (blocks,)
    wins = torch.ceil(WINDOW_SIGMAS * sigma / ((2 / res) / (1 + far[:, None] + far[None, :])))
    wins = wins.long().tolist()  # (blocks, blocks) window half-widths
    pad = max(max(r) for r in wins)
    if pad > res:
        raise ValueError(f"kernel too wide for windowed convolution at resolution {res}")
    cpu = torch.device("cpu")
    idx = _unfold_plan(res, pad, cpu)  # (6, N, N), -1 in the corner blocks
    big = res + 2 * pad
    quads = blocks % 2 == 0
    if quads:
        half = res // 2
        n = half + 2 * pad
        lines = _tile_lines(half, n, cpu)  # (2, n)
        face = torch.arange(6)
        src = idx[face, lines.T[:, None, :, None, None], lines.T[None, :, None, :, None]]
        src = src.reshape(n, n, 24)
        core_blocks = range(blocks // 2, blocks)  # the canonical tile is the + quadrant's
        first = blocks // 2
    else:
        half, n = res, big
        src = idx.permute(1, 2, 0)  # (N, N, 6)
        core_blocks = range(blocks)
        first = 0
    src = torch.where(src >= 0, src, 6 * res * res)
    dirs = cubemap.texel_directions(res, dtype=torch.float32).reshape(-1, 3)
    dirs = torch.cat([dirs, dirs[:1]])[src[..., 0]]  # (n, n, 3); corners are masked by om
    om = torch.cat([cubemap.texel_solid_angles(res).reshape(-1), torch.zeros(1)])[src[..., 0]]
    # blocks of the canonical tile, grouped by window half-width, or all in one group whose
    # windows are padded to the widest (the padding points at the zero row n^2)
    by_win: dict[int, list[tuple[int, int, int]]] = {}
    for bi in core_blocks:
        for bj in core_blocks:
            w = pad if _one_window_group(device) else wins[bi][bj]
            by_win.setdefault(w, []).append((bi - first, bj - first, wins[bi][bj]))
    flat_dirs = torch.cat([dirs.reshape(-1, 3), torch.zeros(1, 3)])  # and the zero row's
    k = torch.arange(bs)
    groups = []
    for w, members in sorted(by_win.items()):
        r0 = torch.tensor([pad + bi * bs for bi, _, _ in members])  # (G,) block origins
        c0 = torch.tensor([pad + bj * bs for _, bj, _ in members])
        own = torch.tensor([wb for _, _, wb in members])[:, None]  # (G, 1) their own windows
        kk = torch.arange(-w, bs + w)
        win = (r0[:, None, None] + kk[None, :, None]) * n + c0[:, None, None] + kk[None, None, :]
        outside = (kk < -own) | (kk >= bs + own)  # (G, L)
        win = win.masked_fill(outside[:, :, None] | outside[:, None, :], n * n)
        blk = (r0[:, None, None] + k[None, :, None]) * n + c0[:, None, None] + k[None, None, :]
        blk, win = blk.reshape(len(members), -1), win.reshape(len(members), -1)
        dst = (r0[:, None, None] - pad + k[None, :, None]) * half + (
            c0[:, None, None] - pad + k[None, None, :]
        )
        group = (flat_dirs[blk], win.reshape(-1).int(), flat_dirs[win], dst.reshape(-1))
        groups.append(tuple(a.to(device) for a in group))
    untile = _untile_index(half, half, 0, cpu).reshape(-1).to(device) if quads else None
    return n, src.reshape(-1).int().to(device), om.to(device), groups, untile


def windowed_increment(level: torch.Tensor, lam_inc: float, *, block: int = 8) -> torch.Tensor:
    """Exact convolution of a cube map with a narrow vMF of sharpness ``lam_inc``.

    Each face is padded with its neighbours' real texels (:func:`_unfold_plan`), so every output
    texel sees a window of the map's own texels around it. The sum uses the exact kernel
    ``exp(lam (mu.w - 1))`` with the true directions and exact solid angles of those texels, so
    it equals the dense sum up to the kernel's weight beyond ``WINDOW_SIGMAS``. The face is cut
    into ``block x block`` texel blocks whose window is sized to their smallest texels (texels
    shrink by up to 3x toward the corners); each block's sum is one matrix product,
    ``(block^2, window texels) @ (window texels, tiles x channels + 1)``, for the blocks of one
    window size at once, all tiles sharing the kernel (:func:`_windowed_plan`).

    Parameters
    ----------
    level : (6, R, R, 3) normalised radiance
    block : side of the output blocks, in texels (at most R)

    Returns
    -------
    (6, R, R, 3)
    """
    res, ch = level.shape[1], level.shape[-1]
    dev, dt = level.device, level.dtype
    n, src, om, groups, untile = _windowed_plan(res, float(lam_inc), block, dev)
    tiles = src.numel() // (n * n)
    half = res // 2 if untile is not None else res
    # beyond the window radius the kernel is below exp(-WINDOW_SIGMAS^2 / 2): cut there, after
    # the exponential (whose arguments then stay finite, the fast path of exp)
    g_cut = math.exp(lam_inc * (math.cos(min(math.pi, WINDOW_SIGMAS / math.sqrt(lam_inc))) - 1))
    flat = torch.cat([level.reshape(-1, ch), level.new_zeros(1, ch)])
    # (n n + 1, T C + 1): radiance x solid angle of every tile and the solid angle, then a zero
    # row for the window entries past a block's own window
    f = level.new_zeros(n * n + 1, tiles * ch + 1)
    om_t = om.to(dt).reshape(-1, 1)
    torch.mul(flat.index_select(0, src).reshape(n * n, tiles * ch), om_t, out=f[:-1, :-1])
    f[:-1, -1:] = om_t
    out = level.new_empty(half * half, tiles * ch + 1)
    for mu, win, wdirs, dst in groups:
        g = torch.bmm(mu.to(dt), wdirs.to(dt).transpose(1, 2))  # (G, P, Q) dot products
        g = torch.nn.functional.threshold_(g.sub_(1).mul_(lam_inc).exp_(), g_cut, 0)
        acc = torch.bmm(g, f.index_select(0, win).reshape(g.shape[0], -1, f.shape[1]))
        out.index_copy_(0, dst, acc.reshape(-1, f.shape[1]))  # (G P, T C + 1)
    val = out[:, :-1] / out[:, -1:]  # (h h, T C)
    if untile is None:
        return val.reshape(res, res, tiles, ch).permute(2, 0, 1, 3).contiguous()
    return val.reshape(-1, ch).index_select(0, untile).reshape(6, res, res, ch)


def dense_increment(level: torch.Tensor, lam: float, *, chunk: int = 2048) -> torch.Tensor:
    """Exact convolution of a small cube map with the normalised vMF of sharpness ``lam``.

    Every output texel sums over every input texel with the exact kernel and solid angles:
    ``(6 R^2)^2`` work, for ``R <= 32``.

    Parameters
    ----------
    level : (6, R, R, 3)

    Returns
    -------
    (6, R, R, 3)
    """
    res = level.shape[1]
    dev = level.device
    d = cubemap.texel_directions(res, device=dev).reshape(-1, 3)
    om = cubemap.texel_solid_angles(res, device=dev).reshape(-1, 1)
    f = torch.cat([level.reshape(-1, 3) * om, om], 1)  # (N, 4)
    out = torch.empty(d.shape[0], 3, device=dev, dtype=level.dtype)
    for i in range(0, d.shape[0], chunk):  # bounded memory: (chunk, N) kernel block
        acc = torch.exp((d[i : i + chunk] @ d.T - 1) * lam) @ f
        out[i : i + chunk] = acc[:, :3] / acc[:, 3:]
    return out.reshape(level.shape)


# --------------------------------------------------------------------------------------------
# spherical harmonics for the widest lobes


#: Extra terms of the continued fraction of :func:`vmf_band_factors` past ``order + lam``,
#: where its terms ``lam / (2 l + 1)`` have fallen below 1 and each one past gains a factor.
_BESSEL_EXTRA_TERMS = 64


def vmf_band_factors(lam: float, order: int) -> np.ndarray:
    """Funk-Hecke factors ``a_l = i_l(lam) / i_0(lam)`` of the normalised vMF, ``(order,)``.

    ``(L * vMF)_lm = a_l L_lm``, with ``i_l`` the modified spherical Bessel functions. Computed
    as products of the ratios ``r_l = i_l / i_{l-1}``, which the recurrence
    ``i_{l-1} - i_{l+1} = (2 l + 1) / lam * i_l`` gives as the continued fraction
    ``r_l = lam / (2 l + 1 + lam r_{l+1})``, evaluated backwards from ``r = 0`` far enough out
    (``i_l`` is the recurrence's minimal solution, so the backward sweep is stable): ratios,
    so nothing overflows at any ``lam``.
    """
    l = np.arange(order, dtype=np.float64)
    if lam < 1e-8:
        return (l == 0).astype(np.float64)
    ratios = np.ones(order, dtype=np.float64)
    r = 0.0
    for k in range(order + math.ceil(lam) + _BESSEL_EXTRA_TERMS, 0, -1):
        r = lam / (2 * k + 1 + lam * r)
        if k < order:
            ratios[k] = r
    return np.cumprod(ratios)


def sh_order_for(lam: float) -> int:
    """Fewest bands whose first dropped band factor is below ``SH_BAND_EPS``."""
    order = 1
    while vmf_band_factors(lam, order + 1)[-1] > SH_BAND_EPS:
        order += 1
    return order


#: Directions whose basis values are computed at once (a few MB of float64 work arrays).
_BASIS_CHUNK = 2048


def _sh_basis_rows(d: torch.Tensor, order: int) -> torch.Tensor:
    """Real SH basis of unit directions ``d`` (N, 3) float64, band-major: ``(order^2, N)``.

    The conventions and recurrences of :func:`lobelight.lobes.sh.basis` (the same values), laid
    out with the directions in the last axis so that each step of the recurrence over bands is
    one operation on contiguous rows.
    """
    x, y, z = d.T.contiguous()
    dev, dt = d.device, d.dtype
    n = d.shape[0]
    out = torch.empty(order * order, n, device=dev, dtype=dt)
    # sqrt(2) sin^m(theta) (cos, sin)(m phi): real and imaginary parts of (x + i y)^m
    cos_m = torch.empty(order, n, device=dev, dtype=dt)
    sin_m = torch.empty(order, n, device=dev, dtype=dt)
    cos_m[0], sin_m[0] = 1, 0
    for m in range(1, order):
        cos_m[m] = x * cos_m[m - 1] - y * sin_m[m - 1]
        sin_m[m] = x * sin_m[m - 1] + y * cos_m[m - 1]
    cos_m *= math.sqrt(2.0)
    sin_m *= math.sqrt(2.0)
    # q[m] = K_l^m P_l^m(z) / sin^m(theta) for the current band l, m = 0 .. l
    q_prev2 = None
    q_prev = torch.full((1, n), 1.0 / math.sqrt(4.0 * math.pi), device=dev, dtype=dt)
    out[0] = q_prev[0]
    for l in range(1, order):
        q = torch.empty(l + 1, n, device=dev, dtype=dt)
        if l >= 2:
            # m = 0 .. l-2: q_l = a (z q_{l-1} - b q_{l-2}), the normalised three-term recurrence
            m = torch.arange(l - 1, device=dev, dtype=dt)
            a = torch.sqrt((4.0 * l * l - 1.0) / (l * l - m * m))[:, None]
            b = torch.sqrt(((l - 1.0) ** 2 - m * m) / (4.0 * (l - 1.0) ** 2 - 1.0))[:, None]
            torch.mul(a, z * q_prev[: l - 1] - b * q_prev2, out=q[: l - 1])
        q[l - 1] = math.sqrt(2.0 * l + 1.0) * z * q_prev[l - 1]
        q[l] = math.sqrt((2.0 * l + 1.0) / (2.0 * l)) * q_prev[l - 1]
        c = l * l + l  # index of m = 0
        out[c] = q[0]
        torch.mul(q[1:], cos_m[1 : l + 1], out=out[c + 1 : c + l + 1])
        out[c - l : c] = (q[1:] * sin_m[1 : l + 1]).flip(0)  # m = -l .. -1
        q_prev2, q_prev = q_prev, q
    return out


@lru_cache(maxsize=16)
def _basis(res: int, order: int, device: torch.device) -> torch.Tensor:
    """SH basis at the texel centres of a cube map, band-major ``(order^2, 6 res^2)`` float32.

    Depends on the resolution only, so it is kept between calls; computed in float64 in chunks
    of directions, at the float32 texel directions renormalised (as
    :func:`lobelight.lobes.sh.basis` of ``cubemap.texel_directions(res)``).
    """
    d = cubemap.texel_directions(res, device=device).reshape(-1, 3).double()
    d = torch.nn.functional.normalize(d, dim=-1)
    out = torch.empty(order * order, d.shape[0], device=device, dtype=torch.float32)
    for s in range(0, d.shape[0], _BASIS_CHUNK):
        out[:, s : s + _BASIS_CHUNK] = _sh_basis_rows(d[s : s + _BASIS_CHUNK], order)
    return out


@lru_cache(maxsize=8)
def _sh_plan(
    src_res: int, lams: tuple, resolutions: tuple, device: torch.device, dtype: torch.dtype
) -> tuple:
    """What :func:`sh_levels` needs besides the map, ``(order, om, groups)``: the SH order, the
    source's texel solid angles ``(6 S^2, 1)`` and, per output resolution, ``(res, which, fac)``
    with the output indices of its levels and their band factors ``(order^2, L, 1)``."""
    box = (2 / src_res) ** 2 / 12  # variance already in the source's texels
    eff = [1 / max(1 / lam - box, SMALL) for lam in lams]
    order = sh_order_for(max(eff))
    om = cubemap.texel_solid_angles(src_res, device=device, dtype=dtype).reshape(-1, 1)
    band = np.repeat(np.arange(order), 2 * np.arange(order) + 1)
    groups = []
    for res in sorted(set(resolutions)):
        which = [i for i, r in enumerate(resolutions) if r == res]
        fac = np.stack([vmf_band_factors(eff[i], order)[band] for i in which], 1)  # (o^2, L)
        groups.append((res, which, torch.as_tensor(fac[:, :, None], device=device, dtype=dtype)))
    return order, om, groups


def sh_levels(
    source: torch.Tensor, lams: list[float], resolutions: list[int]
) -> list[torch.Tensor]:
    """Exact vMF convolutions of ``source`` at each ``lams[i]``, sampled at ``resolutions[i]``.

    Parameters
    ----------
    source : (6, S, S, 3) area-averaged map; its texels' own box blur (variance ``h^2/12``) is
        taken out of each lobe's variance.
    lams, resolutions : one entry per output level.

    Returns
    -------
    list of (6, R_i, R_i, 3)

    One projection, then one reconstruction per resolution for all its levels together.
    """
    dev, dt = source.device, source.dtype
    order, om, groups = _sh_plan(
        source.shape[1], tuple(map(float, lams)), tuple(resolutions), dev, dt
    )
    # a fourth channel of ones: dividing by its reconstruction keeps a constant map exactly
    # constant (the cube's midpoint quadrature leaks ~1e-5 of it into higher bands otherwise)
    ones = torch.ones_like(source[..., :1])
    coef = _basis(source.shape[1], order, dev).to(dt) @ (
        torch.cat([source, ones], -1).reshape(-1, 4) * om
    )
    out: list[torch.Tensor | None] = [None] * len(lams)
    for res, which, fac in groups:
        scaled = (coef[:, None, :] * fac).reshape(order * order, -1)  # (o^2, 4L)
        rec = (_basis(res, order, dev).to(dt).T @ scaled).reshape(6, res, res, len(which), 4)
        val = rec[..., :3] / rec[..., 3:]
        for col, i in enumerate(which):
            out[i] = val[..., col, :].contiguous()
    return out


# --------------------------------------------------------------------------------------------
# bilinear reconstruction prefilter


def sharpen(level: torch.Tensor, a: float = SHARPEN) -> torch.Tensor:
    """Separable ``[-a, 1 + 2a, -a]`` on each face (neighbours across edges), ``(6, R, R, C)``."""
    p = cubemap.pad_seamless(level, 1)
    # each pass: one new array, then in-place scaling and accumulation
    x = torch.add(p[:, :, :-2], p[:, :, 2:]).mul_(-a).add_(p[:, :, 1:-1], alpha=1 + 2 * a)
    return torch.add(x[:, :-2], x[:, 2:]).mul_(-a).add_(x[:, 1:-1], alpha=1 + 2 * a)
