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
    width a bilinear lookup (after the reconstruction prefilter) reproduces to under 1 %.
    Why phases: a plain mip chain quadruples ``lam`` per level, and blending two Gaussians
    four times apart in ``lam`` misrepresents the Gaussian in between by up to 29 % (relative
    L2) for a point-like light such as the sun; with four phases (``rho = sqrt 2``) the blend
    error is under 1 %.

GL layout
    Phase ``j`` over all mips is an ordinary mip-mapped cube map: ``gl_chains()[j][m]`` is the
    ``(6, R_m, R_m, 3)`` level, uploaded as is (GL face order and texel orientation, see
    :mod:`lobelight.geometry.cubemap`). A shader computes ``k`` from ``lam`` as
    :meth:`level_coords` does and fetches two levels with ``textureLod`` at integer lods.

How the levels are built (see :mod:`._convolve` for each operator)
    Fine levels come from a cascade: each level is the previous one convolved with the narrow
    vMF that takes its width to the next (widths tracked as vMF mean cosines, which multiply
    under convolution), after a 2 x 2 solid-angle-weighted downsample when the mip changes. The
    increment is a separable anisotropic three-pass filter at ``R >= SEPARABLE_MIN_RES`` and an
    exact windowed sum over the face and its neighbours' real texels below that. Levels at
    ``R <= SH_MAX_RES`` (the widest lobes, where a cascade of narrow increments drifts from a
    vMF, and where one projection is cheaper than any sum) come directly from exact
    spherical-harmonic band factors. Every stored level then gets a small sharpening, the
    reconstruction prefilter that makes bilinear lookup of a 2.5-texel Gaussian accurate to
    0.8 % instead of 2 %.

Cache
    :func:`prefilter` keeps chains on disk (:mod:`._chain_cache`), keyed by a hash of the map and
    of the settings, so a map is prefiltered once per machine: by default an EnvMap's chain,
    ``cache=`` chooses otherwise.
"""

from __future__ import annotations

import logging
import math
import numbers
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np
import torch

from .._backend import as_tensor
from .._tol import SHARPNESS_MIN
from ..errors import InputError
from ..geometry import cubemap
from ..lobes import sg
from . import _chain_cache, _convolve

__all__ = ["CHAIN_VERSION", "TEXELS_PER_SIGMA", "Prefiltered", "clear_memory_caches", "prefilter"]

logger = logging.getLogger(__name__)

#: Gaussian standard deviation, in texels at the centre of a face, of every level's phase 0.
TEXELS_PER_SIGMA = 2.5
#: Levels at least this fine get the bilinear reconstruction prefilter.
SHARPEN_MIN_RES = 4
#: Levels at this face resolution or coarser come straight from spherical harmonics (up to
#: order 31 for the 32^2 levels, on a 64^2 copy of the map).
SH_MAX_RES = 32
#: Cascade increments at this resolution or finer use the separable anisotropic passes (their
#: relative error scales with the lobe width in radians, so it falls as resolution rises);
#: between the two, exact windowed sums.
SEPARABLE_MIN_RES = 256


def _langevin(lam: torch.Tensor) -> torch.Tensor:
    # Mean cosine of a vMF: coth(lam) - 1/lam, with its series near 0.
    lam = lam.to(torch.float64)
    small = lam < 1e-3
    safe = torch.where(small, torch.ones_like(lam), lam)
    big = 1 / torch.tanh(safe) - 1 / safe
    return torch.where(small, lam / 3, big)


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
    blend: str = "l2"
    name: str = "envmap"
    _padded: list[torch.Tensor] = field(default_factory=list, repr=False)

    def __post_init__(self) -> None:
        if not self._padded:
            self._padded = _per_resolution(self.levels, sharpen=False)[1]

    @property
    def device(self) -> torch.device:
        return self.levels[0].device

    @property
    def padded(self) -> list[torch.Tensor]:
        """The levels with a border of one seamless texel, ``(6, R_k + 2, R_k + 2, 3)`` each
        (:func:`lobelight.geometry.cubemap.pad_seamless`): what a bilinear lookup reads."""
        return self._padded

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
        kf = torch.log(lams[0] / lam.clamp_min(SHARPNESS_MIN)) / math.log(rho)
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
        z = sg.integral(lam.to(torch.float64)).to(self.levels[0].dtype)
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


@lru_cache(maxsize=16)
def _downsample_weights(
    res: int, device: torch.device, dtype: torch.dtype
) -> tuple[torch.Tensor, torch.Tensor]:
    """Texel solid angles ``(R, R, 1)`` of a face and their 2 x 2 sums ``(R/2, R/2, 1)``: the
    weights of :func:`_downsample`, the same for every face."""
    om = cubemap.texel_solid_angles(res, device=device, dtype=dtype)[0]
    h = res // 2
    return om[..., None], om.reshape(h, 2, h, 2).sum((1, 3))[..., None]


def _downsample(cube: torch.Tensor) -> torch.Tensor:
    """:func:`lobelight.geometry.cubemap.downsample` of a ``(6, R, R, C)`` cube: the 2 x 2
    solid-angle-weighted average. The pairs of rows, then of columns, of the weighted texels
    are summed as two additions of strided halves (no reduction kernel)."""
    res, ch = cube.shape[1], cube.shape[-1]
    if res % 2:
        raise InputError("cube", f"resolution must be even to downsample, got {res}")
    h = res // 2
    om, den = _downsample_weights(res, cube.device, cube.dtype)
    x = (cube * om).view(6, h, 2, res * ch)
    rows = (x[:, :, 0] + x[:, :, 1]).view(6, h, h, 2 * ch)
    return (rows[..., :ch] + rows[..., ch:]).div_(den)


def _downsample_to(cube: torch.Tensor, res: int) -> torch.Tensor:
    """Solid-angle-weighted 2 x 2 downsamples of ``(6, R, R, C)`` until the faces are ``res``."""
    while cube.shape[1] > res:
        cube = _downsample(cube)
    return cube


def _mean_cosine(lam: float) -> float:
    """Mean cosine of a vMF of sharpness ``lam``: ``coth(lam) - 1/lam``, its series near 0."""
    if lam < 1e-3:
        return lam / 3
    return 1 / math.tanh(lam) - 1 / lam


#: A mean cosine within this of 1 is a delta (infinite sharpness): the vMF of sharpness ``lam``
#: has ``1 - a ~ 1/lam``, so this is ``lam ~ 1e12``, past the bisection's upper end (1e9).
_MEAN_COSINE_GAP_MIN = 1e-12


def _inverse_langevin(a: float) -> float:
    """Sharpness whose vMF has mean cosine ``a`` in (0, 1)."""
    if a <= 0:
        return 0.0
    if a >= 1 - _MEAN_COSINE_GAP_MIN:
        return float("inf")
    lo, hi = 1e-9, 1e9
    for _ in range(200):  # bisection in log space: 200 halvings reach float64 resolution
        mid = math.sqrt(lo * hi)
        if _mean_cosine(mid) < a:
            lo = mid
        else:
            hi = mid
    return math.sqrt(lo * hi)


#: Version of what :func:`prefilter` computes, part of every cache key: bumped whenever a change
#: to the algorithm changes the levels (the constants above and in :mod:`._convolve` are in the
#: key by value, so changing one of them needs no bump).
CHAIN_VERSION = 2


def _description(kind: str, base_res: int, phases: int) -> dict:
    """Everything besides the source's values that a chain's levels depend on (the cache key)."""
    return {
        "chain_version": CHAIN_VERSION,
        "source": kind,
        "base_res": base_res,
        "phases": phases,
        "constants": {
            "TEXELS_PER_SIGMA": TEXELS_PER_SIGMA,
            "SHARPEN_MIN_RES": SHARPEN_MIN_RES,
            "SH_MAX_RES": SH_MAX_RES,
            "SEPARABLE_MIN_RES": SEPARABLE_MIN_RES,
            "PASS_SIGMAS": _convolve.PASS_SIGMAS,
            "WINDOW_SIGMAS": _convolve.WINDOW_SIGMAS,
            "SHARPEN": _convolve.SHARPEN,
            "SH_BAND_EPS": _convolve.SH_BAND_EPS,
            "HALO_SUBSAMPLES": _convolve.HALO_SUBSAMPLES,
        },
    }


def _folder(cache, is_map: bool) -> Path | None:
    """Where the chain is cached (None: not at all) for the ``cache`` argument of prefilter."""
    if cache is None:
        cache = is_map
    return _chain_cache.cache_folder(cache, "None, a bool or a folder")


def clear_memory_caches() -> None:
    """Forget the index plans and SH bases kept in memory between calls (a fresh process's
    state, for timing a cold start)."""
    for fn in (
        _convolve._halo_plan,
        _convolve._unfold_plan,
        _convolve._basis,
        _convolve._anisotropic_plan,
        _convolve._windowed_plan,
        _convolve._sh_plan,
        _downsample_weights,
        _schedule,
        cubemap.seamless_pad_plan,
    ):
        fn.cache_clear()


def prefilter(
    env,
    *,
    base_res: int = 512,
    phases: int = 4,
    blend: str = "l2",
    device=None,
    cache=None,
) -> Prefiltered:
    """Build the Gaussian-prefiltered chain of an environment, or read it from the disk cache.

    Parameters
    ----------
    env : EnvMap, or a (6, R, R, 3) cube map (tensor or array; a finer one is box-downsampled)
    base_res : resolution of the sharpest level's faces (a power of two); the chain resolves
        ``lam`` up to ``(base_res / (2 TEXELS_PER_SIGMA))**2`` (10486 for 512).
    phases : levels per mip resolution (sharpness ratio ``4**(1/phases)`` between levels).
    blend : "moment" or "l2" (see :meth:`Prefiltered.level_coords`).
    device : torch device for the computation and the result (default: the env's).
    cache : where the levels are kept between processes (:mod:`._chain_cache`): None (the
        default) caches an EnvMap's chain in ``lobelight._cache.cache_dir() / "prefilter"`` and
        not a raw cube map's; True caches either there, a folder caches either in that folder,
        False never reads or writes a cache. The key is a hash of the map's values, layout,
        dtype and shape and of ``base_res``, ``phases`` and the algorithm's version and
        constants; ``blend`` is not in it (it only weights levels at lookup), nor ``device``
        (entries are stored from the CPU and loaded onto ``device``).

    Returns
    -------
    Prefiltered
    """
    check_settings(base_res, phases, blend)
    name = getattr(env, "name", "envmap")
    is_map = hasattr(env, "to_cubemap")
    folder = _folder(cache, is_map)
    if is_map:
        if device is not None:
            env = env.to(device)
        source, kind = env.data, f"envmap:{env.layout}"
    else:
        env = as_tensor(env, device=device, dtype=torch.float32)
        source, kind = env, "cube"
        _check_source_cube(env, base_res)
    if folder is not None:
        description = _description(kind, base_res, phases)
        key = _chain_cache.chain_key(source, description)
        path = folder / f"{key}.npz"
        hit = _chain_cache.read_chain(path, key, _resolutions(base_res, phases))
        if hit is not None:
            dev = source.device
            lambdas = torch.from_numpy(hit[0]).to(dev)
            levels = [torch.from_numpy(lv).to(dev) for lv in hit[1]]
            return Prefiltered(
                levels=levels, lambdas=lambdas, phases=phases, blend=blend, name=name
            )
    base = base_cube(env, base_res)
    levels, padded = _build(base, base_res, phases)
    lambdas = _lambdas(base_res, phases).to(base.device)
    if folder is not None:
        try:
            _chain_cache.write_chain(path, key, description, lambdas, levels)
        except OSError as exc:  # a cache that cannot be written only costs the next run time
            logger.warning("could not write the prefiltered chain to %s: %s", path, exc)
    return Prefiltered(
        levels=levels, lambdas=lambdas, phases=phases, blend=blend, name=name, _padded=padded
    )


def check_settings(base_res: int, phases: int, blend: str) -> None:
    """Refuse a chain's settings that :func:`prefilter` cannot build, naming the setting."""
    if isinstance(base_res, bool) or not isinstance(base_res, numbers.Integral) or base_res < 1:
        raise InputError("base_res", f"must be a power of two, got {base_res!r}")
    if base_res & (base_res - 1):
        raise InputError("base_res", f"must be a power of two, got {base_res}")
    if isinstance(phases, bool) or not isinstance(phases, numbers.Integral) or phases < 1:
        raise InputError("phases", f"must be an integer >= 1, got {phases!r}")
    if blend not in ("moment", "l2"):
        raise InputError("blend", f"must be 'moment' or 'l2', got {blend!r}")


def _check_source_cube(cube: torch.Tensor, base_res: int) -> None:
    """Refuse a cube map that is neither ``(6, base_res, base_res, 3)`` nor a finer cube.

    Not :func:`lobelight._checks.check_cube`: a chain's source must have three channels and at
    least ``base_res`` texels a side, and the message names the shape it expects."""
    shape = tuple(cube.shape)
    finer = cube.ndim == 4 and shape[0] == 6 and shape[1] == shape[2] > base_res
    if shape != (6, base_res, base_res, 3) and not (finer and shape[3] == 3):
        raise InputError("env", f"expected a (6, {base_res}, {base_res}, 3) cube map, got {shape}")


def base_cube(env, base_res: int, *, check_finite: bool = True) -> torch.Tensor:
    """The ``(6, base_res, base_res, 3)`` float32 cube map a chain is built from, on the env's
    device: an EnvMap resampled, a finer cube box-downsampled. Refuses NaN and Inf values
    (``check_finite``: one value read back to the host).

    Parameters
    ----------
    env : EnvMap, or a (6, R, R, 3) float32 tensor with ``R >= base_res`` (checked by the caller)
    """
    if hasattr(env, "to_cubemap"):
        base = env.to_cubemap(base_res).to(torch.float32)
    else:
        base = env if env.shape[1] == base_res else _downsample_to(env, base_res)
    if check_finite and not bool(torch.isfinite(base).all()):
        raise InputError("env", "cube map has NaN or Inf values")
    return base


def _resolutions(base_res: int, phases: int) -> list[int]:
    """Face resolution of every level: ``phases`` levels per mip, ``base_res`` down to 1."""
    n_mips = int(math.log2(base_res)) + 1
    return [base_res >> (k // phases) for k in range(n_mips * phases)]


def _lambdas(base_res: int, phases: int) -> torch.Tensor:
    """Sharpness of every level, ``(K,)`` float64: ``lam_0 rho**-k``."""
    n_levels = len(_resolutions(base_res, phases))
    lam0 = (base_res / (2 * TEXELS_PER_SIGMA)) ** 2
    return lam0 * (4 ** (1 / phases)) ** -torch.arange(n_levels, dtype=torch.float64)


@dataclass(frozen=True)
class _Step:
    """How one cascade level is made from the one before: ``reseed`` starts over from the map
    at ``res``; ``downsamples`` 2 x 2 downsamples follow; then an increment of sharpness ``lam``
    by ``op`` ("separable", "windowed", or None when the level needs no blur of its own)."""

    res: int
    reseed: bool
    downsamples: int
    op: str | None
    lam: float


@lru_cache(maxsize=8)
def _schedule(
    base_res: int, phases: int
) -> tuple[tuple[_Step, ...], tuple[tuple[float, int], ...]]:
    """The chain's recipe, which depends only on the settings: a :class:`_Step` for each
    cascade level (the first levels) and the sharpness and resolution of each level made from
    spherical harmonics (the rest)."""
    res_of = _resolutions(base_res, phases)
    lams = _lambdas(base_res, phases).tolist()
    # Widths are tracked as vMF mean cosines, which multiply under convolution (exactly for the
    # first SH band; for narrow lobes this is adding variances 1/lam). The base's texels and
    # each 2 x 2 downsample are box filters of variance h^2/12 and h^2/16 (h = 2/R, the texel
    # size at a face centre).
    steps: list[_Step] = []
    cur_res = base_res
    cur_mc = _mean_cosine(12 * (base_res / 2) ** 2)
    for k, res in enumerate(res_of):
        if res <= SH_MAX_RES:
            break
        # Re-seed the exact part of the cascade from the map itself, so the separable passes'
        # residual error (largest near bright texels) does not flow into it.
        reseed = cur_res >= SEPARABLE_MIN_RES > res
        if reseed:
            cur_res, cur_mc = res, _mean_cosine(12 * (res / 2) ** 2)
        downsamples = 0
        while cur_res > res:
            cur_res //= 2
            downsamples += 1
            cur_mc *= _mean_cosine(16 * (cur_res / 2) ** 2)
        target = _mean_cosine(lams[k])
        op, lam_inc = None, 0.0
        if target < cur_mc:
            op = "separable" if res >= SEPARABLE_MIN_RES else "windowed"
            lam_inc = _inverse_langevin(target / cur_mc)
            cur_mc = target
        steps.append(_Step(res, reseed, downsamples, op, lam_inc))
    wide = tuple((lams[k], res_of[k]) for k in range(len(steps), len(res_of)))
    return tuple(steps), wide


def _build(
    base: torch.Tensor, base_res: int, phases: int
) -> tuple[list[torch.Tensor], list[torch.Tensor]]:
    """The levels of the chain of a finite ``(6, base_res, base_res, 3)`` float32 cube map and
    the same levels padded by one seamless texel (:func:`lobelight.geometry.cubemap.pad_seamless`),
    on the cube's device.

    Reads no values back to the host and makes no tensor from host data once the plans of
    :mod:`._convolve` are in memory (after one build at these settings on this device), so a
    CUDA graph can capture it (:class:`lobelight.envmap.ChainBuilder`).
    """
    steps, wide = _schedule(base_res, phases)
    # the map itself at each resolution it is needed at, each downsample done once
    pyramid = {base_res: base}

    def source(res: int) -> torch.Tensor:
        r = min(pyramid)
        while r > res:
            pyramid[r // 2] = _downsample(pyramid[r])
            r //= 2
        return pyramid[res]

    levels: list[torch.Tensor] = []
    cur = base
    # Fine levels: a cascade of narrow increments, each level the previous one convolved with
    # the narrow vMF that takes its width to the next, after a downsample when the mip changes.
    for st in steps:
        if st.reseed:
            cur = source(st.res)
        for _ in range(st.downsamples):
            cur = _downsample(cur)
        if st.op == "separable":
            cur = _convolve.anisotropic_increment(cur, st.lam)
        elif st.op == "windowed":
            cur = _convolve.windowed_increment(cur, st.lam)
        levels.append(cur)
    # Wide levels: exact band factors on a 64^2 copy of the map (no cascade error).
    if wide:
        src = source(min(base_res, 64))
        levels += _convolve.sh_levels(src, [lam for lam, _ in wide], [res for _, res in wide])
    # Reconstruction prefilter for the bilinear lookup.
    return _per_resolution(levels, sharpen=True)


def _per_resolution(
    levels: list[torch.Tensor], *, sharpen: bool
) -> tuple[list[torch.Tensor], list[torch.Tensor]]:
    """Levels sharpened (``sharpen``, at ``R >= SHARPEN_MIN_RES``; else the levels given) and
    padded by one seamless texel, as two lists of ``(6, R, R, 3)`` and ``(6, R + 2, R + 2, 3)``
    tensors.

    Both steps act on each channel alone, so where :func:`_stack_levels` says so the levels of
    one resolution are stacked along the channels and go through them together: one set of
    kernels per resolution, not per level.
    """
    out: list[torch.Tensor] = []
    padded: list[torch.Tensor] = []
    stack = bool(levels) and _stack_levels(levels[0].device)
    start = 0
    while start < len(levels):
        res = levels[start].shape[1]
        stop = start + 1
        while stack and stop < len(levels) and levels[stop].shape[1] == res:
            stop += 1
        group = levels[start:stop]
        x = torch.cat(group, -1) if len(group) > 1 else group[0]  # (6, R, R, 3 L)
        if sharpen and res >= SHARPEN_MIN_RES:
            x = _convolve.sharpen(x)
        p = cubemap.pad_seamless(x)
        out += _unstack(x, len(group)) if sharpen else group
        padded += _unstack(p, len(group))
        start = stop
    return out, padded


def _stack_levels(device: torch.device) -> bool:
    """Whether :func:`_per_resolution` stacks the levels of a resolution: on a GPU, where a
    kernel launch costs more than the three copies stacking takes; not on the CPU, where the
    copies cost more than the operators they save."""
    return device.type != "cpu"


def _unstack(x: torch.Tensor, count: int) -> list[torch.Tensor]:
    """``count`` levels stacked along the channels, ``(6, n, n, 3 count)``, as contiguous
    ``(6, n, n, 3)`` tensors (views of one ``(count, 6, n, n, 3)`` array)."""
    n = x.shape[1]
    return list(x.reshape(6, n, n, count, 3).permute(3, 0, 1, 2, 4).contiguous().unbind(0))
