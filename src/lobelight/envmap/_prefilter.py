"""Gaussian-prefiltered environment lighting: one lookup integrates a spherical Gaussian.

For a spherical Gaussian ``G(w; mu, lam) = exp(lam (mu.w - 1))`` the integral against the
lighting factors into the Gaussian's own integral and a normalised average of the lighting::

    int G(w; mu, lam) L(w) dw  =  Z(lam) * Lbar_lam(mu),     Z(lam) = 2 pi (1 - exp(-2 lam)) / lam

``Lbar_lam`` is the lighting convolved with the von Mises-Fisher density of concentration ``lam``.
This module tabulates ``Lbar`` for a geometric ladder of sharpness values and reads it back
with one bilinear (direction) x linear (sharpness) interpolation.

Level ladder
    Level ``k`` has sharpness ``lam_k = lam_0 * rho**-k`` with ``rho = 4**(1/phases)``. Levels come
    in groups of ``phases`` per cube-map resolution: level ``k`` lives on mip ``m = k // phases``
    (resolution ``base_res >> m``) as phase ``j = k % phases``. ``lam_0`` puts the Gaussian's
    standard deviation at ``TEXELS_PER_SIGMA`` texels at the centre of a base face, the finest
    width a bilinear lookup reproduces to about 1 %. Why phases: a plain mip chain quadruples
    ``lam`` per level, and blending two Gaussians four times apart in ``lam`` misrepresents the
    Gaussian in between by up to 29 % (relative L2) for a point-like light such as the sun; with
    four phases (``rho = sqrt 2``) the blend error is under 1 %.

GL layout
    Phase ``j`` over all mips is an ordinary mip-mapped cube map: ``gl_chains()[j][m]`` is the
    ``(6, R_m, R_m, 3)`` level, uploaded as is (GL face order and texel orientation, see
    :mod:`lobelight.cubemap`). A shader computes ``k`` from ``lam`` as :meth:`level_coords` does and
    fetches two levels with ``textureLod`` at integer lods.

How the levels are built
    A cascade: each level is the previous one convolved with the narrow vMF that takes its width
    to the next (widths tracked as vMF mean cosines, which multiply under convolution), after a
    2 x 2 solid-angle-weighted downsample when the mip changes. Above ``dense_max_res`` the
    increment is an exact windowed sum on each face's extended gnomonic plane (true directions,
    exact solid angles, neighbouring faces resampled onto the border); at or below it, an exact
    dense sum. Each level is stored slightly sharper than its nominal ``lam_k`` because a
    bilinear lookup adds on average ``h**2 / 6`` of variance per axis (``h`` the texel size).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import scipy.special
import torch

from .. import cubemap
from .._backend import as_tensor
from ..errors import InputError

__all__ = ["TEXELS_PER_SIGMA", "Prefiltered", "prefilter"]

#: Gaussian standard deviation, in texels at the centre of a face, of every level's phase 0.
TEXELS_PER_SIGMA = 2.5
#: Extent of a Gaussian kernel window, in standard deviations (weight exp(-4.3**2/2) < 1e-4).
WINDOW_SIGMAS = 4.3
#: Band factors below this are dropped from the spherical-harmonic path.
SH_BAND_EPS = 1e-5


def sg_integral(lam: torch.Tensor) -> torch.Tensor:
    """``int exp(lam (mu.w - 1)) dw = 2 pi (1 - exp(-2 lam)) / lam``, stable for small lam."""
    return 2 * math.pi * (-torch.expm1(-2 * lam)) / lam


def _langevin(lam: torch.Tensor) -> torch.Tensor:
    # Mean cosine of a vMF: coth(lam) - 1/lam, with its series near 0.
    lam = lam.to(torch.float64)
    small = lam < 1e-3
    safe = torch.where(small, torch.ones_like(lam), lam)
    big = 1 / torch.tanh(safe) - 1 / safe
    return torch.where(small, lam / 3, big)


def vmf_band_factors(lam: float, order: int) -> np.ndarray:
    """Funk-Hecke factors ``a_l = i_l(lam) / i_0(lam)`` of the normalised vMF, ``(order,)``.

    ``(L * vMF)_lm = a_l L_lm``. Uses exponentially scaled Bessel functions (no overflow).
    """
    l = np.arange(order, dtype=np.float64)
    return scipy.special.ive(l + 0.5, lam) / scipy.special.ive(0.5, lam)


def _sh_order_for(lam: float) -> int:
    # Smallest order whose last band factor is below SH_BAND_EPS.
    order = 2
    while vmf_band_factors(lam, order + 1)[-1] > SH_BAND_EPS:
        order += 1
    return order + 1


@dataclass
class Prefiltered:
    """A Gaussian-prefiltered environment: ``integrate(mu, lam)`` in one interpolated lookup.

    Attributes
    ----------
    levels : list of (6, R_k, R_k, 3) float32 tensors
        ``Lbar`` at the sharpness ``lambdas[k]`` (normalised: a constant map gives the constant).
    lambdas : (K,) float64 tensor, decreasing, ``lam_0 * rho**-k``.
    phases : int, levels per mip resolution.
    blend : "moment" or "l2", how two neighbouring levels are weighted (see :meth:`level_coords`).
    """

    levels: list[torch.Tensor]
    lambdas: torch.Tensor
    phases: int
    blend: str = "moment"
    name: str = "envmap"
    _padded: list[torch.Tensor] = field(default_factory=list, repr=False)

    def __post_init__(self) -> None:
        if not self._padded:
            self._padded = [cubemap.pad_seamless(lv) for lv in self.levels]

    @property
    def device(self) -> torch.device:
        return self.levels[0].device

    @property
    def base_res(self) -> int:
        return int(self.levels[0].shape[1])

    @property
    def lam_max(self) -> float:
        """Sharpest lobe the chain resolves (level 0); sharper lobes are clamped to it."""
        return float(self.lambdas[0])

    @property
    def lam_min(self) -> float:
        """Widest tabulated lobe; wider lobes use the last level."""
        return float(self.lambdas[-1])

    def level_coords(self, lam: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Fractional level of each sharpness: ``(k0 (...) int64, t (...))``.

        The lookup is ``(1 - t) Lbar_{k0} + t Lbar_{k0+1}``. With ``blend="moment"`` ``t`` makes the
        blend's mean cosine equal the requested vMF's, so the lighting's SH bands 0 and 1 are
        reproduced exactly and smooth lighting is right to second order. With ``blend="l2"`` ``t``
        minimises the L2 distance between the blended and the requested kernel in the small-angle
        limit (closed form for 2-D Gaussians), which halves the error for point lights.
        """
        lam = as_tensor(lam, device=self.device).to(torch.float64)
        lams = self.lambdas.to(lam.device)
        rho = float(lams[0] / lams[1])
        kf = torch.log(lams[0] / lam.clamp_min(1e-12)) / math.log(rho)
        kmax = len(self.levels) - 1
        k0 = kf.floor().clamp(0, kmax - 1).long()
        la, lb = lams[k0], lams[k0 + 1]
        if self.blend == "l2":
            s, sa, sb = 1 / lam, 1 / la, 1 / lb

            def ip(x, y):  # <N_x, N_y> for normalised 2-D Gaussians of variances x, y (x 2 pi)
                return 1 / (x + y)

            num = ip(s, sb) - ip(s, sa) - ip(sa, sb) + ip(sa, sa)
            den = ip(sa, sa) - 2 * ip(sa, sb) + ip(sb, sb)
            t = num / den
        else:
            ma, mb, m = _langevin(la), _langevin(lb), _langevin(lam)
            t = (ma - m) / (ma - mb)
        t = torch.where(kf < 0, torch.zeros_like(t), t)
        t = torch.where(kf > kmax, torch.ones_like(t), t)
        return k0, t.clamp(0, 1)

    def lookup(self, mu, lam) -> torch.Tensor:
        """Normalised Gaussian average of the lighting, ``(..., 3)``.

        Parameters
        ----------
        mu : (..., 3) lobe axes (need not be unit)
        lam : (...) or scalar sharpness, broadcast against ``mu[..., 0]``
        """
        mu = as_tensor(mu, device=self.device)
        lam = as_tensor(lam, device=self.device).to(torch.float64)
        shape = torch.broadcast_shapes(mu.shape[:-1], lam.shape)
        mu = mu.expand(*shape, 3).reshape(-1, 3)
        lam = lam.expand(shape).reshape(-1)
        k0, t = self.level_coords(lam)
        out = torch.zeros(mu.shape[0], 3, device=self.device, dtype=self.levels[0].dtype)
        tt = t.to(out.dtype).unsqueeze(-1)
        # One pass per level (a loop over levels, not elements): gather the lobes that use it.
        for k in range(len(self.levels)):
            for sel, w in ((k0 == k, 1 - tt), (k0 + 1 == k, tt)):
                idx = sel.nonzero().squeeze(-1)
                if idx.numel():
                    val = cubemap.sample(self.levels[k], mu[idx], padded=self._padded[k])
                    out.index_add_(0, idx, w[idx] * val)
        return out.reshape(*shape, 3)

    def integrate(self, mu, lam) -> torch.Tensor:
        """``int G(w; mu, lam) L(w) dw`` for each lobe, ``(..., 3)``.

        Parameters
        ----------
        mu : (..., 3) lobe axes;  lam : (...) sharpness in ``[lam_min, lam_max]`` for full accuracy.
        """
        lam = as_tensor(lam, device=self.device)
        z = sg_integral(lam.to(torch.float64)).to(self.levels[0].dtype)
        return self.lookup(mu, lam) * z.unsqueeze(-1)

    def gl_chains(self) -> list[list[np.ndarray]]:
        """Levels as ``phases`` mip-mapped cube maps: ``[phase][mip] -> (6, R, R, 3) float32``."""
        chains: list[list[np.ndarray]] = [[] for _ in range(self.phases)]
        for k, lv in enumerate(self.levels):
            chains[k % self.phases].append(lv.detach().cpu().numpy().astype(np.float32))
        return chains

    def nbytes(self) -> int:
        return sum(lv.numel() * lv.element_size() for lv in self.levels)


# --------------------------------------------------------------------------------------------
# building


def _extended_grid(res: int, pad: int, device) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Directions, solid angles and face coordinates of a face grid extended by ``pad`` texels.

    Returns ``dirs (6, n, n, 3)``, ``omega (6, n, n)`` and ``uv (n,)`` with ``n = res + 2 pad``.
    The extended plane is the face's gnomonic chart, so its texels tile a region of the sphere
    without overlap and their solid angles follow from the same closed form as inside the face.
    """
    k = torch.arange(-pad, res + pad + 1, device=device, dtype=torch.float64)
    e = 2 * k / res - 1  # texel edges
    c = (e[1:] + e[:-1]) / 2  # centres
    y, x = torch.meshgrid(e, e, indexing="ij")
    a = torch.atan2(x * y, torch.sqrt(x * x + y * y + 1))
    omega = (a[1:, 1:] - a[:-1, 1:] - a[1:, :-1] + a[:-1, :-1]).abs()
    n = res + 2 * pad
    v, u = torch.meshgrid(c, c, indexing="ij")
    face = torch.arange(6, device=device).reshape(6, 1, 1).expand(6, n, n)
    d = cubemap.face_uv_to_direction(face, u.expand(6, n, n), v.expand(6, n, n))
    return torch.nn.functional.normalize(d, dim=-1), omega.expand(6, n, n), c


def _windowed_increment(level: torch.Tensor, lam_inc: float, *, blocks: int = 4) -> torch.Tensor:
    """Exact convolution of a cube map with a narrow vMF of sharpness ``lam_inc``.

    Each face is extended by a border on its gnomonic plane (the neighbouring faces resampled
    bilinearly onto it), so every output texel sees a window of real texels around it. The sum
    uses the exact kernel ``exp(lam (mu.w - 1))`` with the true directions and exact solid
    angles of the window's texels. The face is cut into ``blocks x blocks`` regions whose window
    is sized to their smallest texels (texels shrink by up to 3x toward the corners), so the
    window always spans ``WINDOW_SIGMAS`` standard deviations without paying for it everywhere.

    Parameters
    ----------
    level : (6, R, R, 3) normalised radiance

    Returns
    -------
    (6, R, R, 3)
    """
    res = level.shape[1]
    dev, dt = level.device, level.dtype
    sigma = 1 / math.sqrt(lam_inc)
    # radial angular size of a texel at face point p: (2/R) / (1 + |p|^2); per block use the
    # block's outer corner (its smallest texels) to size the window in texels
    bs = res // blocks
    edges = torch.linspace(-1, 1, blocks + 1, dtype=torch.float64)
    far = torch.maximum(edges[:-1].abs(), edges[1:].abs())  # (blocks,) farthest |coord| per block
    wins = [
        [
            math.ceil(
                WINDOW_SIGMAS * sigma / ((2 / res) / (1 + float(far[i]) ** 2 + float(far[j]) ** 2))
            )
            for j in range(blocks)
        ]
        for i in range(blocks)
    ]
    pad = max(max(r) for r in wins)
    if pad > res:
        raise ValueError(f"kernel too wide for windowed convolution at resolution {res}")
    dirs, omega, _ = _extended_grid(res, pad, dev)
    dirs = dirs.to(dt).permute(3, 0, 1, 2).contiguous()  # (3, 6, n, n)
    vals = cubemap.sample(level, dirs.permute(1, 2, 3, 0))  # (6, n, n, 3)
    om = omega.to(dt)
    f = torch.cat([(vals * om.unsqueeze(-1)).permute(3, 0, 1, 2), om.unsqueeze(0)], 0)  # (4,6,n,n)
    out = torch.empty(4, 6, res, res, device=dev, dtype=dt)
    cos_cut = math.cos(min(math.pi, WINDOW_SIGMAS * sigma))
    for bi in range(blocks):
        for bj in range(blocks):
            w = wins[bi][bj]
            r0, c0 = pad + bi * bs, pad + bj * bs  # block origin in the extended grid
            mu = dirs[:, :, r0 : r0 + bs, c0 : c0 + bs]  # (3, 6, bs, bs)
            acc = torch.zeros(4, 6, bs, bs, device=dev, dtype=dt)
            for di in range(-w, w + 1):
                for dj in range(-w, w + 1):
                    if di * di + dj * dj > w * w:
                        continue
                    nb = dirs[:, :, r0 + di : r0 + di + bs, c0 + dj : c0 + dj + bs]
                    dot = (mu * nb).sum(0)  # (6, bs, bs)
                    # beyond the window radius the kernel is below exp(-WINDOW_SIGMAS^2 / 2)
                    g = torch.where(dot > cos_cut, torch.exp((dot - 1) * lam_inc), 0.0)
                    acc.addcmul_(
                        g.unsqueeze(0), f[:, :, r0 + di : r0 + di + bs, c0 + dj : c0 + dj + bs]
                    )
            out[:, :, bi * bs : (bi + 1) * bs, bj * bs : (bj + 1) * bs] = acc
    return (out[:3] / out[3:4]).permute(1, 2, 3, 0).contiguous()


def _dense_increment(level: torch.Tensor, lam_inc: float, *, chunk: int = 2048) -> torch.Tensor:
    """Exact convolution of a (small) cube map with a vMF of sharpness ``lam_inc``.

    Every output texel sums over every input texel with the exact kernel and solid angles:
    ``(6 R^2)^2`` work, used only at small resolutions where windows would span most of a face.

    Parameters
    ----------
    level : (6, R, R, 3) normalised radiance

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
        # float32 is enough: the kernel is in [0, 1] and the sums are ratios of like terms
        acc = torch.exp((d[i : i + chunk] @ d.T - 1) * lam_inc) @ f
        out[i : i + chunk] = acc[:, :3] / acc[:, 3:]
    return out.reshape(level.shape)


def _inverse_langevin(a: float) -> float:
    """Sharpness whose vMF has mean cosine ``a`` in (0, 1)."""
    if a <= 0:
        return 0.0
    if a >= 1 - 1e-12:
        return float("inf")
    lo, hi = 1e-9, 1e9
    for _ in range(200):  # bisection in log space: 200 halvings reach float64 resolution
        mid = math.sqrt(lo * hi)
        if float(_langevin(torch.tensor(mid))) < a:
            lo = mid
        else:
            hi = mid
    return math.sqrt(lo * hi)


def prefilter(
    env,
    *,
    base_res: int = 512,
    phases: int = 4,
    dense_max_res: int = 16,
    blend: str = "moment",
    device=None,
) -> Prefiltered:
    """Build the Gaussian-prefiltered chain of an environment.

    Parameters
    ----------
    env : EnvMap, or a (6, R, R, 3) cube map (tensor or array)
    base_res : resolution of the sharpest level's faces (a power of two); the chain resolves
        ``lam`` up to ``(base_res / (2 TEXELS_PER_SIGMA))**2`` (10486 for 512).
    phases : levels per mip resolution (sharpness ratio ``4**(1/phases)`` between levels).
    dense_max_res : levels at this resolution or coarser are convolved exactly (dense sums).
    blend : "moment" or "l2" (see :meth:`Prefiltered.level_coords`).
    device : torch device for the computation and the result (default: the env's).

    Returns
    -------
    Prefiltered
    """
    if base_res < 1 or base_res & (base_res - 1):
        raise InputError("base_res", f"must be a power of two, got {base_res}")
    if phases < 1:
        raise InputError("phases", f"must be >= 1, got {phases}")
    if blend not in ("moment", "l2"):
        raise InputError("blend", f"must be 'moment' or 'l2', got {blend!r}")
    name = getattr(env, "name", "envmap")
    if hasattr(env, "to_cubemap"):
        if device is not None:
            env = env.to(device)
        base = env.to_cubemap(base_res)
    else:
        base = as_tensor(env, device=device, dtype=torch.float32)
        if tuple(base.shape) != (6, base_res, base_res, 3):
            if base.ndim == 4 and base.shape[0] == 6 and base.shape[1] > base_res:
                while base.shape[1] > base_res:
                    base = cubemap.downsample(base)
            else:
                raise InputError(
                    "env",
                    f"expected a (6, {base_res}, {base_res}, 3) cube map, got {tuple(base.shape)}",
                )
    base = base.to(torch.float32)
    dev = base.device
    n_mips = int(math.log2(base_res)) + 1
    rho = 4 ** (1 / phases)
    lam0 = (base_res / (2 * TEXELS_PER_SIGMA)) ** 2
    n_levels = n_mips * phases
    lambdas = lam0 * rho ** -torch.arange(n_levels, dtype=torch.float64)

    def mc(lam: float) -> float:  # mean cosine of a vMF: widths compose by multiplying it
        return float(_langevin(torch.tensor(lam, dtype=torch.float64)))

    def h(res: int) -> float:  # texel size (radians) at a face centre
        return 2.0 / res

    # Widths are tracked as vMF mean cosines, which multiply under convolution (exactly for the
    # first SH band) and reduce to adding variances 1/lam for narrow lobes. A box-filtered texel
    # and a 2 x 2 downsample blur by variances h^2/12 and h^2/16; a bilinear lookup adds h^2/6
    # on average, so each level is stored that much sharper than its nominal lam_k.
    levels: list[torch.Tensor] = []
    cur, cur_res = base, base_res
    cur_mc = mc(12 / h(base_res) ** 2)
    for k in range(n_levels):
        res = base_res >> (k // phases)
        while cur_res > res:
            cur = cubemap.downsample(cur)
            cur_res //= 2
            cur_mc *= mc(16 / h(cur_res) ** 2)
        target = mc(float(lambdas[k])) / (mc(6 / h(res) ** 2) if res >= 8 else 1.0)
        if target < cur_mc:
            lam_inc = _inverse_langevin(target / cur_mc)
            if res > dense_max_res:
                cur = _windowed_increment(cur, lam_inc)
            else:
                cur = _dense_increment(cur, lam_inc)
            cur_mc = target
        levels.append(cur)
    return Prefiltered(
        levels=levels, lambdas=lambdas.to(dev), phases=phases, blend=blend, name=name
    )
