"""Environment maps: distant lighting, the radiance arriving from each direction.

Conventions (``docs/conventions.md``): directions are ``(..., 3)`` in the world frame,
right-handed, +Y up; radiance is linear RGB float32. An :class:`EnvMap` holds one of two layouts.

``"latlong"`` — an ``(H, W, 3)`` image read exactly as Mitsuba 3's ``envmap`` emitter reads it
(``src/emitters/envmap.cpp``, identity ``to_world``), so that a reference render of the same file
agrees. For a unit direction ``d``::

    u = atan2(d.x, -d.z) / (2 pi)          # 0 looks along -Z, 1/4 along +X, 1/2 along +Z
    v = acos(d.y) / pi                     # 0 is the zenith (+Y), 1 the nadir (-Y)
    u = u - 1 / (2 W);  u = u - floor(u)   # columns are cell-centred: column j at u = (j + 1/2)/W
    x = u * W;  y = v * (H - 1)            # rows are *corner*-aligned: row i at theta = i pi/(H-1)
    bilinear in (x, y) between columns floor(x), floor(x) + 1 (column W wraps to column 0)
    and rows floor(y), floor(y) + 1, with floor clamped to W - 1 and H - 2.

So row 0 is the zenith itself and row ``H - 1`` the nadir itself (not half a pixel away), and
columns wrap around. ``tests/test_envmap.py::test_latlong_matches_mitsuba`` checks this against
Mitsuba 3.9 ``scalar_rgb`` renders with a ``radiancemeter``: Mitsuba applies no scale and, in RGB
variants, no colour conversion to an RGB image. A direction exactly at a pole has no azimuth;
Mitsuba then reads whichever column its ``atan2`` of two rounding-level numbers gives, and so do we.

``"cubemap"`` — a ``(6, R, R, 3)`` cube map in the layout of :mod:`lobelight.geometry.cubemap`
(OpenGL faces and texel orientation), looked up with its bilinear, seamless
:func:`~lobelight.geometry.cubemap.sample`.

Power. :meth:`EnvMap.power` is the exact integral of the map's own interpolant for lat-long maps
(pixel ``(i, j)`` weighted by ``2 pi / W`` times the integral over ``theta`` of its bilinear hat
times ``sin(theta)``) and ``sum L * exact texel solid angle`` for cube maps.

Resampling. :meth:`~EnvMap.to_cubemap`, :meth:`~EnvMap.to_latlong` and :meth:`~EnvMap.rotate` set
every target texel to the solid-angle-weighted *average* of the source over the texel. The cell
of lat-long pixel ``(i, j)`` is ``theta in [i - 1/2, i + 1/2] pi/(H-1)`` (clipped to
``[0, pi]``) by ``phi in [j, j + 1] 2 pi/W``, the region around its sample point. The source is
split as ``min(L, c) + spikes``, ``c`` the level exceeded by only the brightest 0.2 % of texels:

- the bounded part is averaged with a stratified grid of ``s_a x s_b`` sub-samples per target
  texel (lat-long: equally spaced in ``cos(theta)`` and ``phi``, so of equal solid angle; cube:
  equally spaced in face coordinates, weighted by solid angle). By default the grid is chosen
  per texel and per axis so that sub-samples are at most half a *source* pixel apart along that
  axis, measured where the texel looks (lat-long pixels are ``sin(theta)`` times narrower in
  azimuth near the poles, cube texels up to 3 times smaller near face corners);
- the spikes (a sun, a lamp) are *splatted*: each spike texel's exact share of :meth:`power`
  is spread over its footprint (its bilinear hat) by many low-discrepancy points and added to
  the target texels they land in, so it is kept to float rounding however small the sun and
  however coarse the target, where point sampling would lose O((sample spacing / pixel)^2) of
  it. Locally a splatted texel is off by the counting error of its points (``_SPLAT_PER_CELL``
  points across the smallest target cell).

So a round trip lat-long -> cube map -> lat-long keeps the power of the spikes to float
rounding and that of the bounded part to its sub-sampling error.

A resampled cube map can be kept on disk (:meth:`EnvMap.to_cubemap`'s ``cache``), beside the
prefiltered chains (:mod:`._chain_cache`), keyed by a hash of the map's values and of the
resampling's settings (:data:`RESAMPLE_VERSION` and the constants below): a renderer that
starts again with the same map reads its background and SH projection's cubes back.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .._backend import as_tensor
from .._checks import check_int
from .._tol import SMALL
from ..errors import InputError
from ..geometry import cubemap
from . import _chain_cache
from ._files import save

__all__ = ["LAYOUTS", "RESAMPLE_VERSION", "EnvMap", "describe_bad_values"]

logger = logging.getLogger(__name__)

LAYOUTS = ("latlong", "cubemap")

# Sub-samples per source pixel (along each axis) of the automatic supersampling of the bounded
# part of the source. A point-sampled average of a piecewise-bilinear interpolant errs where its
# kinks fall between samples, by O((spacing / pixel)^2) of the local power: negligible once the
# spikes are splatted, and 4 would cost four times the sub-samples.
_SAMPLES_PER_SOURCE_PIXEL = 2.0
# Per-axis factors are rounded up to this ladder (fewer distinct groups to process) and capped:
# the last entry bounds the work for a texel that covers a lat-long pole, where pixels vanish.
_LADDER = torch.tensor([1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64])
# Texels brighter than all but this fraction of the map (at least 1) are "spikes", splatted
# with exact power (see _resample): a sun is a few pixels, and splatting 1000 texels is cheap.
_SPIKE_FRACTION = 0.002
_MAX_SPIKES = 256  # and at most this many, so that each can be splatted finely
_SPLAT_BUDGET = 1 << 21  # samples for all spikes together (sets the splat grid's size)
# Splat grid: samples per axis across the smallest target cell (at least 4 over a spike's
# footprint, at most what _SPLAT_BUDGET allows). A target cell's share of a spike is counted in
# samples, so this sets how far a splatted value can be off locally (power is exact regardless).
_SPLAT_PER_CELL = 16.0
# Number of direction samples processed at once: bounds temporary memory to ~100 MB.
_CHUNK = 1 << 20
# Tolerance on R^T R = I and det R = 1 for rotate().
_ROTATION_TOL = 1e-4
#: Version of what the resampling computes, part of a cached cube map's key: bumped whenever a
#: change to the algorithm changes its values (the constants above are in the key by value).
RESAMPLE_VERSION = 1

Lookup = Callable[[torch.Tensor], torch.Tensor]


def describe_bad_values(data: torch.Tensor, *, where: str = "pixel") -> str | None:
    """Say which texels of radiance data are not finite or negative, or None when all are fine.

    Parameters
    ----------
    data : (..., 3) radiance; the leading axes index the texel (``(H, W)`` or ``(6, R, R)``)
    where : word for a texel in the message

    Returns
    -------
    A message such as ``"2 pixels with NaN or Inf radiance (at [3, 7], [3, 8]) ..."`` or None.
    """
    bad_nf = (~torch.isfinite(data)).any(-1)  # (...) texels with NaN/Inf in some channel
    bad_neg = (data < 0).any(-1)  # NaN compares False, so these are real negatives
    parts = []
    for mask, what in ((bad_nf, "NaN or Inf"), (bad_neg, "negative")):
        n = int(mask.sum())
        if n:
            first = torch.nonzero(mask)[:3].tolist()
            at = ", ".join(str(p) for p in first) + (", ..." if n > 3 else "")
            parts.append(f"{n} {where}{'s' if n > 1 else ''} with {what} radiance (at {at})")
    if not parts:
        return None
    return "; ".join(parts) + f", of {tuple(data.shape[:-1])}"


class EnvMap:
    """Distant lighting: radiance arriving from each direction.

    Parameters
    ----------
    data : (H, W, 3) lat-long image or (6, R, R, 3) cube map, float (torch or numpy); stored as
        float32 on its device (no copy when it already is a float32 tensor).
    layout : ``"latlong"`` or ``"cubemap"`` (see the module docstring for both conventions)
    name : what to call this map in messages (the loader passes the file path)

    Raises
    ------
    InputError
        Naming ``name``: an unknown layout, a non-float dtype, a wrong shape (a lat-long map
        needs ``H >= 3`` and ``W >= 2``, as Mitsuba does), or radiance that is NaN, infinite or
        negative — the message gives how many texels and the indices of the first three.

    Attributes
    ----------
    data : torch.Tensor, float32, (H, W, 3) or (6, R, R, 3); treat as read-only
    layout : str
    name : str
    device : torch.device
    """

    def __init__(self, data: Any, *, layout: str, name: str = "envmap"):
        if layout not in LAYOUTS:
            raise InputError(name, f"layout must be one of {LAYOUTS}, got {layout!r}")
        dtype = getattr(data, "dtype", None)
        if isinstance(data, np.ndarray) and not np.issubdtype(data.dtype, np.floating):
            raise InputError(name, f"radiance must be a float array, got dtype {dtype}")
        t = as_tensor(data)
        if not t.is_floating_point():
            raise InputError(name, f"radiance must be a float array, got dtype {t.dtype}")
        shape = tuple(t.shape)
        if layout == "latlong":
            if t.ndim != 3 or shape[-1] != 3 or shape[0] < 3 or shape[1] < 2:
                raise InputError(
                    name, f"a lat-long map must be (H, W, 3) with H >= 3, W >= 2; got {shape}"
                )
        elif t.ndim != 4 or shape[0] != 6 or shape[1] != shape[2] or shape[3] != 3 or not shape[1]:
            raise InputError(name, f"a cube map must be (6, R, R, 3), got {shape}")
        t = t.to(torch.float32)
        problem = describe_bad_values(t, where="pixel" if layout == "latlong" else "texel")
        if problem:
            raise InputError(name, problem)
        self.data = t
        self.layout = layout
        self.name = name

    @classmethod
    def _trusted(cls, data: torch.Tensor, layout: str, name: str) -> EnvMap:
        # Results of our own resampling are valid by construction: skip the checks.
        env = cls.__new__(cls)
        env.data, env.layout, env.name = data, layout, name
        return env

    # -- basics ------------------------------------------------------------------------------

    @property
    def device(self) -> torch.device:
        return self.data.device

    @property
    def resolution(self) -> tuple[int, int]:
        """``(H, W)`` of a lat-long map, ``(R, R)`` of a cube map's faces."""
        return (int(self.data.shape[-3]), int(self.data.shape[-2]))

    def to(self, device: Any) -> EnvMap:
        """The same map with its data on ``device``."""
        return EnvMap._trusted(self.data.to(device), self.layout, self.name)

    def __repr__(self) -> str:
        return (
            f"EnvMap(name={self.name!r}, layout={self.layout!r}, "
            f"shape={tuple(self.data.shape)}, device={self.device})"
        )

    # -- lookups -----------------------------------------------------------------------------

    def _source(self) -> _Source:
        # The prepared lookup (the padded image or cube) is cached; the key changes when `data`
        # is replaced or modified in place (torch counts in-place writes in `_version`).
        key = (self.data.data_ptr(), self.data._version, self.data.shape, self.data.device)
        cached = getattr(self, "_cache", None)
        if cached is None or cached[0] != key:
            cached = (key, _Source(self.data, self.layout))
            self._cache = cached
        return cached[1]

    def radiance(self, dirs: Any) -> Any:
        """Radiance arriving from directions (the map's own interpolation, see module docstring).

        Parameters
        ----------
        dirs : (..., 3) directions, torch or numpy, need not be unit length

        Returns
        -------
        (..., 3) float32 on the map's device; a numpy array when ``dirs`` is one.
        """
        was_numpy = isinstance(dirs, np.ndarray)
        d = as_tensor(dirs, dtype=torch.float32, device=self.device)
        if d.shape[-1:] != (3,):
            raise InputError("dirs", f"directions must be (..., 3), got {tuple(d.shape)}")
        lookup = self._source()
        flat = d.reshape(-1, 3)  # (N, 3)
        parts = [lookup(flat[k : k + _CHUNK]) for k in range(0, flat.shape[0], _CHUNK)]
        out = torch.cat(parts) if parts else flat.new_zeros(0, 3)
        out = out.reshape(*d.shape[:-1], 3)
        return out.cpu().numpy() if was_numpy else out

    # -- integrals ---------------------------------------------------------------------------

    def power(self) -> torch.Tensor:
        """Integral of the radiance over the sphere, ``(3,)`` float32 (radiance x steradian).

        Lat-long: the exact integral of the interpolant of the module docstring; cube map:
        ``sum L * exact texel solid angle``. Summed in float64.
        """
        if self.layout == "cubemap":
            omega = cubemap.texel_solid_angles(
                self.data.shape[1], device=self.device, dtype=torch.float64
            )
            tot = (self.data.double() * omega.unsqueeze(-1)).sum((0, 1, 2))
        else:
            h, w = self.resolution
            wrow = _latlong_row_weights(h, device=self.device)  # (H,), sums to 2
            tot = (self.data.double().sum(1) * wrow.unsqueeze(-1)).sum(0) * (2 * math.pi / w)
        return tot.float()

    # -- resampling --------------------------------------------------------------------------

    def to_cubemap(
        self, res: int, *, supersample: int | None = None, cache: bool | str | os.PathLike = False
    ) -> torch.Tensor:
        """Resample to a cube map, each texel the solid-angle-weighted average over the texel.

        Parameters
        ----------
        res : face resolution R
        supersample : sub-samples per texel along each axis (``s x s`` in all) for every texel;
            by default chosen per texel (module docstring).
        cache : keep the resampled cube on disk (module docstring): False (the default) never
            reads or writes one, True keeps it beside the prefiltered chains
            (``lobelight._cache.cache_dir() / "prefilter"``), a folder keeps it there. An entry
            that is damaged or is not this map's is computed again and rewritten.

        Returns
        -------
        (6, R, R, 3) float32 on the map's device. A cube map of the same resolution is returned
        as it is; one whose resolution is a multiple of R is averaged exactly over whole texels.
        """
        res = check_int(res, "res")
        if self.layout == "cubemap":
            src = self.data.shape[1]
            if src == res:
                return self.data
            if supersample is None and src % res == 0:
                return _cube_block_average(self.data, src // res)
        folder = _chain_cache.cache_folder(cache)
        if folder is None:
            return self._resample_cube(res, supersample)
        description = _resample_description(self.layout, res, supersample)
        key = _chain_cache.chain_key(self.data, description)
        path = _chain_cache.cube_path(folder, key)
        hit = _chain_cache.read_cube(path, key, res)
        if hit is not None:
            return torch.from_numpy(hit).to(self.device)
        out = self._resample_cube(res, supersample)
        try:
            _chain_cache.write_cube(path, key, description, out)
        except OSError as exc:  # a cache that cannot be written only costs the next run time
            logger.warning("could not write the resampled cube map to %s: %s", path, exc)
        return out

    def _resample_cube(self, res: int, supersample: int | None) -> torch.Tensor:
        """:meth:`to_cubemap` by cell averaging, ``(6, res, res, 3)``."""
        cells = _CubeCells(res, device=self.device)
        out = _resample(self, cells, supersample=_check_s(supersample))
        return out.reshape(6, res, res, 3)

    def to_latlong(self, height: int, *, supersample: int | None = None) -> EnvMap:
        """Resample to a ``(height, 2 height, 3)`` lat-long map, averaging over pixel cells.

        Parameters
        ----------
        height : H (>= 3); the width is 2 H
        supersample : as in :meth:`to_cubemap`

        Returns
        -------
        EnvMap with layout ``"latlong"``; this map itself when it already is that size.
        """
        height = check_int(height, "height", minimum=3)
        if self.layout == "latlong" and self.resolution == (height, 2 * height):
            return self
        cells = _LatlongCells(height, 2 * height, device=self.device)
        out = _resample(self, cells, supersample=_check_s(supersample))
        return EnvMap._trusted(out.reshape(height, 2 * height, 3), "latlong", self.name)

    def rotate(self, rot: Any, *, supersample: int | None = None) -> EnvMap:
        """The lighting rotated by a rotation matrix: ``new.radiance(d) == old.radiance(R^T d)``.

        Resampled into the same layout and resolution by cell averaging (as
        :meth:`to_latlong`), so power is kept; detail at the pixel scale is slightly smoothed
        (each new texel averages the bilinear source over its cell). The identity returns this
        map.

        Parameters
        ----------
        rot : (3, 3) rotation matrix R (orthonormal with det +1, to 1e-4)
        supersample : as in :meth:`to_cubemap`
        """
        r = as_tensor(rot, dtype=torch.float64, device=self.device)
        if tuple(r.shape) != (3, 3) or not bool(torch.isfinite(r).all()):
            raise InputError(
                "R", f"a rotation must be a finite (3, 3) matrix, got {tuple(r.shape)}"
            )
        eye = torch.eye(3, dtype=torch.float64, device=self.device)
        if (r.T @ r - eye).abs().max() > _ROTATION_TOL or torch.linalg.det(r) < 0:
            raise InputError("R", "is not a rotation matrix (R^T R != I or det R != +1)")
        if bool((r == eye).all()):
            return self
        h, w = self.resolution
        if self.layout == "cubemap":
            cells: _Cells = _CubeCells(h, device=self.device)
        else:
            cells = _LatlongCells(h, w, device=self.device)
        out = _resample(self, cells, rot=r, supersample=_check_s(supersample))
        return EnvMap._trusted(out.reshape(self.data.shape), self.layout, self.name)

    # -- files -------------------------------------------------------------------------------

    def save(self, path: str | Path, **options: Any) -> Path:
        """Write to ``path`` (``.exr`` or ``.hdr``); see :func:`lobelight.envmap.save`."""
        return save(self, path, **options)


# -- sources: what resampling reads --------------------------------------------------------------


class _Source:
    """A map prepared for many lookups, optionally seen through a rotation.

    ``src(d)`` is ``env.radiance(R^T d)`` for ``(N, 3)`` float32 directions (any length);
    :meth:`chord` is the source pixel size around a direction, along a tangent.
    """

    def __init__(self, data: torch.Tensor, layout: str, *, rot: torch.Tensor | None = None):
        self.layout = layout
        self.res = (int(data.shape[-3]), int(data.shape[-2]))
        # for row vectors d, (R^T d)^T = d^T R: the source direction a target direction reads
        self.rot = None if rot is None else rot.to(torch.float32)
        if layout == "cubemap":
            self.cube = data
            self.padded = cubemap.pad_seamless(data)
        else:
            # Mitsuba stores the map with an extra column, a copy of column 0, so that the
            # bilinear lookup wraps around; channels first for grid_sample: (1, 3, H, W + 1).
            img = torch.cat([data, data[:, :1]], 1)
            self.image = img.permute(2, 0, 1).unsqueeze(0).contiguous()

    @staticmethod
    def pixel(env: EnvMap) -> float:
        """Largest angular size of a lat-long pixel (radians)."""
        h, w = env.resolution
        return max(math.pi / (h - 1), 2 * math.pi / w)

    def __call__(self, d: torch.Tensor) -> torch.Tensor:
        if self.rot is not None:
            d = d @ self.rot
        if self.layout == "cubemap":
            return cubemap.sample(self.cube, d, padded=self.padded)
        return _latlong_bilinear(self.image, d)

    def chord(self, d: torch.Tensor, t: torch.Tensor, radius: torch.Tensor) -> torch.Tensor:
        """Angular size of the source pixel at ``d`` measured along the tangent ``t``.

        Parameters
        ----------
        d : (n, 3) unit directions, t : (n, 3) unit tangents at d, radius : (n,) angular radius
            of the neighbourhood (the smallest pixel within it counts)

        Returns
        -------
        (n,) radians, > 0
        """
        if self.rot is not None:
            d, t = d @ self.rot, t @ self.rot
        h, w = self.res
        if self.layout == "cubemap":
            # a texel of size 2/R in face coordinates spans 2/R sqrt(1 + v^2) / (1 + u^2 + v^2)
            # radians along the face's u axis and likewise along v: take the smaller (isotropic)
            _, u, v = cubemap.direction_to_face_uv(d)
            q = 1 + u * u + v * v
            return (2.0 / h) * torch.minimum(1 + u * u, 1 + v * v).sqrt() / q
        sin_t = torch.hypot(d[:, 0], d[:, 2])  # (n,)
        to_pole = torch.atan2(sin_t, d[:, 1].abs())  # angle to the nearer pole
        a_theta = math.pi / (h - 1)
        a_phi = (2 * math.pi / w) * torch.sin((to_pole - radius).clamp_min(0))
        # components of t along the azimuth direction e_phi = (-d.z, 0, d.x)/sin(theta)
        c_phi = ((t[:, 2] * -d[:, 0] + t[:, 0] * d[:, 2]).abs() / sin_t.clamp_min(SMALL)).clamp(
            max=1
        )
        c_theta = (1 - c_phi * c_phi).clamp_min(0).sqrt()
        return torch.minimum(
            a_theta / c_theta.clamp_min(SMALL), a_phi.clamp_min(SMALL) / c_phi.clamp_min(SMALL)
        )


def _latlong_bilinear(image: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    """Mitsuba's envmap lookup of ``(N, 3)`` directions in a ``(1, 3, H, W + 1)`` padded image.

    ``grid_sample`` with ``align_corners=True`` puts grid -1 and +1 on the first and last pixel
    centres: ``x = (gx + 1)/2 * W`` and ``y = (gy + 1)/2 * (H - 1)``, which with ``gx = 2u - 1``,
    ``gy = 2v - 1`` is Mitsuba's ``u * W`` and ``v * (H - 1)`` up to float32 rounding (the
    sample position moves by at most ~1e-7 W pixels, as in Mitsuba's own float32 arithmetic).
    Returns ``(N, 3)``.
    """
    w = image.shape[-1] - 1
    d = torch.nn.functional.normalize(d.to(image.dtype), dim=-1)  # (N, 3)
    x, y, z = d.unbind(-1)
    u = torch.atan2(x, -z) * (0.5 / math.pi)
    v = torch.acos(y.clamp(-1.0, 1.0)) * (1.0 / math.pi)
    u = u - 0.5 / w
    u = u - torch.floor(u)
    grid = torch.stack([2 * u - 1, 2 * v - 1], -1).reshape(1, 1, -1, 2)  # (1, 1, N, 2)
    out = torch.nn.functional.grid_sample(
        image, grid, mode="bilinear", padding_mode="border", align_corners=True
    )  # (1, 3, 1, N)
    return out[0, :, 0].T


def _latlong_row_weights(h: int, *, device: Any = None) -> torch.Tensor:
    """``(H,)`` float64: integral over theta of row i's hat function times sin(theta); sum 2."""
    delta = math.pi / (h - 1)
    theta = torch.arange(h, dtype=torch.float64, device=device) * delta
    # interior hat: sin(theta_i) * 2 (1 - cos delta)/delta, with 1 - cos = 2 sin^2(delta/2)
    wrow = torch.sin(theta) * (4 * math.sin(delta / 2) ** 2 / delta)
    # the pole rows' half hats: integral_0^delta (1 - t/delta) sin t dt = 1 - sin(delta)/delta
    wrow[0] = wrow[-1] = 1 - math.sin(delta) / delta
    return wrow


# -- targets: the cells to average over ------------------------------------------------------


class _Cells:
    """Target texels as patches of the sphere, indexed ``0 .. n-1`` in row-major layout order.

    ``frames()`` gives, per cell, the centre direction, unit tangents along its two axes
    (``a`` = rows, ``b`` = columns) and its angular extents along them; ``subsamples`` the
    stratified grid of a subset of cells.
    """

    n: int
    min_angle: float  # smallest angular extent of a cell (away from lat-long poles), radians

    def frames(self) -> tuple[torch.Tensor, ...]:
        raise NotImplementedError

    def locate(self, d: torch.Tensor) -> torch.Tensor:
        """Index of the cell containing each of ``(N, 3)`` unit directions, ``(N,)`` int64."""
        raise NotImplementedError

    def measure(self) -> torch.Tensor:
        """``(n,)`` float64: what a cell's value is multiplied by in :meth:`EnvMap.power`."""
        raise NotImplementedError

    def subsamples(
        self, idx: torch.Tensor, sa: int, sb: int
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        raise NotImplementedError


class _CubeCells(_Cells):
    """The ``6 R^2`` texels of a cube map, in the :mod:`lobelight.geometry.cubemap` layout."""

    def __init__(self, res: int, *, device: Any = None):
        self.res, self.device = res, device
        self.n = 6 * res * res
        self.min_angle = 2.0 / res * math.sqrt(2) / 3  # along the diagonal at a face corner
        # per face: the direction at u = v = 0 and the directions u and v move along, read
        # off cubemap.face_uv_to_direction (linear in u, v) so the layout lives in one place
        face = torch.arange(6, device=device)
        zero, one = torch.zeros(6, device=device), torch.ones(6, device=device)
        self.centre = cubemap.face_uv_to_direction(face, zero, zero)  # (6, 3)
        self.u_axis = cubemap.face_uv_to_direction(face, one, zero) - self.centre
        self.v_axis = cubemap.face_uv_to_direction(face, zero, one) - self.centre
        self.frame = torch.stack([self.u_axis, self.v_axis, self.centre], 1)  # (6, 3, 3)

    def _split(self, idx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        r = self.res
        return idx // (r * r), (idx // r) % r, idx % r  # face, row (v), column (u)

    def frames(self) -> tuple[torch.Tensor, ...]:
        r, h = self.res, 2.0 / self.res
        c = (torch.arange(r, device=self.device) + 0.5) * h - 1  # (R,) texel centres
        v = c.reshape(1, r, 1, 1)  # rows
        u = c.reshape(1, 1, r, 1)  # columns
        cen, ua, va = (x.reshape(6, 1, 1, 3) for x in (self.centre, self.u_axis, self.v_axis))
        norm = (1 + u * u + v * v).sqrt()  # |p| of p = centre + u U + v V (orthonormal axes)
        d = (cen + u * ua + v * va) / norm  # (6, R, R, 3)
        # d(p/|p|)/du = (U - d (d.U)) / |p| with d.U = u/|p|: tangents along rows / columns
        ta = (va - d * (v / norm)) / norm
        tb = (ua - d * (u / norm)) / norm
        ext_a, ext_b = ta.norm(dim=-1, keepdim=True), tb.norm(dim=-1, keepdim=True)
        return (
            d.reshape(-1, 3),
            (ta / ext_a).reshape(-1, 3),
            (tb / ext_b).reshape(-1, 3),
            (ext_a * h).reshape(-1),
            (ext_b * h).reshape(-1),
        )

    def locate(self, d):
        f, u, v = cubemap.direction_to_face_uv(d)
        r = self.res
        j = ((u + 1) * (r / 2)).floor().long().clamp(0, r - 1)
        i = ((v + 1) * (r / 2)).floor().long().clamp(0, r - 1)
        return (f * r + i) * r + j

    def measure(self):
        return cubemap.texel_solid_angles(
            self.res, device=self.device, dtype=torch.float64
        ).reshape(-1)

    def subsamples(self, idx, sa, sb):
        f, i, j = self._split(idx)
        h = 2.0 / self.res
        ka = (torch.arange(sa, device=self.device) + 0.5) / sa  # (sa,) in [0, 1]
        kb = (torch.arange(sb, device=self.device) + 0.5) / sb
        m = idx.numel()
        v = ((i[:, None] + ka) * h - 1)[:, :, None].expand(m, sa, sb)  # (m, sa, sb)
        u = ((j[:, None] + kb) * h - 1)[:, None, :].expand(m, sa, sb)
        # p = u U + v V + centre, as (u, v, 1) times each cell's face matrix: one bmm
        uv1 = torch.stack([u, v, torch.ones_like(u)], -1).reshape(m, sa * sb, 3)
        d = torch.bmm(uv1, self.frame[f]).reshape(m, sa, sb, 3)  # on the face plane
        # solid angle density of the face plane, 1/(1 + u^2 + v^2)^(3/2): the sub-squares'
        # weights (exact to O((h/s)^2) of each, and only their ratios within a texel matter)
        weight = (1 + u * u + v * v) ** -1.5  # (m, sa, sb)
        return d, weight


class _LatlongCells(_Cells):
    """The ``H x W`` pixel cells of a lat-long map (module docstring)."""

    def __init__(self, height: int, width: int, *, device: Any = None):
        self.h, self.w, self.device = height, width, device
        self.n = height * width
        self.delta = math.pi / (height - 1)
        self.min_angle = min(self.delta, 2 * math.pi / width)

    def _theta_range(self, i: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        lo = ((i.double() - 0.5) * self.delta).clamp(0, math.pi)
        hi = ((i.double() + 0.5) * self.delta).clamp(0, math.pi)
        return lo, hi

    def frames(self) -> tuple[torch.Tensor, ...]:
        idx = torch.arange(self.n, device=self.device)
        i, j = idx // self.w, idx % self.w
        lo, hi = self._theta_range(i)
        theta = (lo + hi) / 2
        phi = (j.double() + 0.5) * (2 * math.pi / self.w)
        st, ct, sp, cp = torch.sin(theta), torch.cos(theta), torch.sin(phi), torch.cos(phi)
        d = torch.stack([sp * st, ct, -cp * st], -1)
        ta = torch.stack([sp * ct, -st, -cp * ct], -1)  # d/dtheta, down the rows
        tb = torch.stack([cp, torch.zeros_like(cp), sp], -1)  # d/dphi / sin(theta)
        # the cell's widest azimuthal extent: at the equator if it spans it, else at an edge
        spans = (lo <= math.pi / 2) & (hi >= math.pi / 2)
        sin_max = torch.where(spans, 1.0, torch.maximum(torch.sin(lo), torch.sin(hi)))
        ext_b = sin_max * (2 * math.pi / self.w)
        return tuple(x.float() for x in (d, ta, tb, hi - lo, ext_b))

    def locate(self, d):
        theta = torch.atan2(torch.hypot(d[:, 0], d[:, 2]), d[:, 1])
        i = torch.round(theta / self.delta).long().clamp(0, self.h - 1)
        u = torch.atan2(d[:, 0], -d[:, 2]) * (0.5 / math.pi)
        j = ((u - torch.floor(u)) * self.w).floor().long().clamp(0, self.w - 1)
        return i * self.w + j

    def measure(self):
        wrow = _latlong_row_weights(self.h, device=self.device) * (2 * math.pi / self.w)
        return wrow.repeat_interleave(self.w)

    def subsamples(self, idx, sa, sb):
        i, j = idx // self.w, idx % self.w
        lo, hi = self._theta_range(i)
        ka = (torch.arange(sa, dtype=torch.float64, device=self.device) + 0.5) / sa
        kb = (torch.arange(sb, dtype=torch.float64, device=self.device) + 0.5) / sb
        z_top, z_bot = torch.cos(lo)[:, None], torch.cos(hi)[:, None]
        ct = z_top + (z_bot - z_top) * ka  # (m, sa) equal-area strata in cos(theta)
        st = (1 - ct * ct).clamp_min(0).sqrt()
        phi = (j.double()[:, None] + kb) * (2 * math.pi / self.w)  # (m, sb)
        st, ct = st.float()[:, :, None], ct.float()[:, :, None]  # (m, sa, 1)
        sp, cp = torch.sin(phi).float()[:, None, :], torch.cos(phi).float()[:, None, :]
        # Mitsuba's uv_to_direction: (sin phi sin theta, cos theta, -cos phi sin theta)
        d = torch.stack([st * sp, ct.expand(-1, -1, sb), -st * cp], -1)  # (m, sa, sb, 3)
        return d, None


def _resample(
    env: EnvMap, cells: _Cells, *, rot: torch.Tensor | None = None, supersample: int | None
) -> torch.Tensor:
    """``(cells.n, 3)``: the average of ``env`` (rotated by ``rot``) over every target cell.

    The source is split as ``L = min(L, c) + spikes``, with ``c`` the level exceeded by at most
    ``_SPIKE_FRACTION`` of its texels. The bounded part is averaged over cells with
    :func:`_cell_average`. The spikes (a sun) are *splatted*: each spike texel's share of
    :meth:`EnvMap.power` is spread over its footprint with a fine stratified grid and added to
    the cells the samples fall in, so their power is kept exactly (to float rounding) however
    small they are, instead of to O((sample spacing / pixel)^2) by point sampling.
    """
    smooth, spike_idx, spike_val = _split_spikes(env.data)
    source = _Source(smooth, env.layout, rot=rot)
    out = _cell_average(cells, source, supersample=supersample)
    if spike_idx.numel():
        # footprint of a spike: one cube texel, or a lat-long hat two pixels wide
        foot = 2.0 / env.resolution[0] if env.layout == "cubemap" else 2 * _Source.pixel(env)
        most = max(4, int(math.sqrt(_SPLAT_BUDGET / spike_idx.numel())))
        n = int(min(max(math.ceil(_SPLAT_PER_CELL * foot / cells.min_angle), 4), most))
        power = torch.zeros(cells.n, 3, dtype=torch.float64, device=env.device)
        step = max(1, _CHUNK // (n * n))  # spikes per chunk
        for a in range(0, spike_idx.numel(), step):
            sl = slice(a, a + step)
            power += _splat(env, spike_idx[sl], spike_val[sl], cells, rot=rot, n=n)
        out = out + (power / cells.measure().unsqueeze(-1)).float()
    return out


def _split_spikes(data: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``data = smooth + spikes``: returns smooth data, flat texel indices and excess values."""
    peak = data.amax(-1).reshape(-1)  # (n,) brightest channel per texel
    k = int(min(max(_SPIKE_FRACTION * peak.numel(), 1), peak.numel() - 1, _MAX_SPIKES))
    level = torch.topk(peak, k + 1).values[-1]  # at most k texels are brighter than this
    smooth = data.clamp(max=float(level))
    idx = torch.nonzero(peak > level)[:, 0]
    return smooth, idx, (data.reshape(-1, 3)[idx] - smooth.reshape(-1, 3)[idx])


def _splat(
    env: EnvMap,
    idx: torch.Tensor,
    val: torch.Tensor,
    cells: _Cells,
    *,
    rot: torch.Tensor | None,
    n: int,
) -> torch.Tensor:
    """Power of texels ``idx`` (values ``val``, (m, 3)) of ``env`` deposited into ``cells``.

    A lat-long texel is spread over its bilinear hat (``+-1`` pixel in x and y, weighted by the
    hat and ``sin(theta)``), a cube texel over its square (weighted by solid angle), by ``n^2``
    points of the R2 low-discrepancy sequence; the weights of each texel are normalised to its
    exact share of power. (A regular grid would put whole rows of samples on either side of a
    target texel's edge, off by up to one row in count; the R2 points, which never line up
    with an edge, keep a texel's count close to its area even when texels are small.)
    Returns ``(cells.n, 3)`` float64.
    """
    device = env.device
    g = 1.324717957244746  # the plastic number: R2 sequence (Roberts 2018)
    k = torch.arange(n * n, device=device, dtype=torch.float64)
    pa = torch.remainder(0.5 + k / g, 1.0)  # (N,) in [0, 1): down the rows
    pb = torch.remainder(0.5 + k / (g * g), 1.0)  # across the columns
    if env.layout == "cubemap":
        res = env.resolution[0]
        fc = _CubeCells(res, device=device)
        f, i, j = fc._split(idx)
        h = 2.0 / res
        v = (i.double()[:, None] + pa) * h - 1  # (m, N)
        u = (j.double()[:, None] + pb) * h - 1
        uv1 = torch.stack([u, v, torch.ones_like(u)], -1)  # (m, N, 3)
        d = torch.bmm(uv1, fc.frame[f].double())  # (m, N, 3) on the face plane
        weight = (1 + u * u + v * v) ** -1.5  # solid angle density
        share = fc.measure()[idx]  # (m,) texel solid angle
    else:
        h, w = env.resolution
        i, j = idx // w, idx % w
        y = i.double()[:, None] + (2 * pa - 1)  # (m, N) rows within the hat's +-1 pixel
        x = j.double()[:, None] + (2 * pb - 1)
        theta = y * (math.pi / (h - 1))
        phi = (x + 0.5) * (2 * math.pi / w)  # column j looks along u = (j + 1/2)/W
        hat = (1 - (2 * pa - 1).abs()) * (1 - (2 * pb - 1).abs())  # (N,)
        inside = ((y >= 0) & (y <= h - 1)).double()  # no hat beyond a pole
        st = torch.sin(theta)
        weight = hat * st.abs() * inside  # (m, N)
        d = torch.stack([st * torch.sin(phi), torch.cos(theta), -st * torch.cos(phi)], -1)
        share = (_latlong_row_weights(h, device=device) * (2 * math.pi / w))[i]  # (m,)
    weight = weight / weight.sum(1, keepdim=True) * share[:, None]
    if rot is not None:
        d = d @ rot.T.to(d.dtype)  # the old direction q is seen at R q in the rotated map
    target = cells.locate(torch.nn.functional.normalize(d.reshape(-1, 3), dim=-1).float())
    contrib = (weight.reshape(len(idx), -1, 1) * val.double()[:, None, :]).reshape(-1, 3)
    power = torch.zeros(cells.n, 3, dtype=torch.float64, device=device)
    return power.index_add_(0, target, contrib)


def _cell_average(cells: _Cells, source: _Source, *, supersample: int | None) -> torch.Tensor:
    """Average of ``source`` over every cell, ``(cells.n, 3)`` float32.

    Cells are grouped by their per-axis sub-sample counts ``(s_a, s_b)`` and each group is
    evaluated in chunks of at most ``_CHUNK`` samples.
    """
    n = cells.n
    device = cells.device
    if supersample is not None:
        sa = sb = torch.full((n,), supersample, device=device, dtype=torch.long)
    else:
        d, ta, tb, ext_a, ext_b = cells.frames()
        radius = 0.5 * torch.hypot(ext_a, ext_b)
        ladder = _LADDER.to(device)

        def factor(t: torch.Tensor, ext: torch.Tensor) -> torch.Tensor:
            need = torch.ceil(_SAMPLES_PER_SOURCE_PIXEL * ext / source.chord(d, t, radius) - 1e-6)
            k = torch.searchsorted(ladder, need.clamp(1, int(ladder[-1])).long())
            return ladder[k]

        sa, sb = factor(ta, ext_a), factor(tb, ext_b)
        del d, ta, tb, ext_a, ext_b, radius
    out = torch.empty(n, 3, device=device)
    key = sa * 1024 + sb
    order = torch.argsort(key)  # cells grouped by their (s_a, s_b), each group contiguous
    keys, counts = torch.unique_consecutive(key[order], return_counts=True)
    start = 0
    for k, count in zip(keys.tolist(), counts.tolist(), strict=True):
        a, b = divmod(k, 1024)
        idx = order[start : start + count]
        start += count
        step = max(1, _CHUNK // (a * b))
        for c in range(0, idx.numel(), step):
            part = idx[c : c + step]
            d, weight = cells.subsamples(part, a, b)  # (m, a, b, 3), (m, a, b) or None
            val = source(d.reshape(-1, 3)).reshape(part.numel(), a * b, 3)
            if weight is None:
                out[part] = val.mean(1)
            else:
                wf = weight.reshape(part.numel(), 1, a * b)
                out[part] = torch.bmm(wf, val)[:, 0] / wf.sum(-1)
    return out


def _cube_block_average(cube: torch.Tensor, m: int) -> torch.Tensor:
    """Exact solid-angle-weighted average over ``m x m`` texel blocks: ``(6, R, R, C) -> R/m``."""
    res = cube.shape[1]
    k = res // m
    w = cubemap.texel_solid_angles(res, device=cube.device, dtype=torch.float64)
    w = w.reshape(6, k, m, k, m, 1)
    num = (cube.double().reshape(6, k, m, k, m, -1) * w).sum((2, 4))
    return (num / w.sum((2, 4))).float()


def _check_s(supersample: Any) -> int | None:
    return None if supersample is None else check_int(supersample, "supersample")


def _resample_description(layout: str, res: int, supersample: int | None) -> dict:
    """Everything besides the map's values that a resampled cube depends on (its cache key)."""
    return {
        "kind": "cubemap-resample",
        "resample_version": RESAMPLE_VERSION,
        "layout": layout,
        "res": res,
        "supersample": supersample,
        "constants": {
            "SAMPLES_PER_SOURCE_PIXEL": _SAMPLES_PER_SOURCE_PIXEL,
            "LADDER": _LADDER.tolist(),
            "SPIKE_FRACTION": _SPIKE_FRACTION,
            "MAX_SPIKES": _MAX_SPIKES,
            "SPLAT_BUDGET": _SPLAT_BUDGET,
            "SPLAT_PER_CELL": _SPLAT_PER_CELL,
        },
    }
