"""Spherical convolution of cube maps with von Mises-Fisher kernels: the prefilter's engine.

Three operators, each exact or controlled to well under the prefilter's 2 % budget:

``anisotropic_increment``  (fine levels, ``R >= 64``)
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
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import scipy.special
import torch

from ..geometry import cubemap
from ..lobes import sh

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


def _solid_angles(res: int, lo: int, hi: int, device) -> torch.Tensor:
    """Exact solid angles of the extended-plane texels ``[lo, hi)^2``, ``(n, n)`` float64."""
    e = 2 * torch.arange(lo, hi + 1, device=device, dtype=torch.float64) / res - 1
    y, x = torch.meshgrid(e, e, indexing="ij")
    a = torch.atan2(x * y, torch.sqrt(x * x + y * y + 1))
    return (a[1:, 1:] - a[:-1, 1:] - a[1:, :-1] + a[:-1, :-1]).abs()


@lru_cache(maxsize=4)
def _halo_sources(res: int, pad: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Border texels of the extended faces and the sub-samples' source texels, on the CPU.

    Returns
    -------
    rows, cols : (B,) int64 border texels of the ``(n, n)`` grid, ``n = res + 2 pad``, row-major
    src : (6, B, S*S) int64 flat indices into ``(6, res, res)``
    """
    k = torch.arange(-pad, res + pad)
    inside = (k >= 0) & (k < res)
    border = ~(inside[:, None] & inside[None, :])  # (n, n)
    rows, cols = border.nonzero(as_tuple=True)
    s = HALO_SUBSAMPLES
    sub = (torch.arange(s, dtype=torch.float64) + 0.5) / s  # (S,)
    # sub-sample face coordinates of every border texel, broadcast to (B, S, S)
    v = 2 * (rows[:, None, None] - pad + sub[None, :, None]) / res - 1
    u = 2 * (cols[:, None, None] - pad + sub[None, None, :]) / res - 1
    one = torch.ones((), dtype=torch.float64)
    src = [cubemap._face_plane_texels(f, one, u, v, res).reshape(-1, s * s) for f in range(6)]
    return rows, cols, torch.stack(src)


@lru_cache(maxsize=32)
def _halo_plan(res: int, pad: int, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """Where each border texel of the extended faces takes its value from.

    A border texel (outside its face, on the face's gnomonic plane) covers a patch of the sphere
    that lies on neighbouring faces. Its value is the average over ``HALO_SUBSAMPLES^2``
    sub-samples of the texels they fall in: an area average, without the blur of a bilinear
    resampling (which smears a bright texel across the border by a third of a texel).

    A texel's sources do not depend on ``pad``, so the plan is cut out of the one for ``pad``
    rounded up to a multiple of ``HALO_PAD_STEP`` (the cascade's increments at one resolution
    share it).

    Returns
    -------
    dst : (H,) int64 flat indices into ``(6, n, n)`` with ``n = res + 2 pad``
    src : (H, S*S) int64 flat indices into ``(6, res, res)``
    """
    n = res + 2 * pad
    big = -(-pad // HALO_PAD_STEP) * HALO_PAD_STEP
    rows, cols, src = _halo_sources(res, big)
    off = big - pad
    keep = (rows >= off) & (rows < off + n) & (cols >= off) & (cols < off + n)
    cell = (rows[keep] - off) * n + (cols[keep] - off)  # (H/6,) in row-major order
    dst = (torch.arange(6)[:, None] * (n * n) + cell).reshape(-1)
    src = src[:, keep].reshape(-1, src.shape[-1])
    return dst.to(device), src.to(device)


def extend(level: torch.Tensor, pad: int) -> torch.Tensor:
    """Faces extended by ``pad`` texels on their gnomonic planes, ``(6, n, n, C)``.

    Parameters
    ----------
    level : (6, R, R, C)
    """
    res, ch = level.shape[1], level.shape[-1]
    n = res + 2 * pad
    out = level.new_empty(6 * n * n, ch)
    dst, src = _halo_plan(res, pad, level.device)
    flat = level.reshape(-1, ch)
    out[dst] = flat[src].mean(1)
    out = out.reshape(6, n, n, ch)
    out[:, pad : pad + res, pad : pad + res] = level
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
    out = [cubemap._face_plane_texels(f, depth, uc, vc, res) for f in range(6)]
    return torch.stack(out).masked_fill_(corner, -1).to(device)


# --------------------------------------------------------------------------------------------
# 1-D passes


def _gauss_taps(var: torch.Tensor, half: int) -> torch.Tensor:
    """Normalised 1-D Gaussian kernels of variance ``var`` (texels^2): ``(2 half + 1, *var.shape)``.

    The window cuts the tails (up to 1.5 % of the variance at ``PASS_SIGMAS``); the Gaussian is
    widened once so the truncated, normalised kernel keeps the variance asked for. Below
    0.3 texel^2, where a sampled Gaussian no longer holds its variance, the 3-tap
    ``[v/2, 1 - v, v/2]``, whose variance is exactly ``v``.
    """
    t = torch.arange(-half, half + 1, device=var.device, dtype=var.dtype)
    t = t.reshape(-1, *([1] * var.ndim))
    v = var.clamp_min(1e-6)
    w = torch.exp(-(t * t) / (2 * v))
    got = (w * t * t).sum(0) / w.sum(0)
    w = torch.exp(-(t * t) / (2 * v * (v / got.clamp_min(1e-12)).clamp(1, 1.1)))
    w = w / w.sum(0, keepdim=True)
    if half >= 1:
        small = var < 0.3
        three = torch.zeros_like(w)
        three[half] = 1 - var
        three[half - 1] = var / 2
        three[half + 1] = var / 2
        w = torch.where(small, three, w)
    return w


def _pass(
    x: torch.Tensor,
    w: torch.Tensor,
    step: tuple[int, int],
    rows: tuple[int, int],
    cols: tuple[int, int],
) -> torch.Tensor:
    """``out[i, j] = sum_t w[t, i, j] x[i + t step_r, j + t step_c]`` on a window of ``x``.

    Parameters
    ----------
    x : (B, C, H, W);  w : (T, h, w) taps for the output window ``rows x cols`` of ``x``.

    Returns
    -------
    (B, C, h, w)
    """
    half = (w.shape[0] - 1) // 2
    r0, r1 = rows
    c0, c1 = cols
    out = x.new_zeros(x.shape[0], x.shape[1], r1 - r0, c1 - c0)
    for i, t in enumerate(range(-half, half + 1)):
        dr, dc = t * step[0], t * step[1]
        out.addcmul_(x[:, :, r0 + dr : r1 + dr, c0 + dc : c1 + dc], w[i])
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


def anisotropic_increment(level: torch.Tensor, lam: float) -> torch.Tensor:
    """Convolve a cube map with the normalised vMF of sharpness ``lam`` (narrow: a few texels).

    Parameters
    ----------
    level : (6, R, R, 3) radiance, R even

    Returns
    -------
    (6, R, R, 3), same dtype and device
    """
    res = level.shape[1]
    dev, dt = level.device, level.dtype
    sig2, pad, ha, hb, hc = _tile_geometry(res, lam)
    if pad > res:
        raise ValueError(f"vMF of sharpness {lam} too wide for the tiled path at resolution {res}")
    half = res // 2
    n = half + 2 * pad
    # canonical tile: face texels [res/2 - pad, res + pad) on both axes, u, v >= 0 at the core
    c = _coords(res, half - pad, res + pad, dev)
    vv, uu = torch.meshgrid(c, c, indexing="ij")
    r2 = 1 + uu * uu + vv * vv
    # past the quadrant (u v < 0: the mirror tile's territory, needed only as intermediate
    # values near the core) the diagonal variance would be negative; there it is dropped and
    # the row and column passes carry the whole (nearly diagonal) covariance
    c_rc = sig2 * r2 * (uu * vv).clamp_min(0)
    a = (sig2 * r2 * (1 + uu * uu) - c_rc).to(dt)
    b = (sig2 * r2 * (1 + vv * vv) - c_rc).to(dt)
    c_rc = c_rc.to(dt)
    # Measure: the exact kernel times the texel solid angle (prop. to rho^-3) is, in texel
    # coordinates, the Gaussian of covariance C tilted by rho^+1 to first order (Laplace's method
    # on the gnomonic plane), which moves its mean by C grad log rho (0.06 texel at u = v = 0.27
    # for sigma = 2.5 texels, as a dense exact sum confirms). Weighting texels by rho, not by
    # their solid angle, reproduces that drift; by solid angle it would be -3x it, the wrong way.
    # What this leaves out is the kernel's skew, a relative error of order sigma (in radians):
    # 1.3 % of the peak for a single bright texel at lam = 2600, 5 % at lam = 160, which is why
    # coarse resolutions take the exact windowed path instead.
    om = torch.sqrt(r2).to(dt)  # (n, n)

    # output windows of the passes, in tile coordinates: diagonal, then columns, then rows
    core = (pad, pad + half)
    w1 = ((pad - hb, pad + half + hb), (pad - ha, pad + half + ha))
    w2 = ((pad - hb, pad + half + hb), core)
    w3 = (core, core)

    def taps(var, win, h):
        return _gauss_taps(var[win[0][0] : win[0][1], win[1][0] : win[1][1]], h)

    k1, k2, k3 = taps(c_rc, w1, hc), taps(a, w2, ha), taps(b, w3, hb)

    def run(x: torch.Tensor) -> torch.Tensor:  # (B, C, n, n) -> (B, C, half, half)
        y = _pass(x, k1, (1, 1), *w1)
        # y covers w1; the column pass reads it at offsets relative to w1's origin
        y = _pass(y, k2, (0, 1), (0, y.shape[2]), (ha, ha + half))
        return _pass(y, k3, (1, 0), (hb, hb + half), (0, half))

    norm = run(om[None, None])[0, 0]  # (half, half), the passes applied to the solid angles
    ext = extend(level, pad)  # (6, R + 2 pad, R + 2 pad, 3)
    ext = ext.permute(0, 3, 1, 2)  # (6, 3, n_ext, n_ext)
    tiles = []
    for qr in (0, 1):
        rs = slice(half, half + n) if qr else slice(0, n)
        for qc in (0, 1):
            cs = slice(half, half + n) if qc else slice(0, n)
            t = ext[:, :, rs, cs]
            flips = [d for d, q in ((2, qr), (3, qc)) if not q]
            tiles.append(t.flip(flips) if flips else t)
    x = torch.cat(tiles, 0) * om  # (24, 3, n, n), radiance x solid angle
    y = run(x) / norm  # (24, 3, half, half)
    out = torch.empty(6, 3, res, res, device=dev, dtype=dt)
    for i, (qr, qc) in enumerate(((0, 0), (0, 1), (1, 0), (1, 1))):
        t = y[6 * i : 6 * (i + 1)]
        flips = [d for d, q in ((2, qr), (3, qc)) if not q]
        t = t.flip(flips) if flips else t
        out[:, :, qr * half : (qr + 1) * half, qc * half : (qc + 1) * half] = t
    return out.permute(0, 2, 3, 1).contiguous()


# --------------------------------------------------------------------------------------------
# exact paths for coarse resolutions


def windowed_increment(level: torch.Tensor, lam_inc: float, *, block: int = 8) -> torch.Tensor:
    """Exact convolution of a cube map with a narrow vMF of sharpness ``lam_inc``.

    Each face is padded with its neighbours' real texels (:func:`_unfold_plan`), so every output
    texel sees a window of the map's own texels around it. The sum uses the exact kernel
    ``exp(lam (mu.w - 1))`` with the true directions and exact solid angles of those texels, so
    it equals the dense sum up to the kernel's weight beyond ``WINDOW_SIGMAS`` (measured 1e-4
    relative). The face is cut into ``block x block`` texel blocks whose window is sized to their
    smallest texels (texels shrink by up to 3x toward the corners); each block's sum is one
    matrix product, ``(block^2, window texels) @ (window texels, 6 faces x 4 channels)``.

    Parameters
    ----------
    level : (6, R, R, 3) normalised radiance
    block : side of the output blocks, in texels (at most R)

    Returns
    -------
    (6, R, R, 3)
    """
    res = level.shape[1]
    dev, dt = level.device, level.dtype
    sigma = 1 / math.sqrt(lam_inc)
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
    idx = _unfold_plan(res, pad, dev)  # (6, n, n), -1 in the corner blocks
    valid = idx >= 0
    idx = idx.clamp_min(0)
    # The padded net of every face is the same set of texels up to the cube's rotations, so the
    # kernel (which needs only dot products) and the solid angles are those of face 0 for all.
    dirs = cubemap.texel_directions(res, device=dev, dtype=dt).reshape(-1, 3)[idx[0]]  # (n, n, 3)
    om = cubemap.texel_solid_angles(res, device=dev, dtype=dt).reshape(-1)[idx[0]] * valid[0]
    vals = level.reshape(-1, 3)[idx] * valid[..., None]  # (6, n, n, 3)
    # (n, n, 6, 4): radiance x solid angle and the solid angle, each texel's faces side by side
    f = torch.cat([vals * om[..., None], om.expand(6, -1, -1)[..., None]], -1).permute(1, 2, 0, 3)
    out = torch.empty(res, res, 6, 4, device=dev, dtype=dt)
    cos_cut = math.cos(min(math.pi, WINDOW_SIGMAS * sigma))
    for bi in range(blocks):
        for bj in range(blocks):
            w = wins[bi][bj]
            r0, c0 = pad + bi * bs, pad + bj * bs  # block origin in the extended grid
            rows, cols = slice(r0 - w, r0 + bs + w), slice(c0 - w, c0 + bs + w)
            mu = dirs[r0 : r0 + bs, c0 : c0 + bs].reshape(-1, 3)  # (P, 3) output texels
            dot = mu @ dirs[rows, cols].reshape(-1, 3).T  # (P, Q) with the window's texels
            # beyond the window radius the kernel is below exp(-WINDOW_SIGMAS^2 / 2)
            cut = dot <= cos_cut
            g = dot.sub_(1).mul_(lam_inc).exp_().masked_fill_(cut, 0)
            acc = g @ f[rows, cols].reshape(-1, 24)  # (P, 24)
            out[r0 - pad : r0 - pad + bs, c0 - pad : c0 - pad + bs] = acc.reshape(bs, bs, 6, 4)
    return (out[..., :3] / out[..., 3:]).permute(2, 0, 1, 3).contiguous()


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


def vmf_band_factors(lam: float, order: int) -> np.ndarray:
    """Funk-Hecke factors ``a_l = i_l(lam) / i_0(lam)`` of the normalised vMF, ``(order,)``.

    ``(L * vMF)_lm = a_l L_lm``; exponentially scaled Bessel functions, so no overflow.
    """
    l = np.arange(order, dtype=np.float64)
    if lam < 1e-8:
        return (l == 0).astype(np.float64)
    return scipy.special.ive(l + 0.5, lam) / scipy.special.ive(0.5, lam)


def sh_order_for(lam: float) -> int:
    """Fewest bands whose first dropped band factor is below ``SH_BAND_EPS``."""
    order = 1
    while vmf_band_factors(lam, order + 1)[-1] > SH_BAND_EPS:
        order += 1
    return order


@lru_cache(maxsize=16)
def _basis(res: int, order: int, device: torch.device) -> torch.Tensor:
    # (6 res^2, order^2) float32: depends on the resolution only, so it is kept between calls
    return sh.basis(cubemap.texel_directions(res, device=device), order).reshape(-1, order * order)


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
    """
    dev, dt = source.device, source.dtype
    s = source.shape[1]
    box = (2 / s) ** 2 / 12  # variance already in the source's texels
    eff = [1 / max(1 / lam - box, 1e-12) for lam in lams]
    order = sh_order_for(max(eff))
    ys = _basis(s, order, dev)
    om = cubemap.texel_solid_angles(s, device=dev).reshape(-1, 1)
    # a fourth channel of ones: dividing by its reconstruction keeps a constant map exactly
    # constant (the cube's midpoint quadrature leaks ~1e-5 of it into higher bands otherwise)
    ones = torch.ones_like(source[..., :1])
    coef = ys.T @ (torch.cat([source, ones], -1).reshape(-1, 4) * om)  # (order^2, 4)
    band = torch.arange(order, device=dev).repeat_interleave(
        2 * torch.arange(order, device=dev) + 1
    )
    out = []
    for lam, res in zip(eff, resolutions, strict=True):
        fac = torch.as_tensor(vmf_band_factors(lam, order), device=dev, dtype=dt)[band]
        rec = _basis(res, order, dev) @ (coef * fac[:, None])  # (6 res^2, 4)
        out.append((rec[:, :3] / rec[:, 3:]).reshape(6, res, res, 3))
    return out


# --------------------------------------------------------------------------------------------
# bilinear reconstruction prefilter


def sharpen(level: torch.Tensor, a: float = SHARPEN) -> torch.Tensor:
    """Separable ``[-a, 1 + 2a, -a]`` on each face (neighbours across edges), ``(6, R, R, C)``."""
    p = cubemap.pad_seamless(level, 1)
    x = (1 + 2 * a) * p[:, :, 1:-1] - a * (p[:, :, :-2] + p[:, :, 2:])
    return (1 + 2 * a) * x[:, 1:-1] - a * (x[:, :-2] + x[:, 2:])
