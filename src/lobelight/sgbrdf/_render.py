"""Shading with fitted SG-BRDFs under distant lighting (the EM paper's sec. V, in torch).

Per shading point (normal ``n``, optional tangent ``t``, direction to the viewer ``o``, world
frame): ``o`` in the tangent frame picks the lobes (:meth:`SGBRDF.lobes`, interpolated between
the fixed views), their means go to the world frame, and each lobe is integrated against the
lighting in one lookup::

    L_o = sum_k w_k int G(w; mu_k, kappa_k) L(w) dw

Two lookups (duck-typed: anything with ``integrate(mu, lam) -> (..., 3)`` works)
    :class:`lobelight.envmap.Prefiltered` (the default): the exact Gaussian-prefiltered chain,
    ``Z(kappa)`` times the lighting convolved with the lobe's own vMF.

    :class:`MipChain`: the paper's eq. (10), a box-filtered mip chain of the environment (what
    GPUs build in hardware) read at the level whose texel matches the lobe's solid angle
    ``Omega_s = -2 pi ln(1 - a) / kappa`` (the cap holding a fraction ``a`` of the lobe):
    ``level = 1/2 log2(Omega_s / Omega_p)``, ``Omega_p`` the solid angle of a base texel at the
    lookup direction (the paper's distortion factor ``d(i)``, here for a cube map), trilinear
    between levels. A box of texels is not a Gaussian, so this is an approximation even at
    the best ``a``; ``tests/test_sgbrdf.py`` measures both against quadrature.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import torch

from .._backend import as_tensor
from .._checks import check_directions
from .._tol import DIVISOR_F32, SHARPNESS_MIN
from ..errors import InputError
from ..geometry import cubemap
from ..geometry.sphere import frame
from ..lobes import sg
from ._fit import SGBRDF

__all__ = ["COVERAGE", "MipChain", "mip_chain", "render_sphere", "shade", "sphere_hits"]

#: Default coverage ``a`` of eq. (10): the most accurate of 0.3 ... 0.9 against
#: quadrature on the built-in sky (tests/test_sgbrdf.py::test_lookups_against_quadrature).
COVERAGE = 0.5


@dataclass
class MipChain:
    """A box-filtered cube-map mip chain read by the paper's eq. (10) (module docstring).

    Attributes
    ----------
    levels : list of (6, R >> k, R >> k, 3) float32, solid-angle-weighted 2 x 2 averages
    coverage : the fraction ``a`` of a lobe's mass whose cap sets the level
    """

    levels: list[torch.Tensor]
    coverage: float = COVERAGE
    _padded: list[torch.Tensor] = field(default_factory=list, repr=False)

    def __post_init__(self) -> None:
        if not 0 < self.coverage < 1:
            raise InputError("coverage", f"must be in (0, 1), got {self.coverage}")
        if not self._padded:
            self._padded = [cubemap.pad_seamless(lv) for lv in self.levels]

    @property
    def device(self) -> torch.device:
        return self.levels[0].device

    def texel_solid_angle(self, dirs: Any) -> torch.Tensor:
        """Solid angle of a base-level texel at ``dirs (..., 3)``: ``(...)`` float64 (the paper's
        ``Omega_p = d(i) / (w h)`` for a cube map, ``(2 / R)^2 / (1 + u^2 + v^2)^(3/2)``)."""
        _, u, v = cubemap.direction_to_face_uv(as_tensor(dirs, device=self.device))
        res = self.levels[0].shape[1]
        return (2.0 / res) ** 2 / (1 + u.double() ** 2 + v.double() ** 2) ** 1.5

    def level(self, mu: Any, lam: Any) -> torch.Tensor:
        """Fractional mip level of eq. (10), clamped to the chain: ``(...)`` float64."""
        mu = as_tensor(mu, device=self.device)
        lam = as_tensor(lam, device=self.device).to(torch.float64)
        omega_s = -2 * math.pi * math.log(1 - self.coverage) / lam.clamp_min(SHARPNESS_MIN)
        lvl = 0.5 * torch.log2(omega_s / self.texel_solid_angle(mu))
        return lvl.clamp(0, len(self.levels) - 1)

    def lookup(self, mu: Any, lam: Any) -> torch.Tensor:
        """Trilinear lookup at the eq. (10) level: ``mu (..., 3)``, ``lam (...)`` -> (..., 3)."""
        mu = as_tensor(mu, device=self.device)
        lam = as_tensor(lam, device=self.device)
        shape = torch.broadcast_shapes(mu.shape[:-1], lam.shape)
        mu = mu.expand(*shape, 3).reshape(-1, 3)
        lvl = self.level(mu, lam.expand(shape).reshape(-1))  # (Q,)
        return self.lookup_level(mu, lvl).reshape(*shape, 3)

    def lookup_level(self, dirs: Any, level: Any) -> torch.Tensor:
        """Trilinear lookup at given fractional levels (what ``textureLod`` does on a GPU).

        Parameters
        ----------
        dirs : (..., 3) directions;  level : (...) fractional mip levels (clamped to the chain)

        Returns
        -------
        (..., 3) float32
        """
        dirs = as_tensor(dirs, device=self.device)
        level = as_tensor(level, device=self.device)
        shape = torch.broadcast_shapes(dirs.shape[:-1], level.shape)
        mu = dirs.expand(*shape, 3).reshape(-1, 3)  # (Q, 3)
        lvl = level.expand(shape).reshape(-1).to(torch.float64).clamp(0, len(self.levels) - 1)
        k0 = lvl.floor().long().clamp(max=len(self.levels) - 1)
        t = (lvl - k0).to(self.levels[0].dtype).unsqueeze(-1)
        out = torch.zeros(mu.shape[0], 3, device=self.device, dtype=self.levels[0].dtype)
        for k in range(len(self.levels)):  # a loop over levels, each gathers its lobes
            for sel, wgt in ((k0 == k, 1 - t), (k0 + 1 == k, t)):
                idx = sel.nonzero().squeeze(-1)
                if idx.numel():
                    val = cubemap.sample(self.levels[k], mu[idx], padded=self._padded[k])
                    out.index_add_(0, idx, wgt[idx] * val)
        return out.reshape(*shape, 3)

    def integrate(self, mu: Any, lam: Any) -> torch.Tensor:
        """``int G(w; mu, lam) L(w) dw ~ Z(lam) * lookup``, ``(..., 3)``."""
        lam = as_tensor(lam, device=self.device)
        z = sg.integral(lam.to(torch.float64)).to(self.levels[0].dtype)
        return self.lookup(mu, lam) * z.unsqueeze(-1)


def normals_and_views(normals: Any, views: Any, device) -> tuple[torch.Tensor, torch.Tensor]:
    """Shading normals and view directions as float32 ``(..., 3)`` tensors on ``device``,
    checked and broadcast against each other."""
    n = as_tensor(normals, device=device).to(torch.float32)
    o = as_tensor(views, device=device).to(torch.float32)
    check_directions(n, "normals")
    check_directions(o, "views")
    n, o = torch.broadcast_tensors(n, o)
    return n, o


def mip_chain(env: Any, /, *, base_res: int = 256, coverage: float = COVERAGE) -> MipChain:
    """Build the box-filtered mip chain of an environment for :class:`MipChain` lookups.

    Parameters
    ----------
    env : :class:`lobelight.envmap.EnvMap`, or a ``(6, R, R, 3)`` cube map
    base_res : face resolution of level 0 (a power of two; an EnvMap is resampled to it)
    coverage : ``a`` of eq. (10), in (0, 1)

    Returns
    -------
    MipChain with ``log2(base_res) + 1`` levels down to 1 x 1 faces
    """
    if base_res < 1 or base_res & (base_res - 1):
        raise InputError("base_res", f"must be a power of two, got {base_res}")
    if hasattr(env, "to_cubemap"):
        cube = env.to_cubemap(base_res)
    else:
        cube = as_tensor(env, dtype=torch.float32)
        if cube.ndim != 4 or cube.shape[0] != 6 or cube.shape[1] != cube.shape[2]:
            raise InputError(
                "env", f"must be an EnvMap or a (6, R, R, 3) cube map, got {tuple(cube.shape)}"
            )
        while cube.shape[1] > base_res:
            cube = cubemap.downsample(cube)
    levels = [cube.to(torch.float32)]
    while levels[-1].shape[1] > 1:
        levels.append(cubemap.downsample(levels[-1]))
    return MipChain(levels=levels, coverage=coverage)


# --------------------------------------------------------------------------------------------
# shading


def _vec(x: Any, name: str, like: torch.Tensor | None = None) -> torch.Tensor:
    t = as_tensor(x, device=None if like is None else like.device)
    if not t.is_floating_point():
        t = t.to(torch.float32)
    if like is not None:
        t = t.to(like.dtype)
    check_directions(t, name)
    return t


def shade(
    model: SGBRDF, lighting: Any, normals: Any, views: Any, /, *, tangents: Any = None
) -> torch.Tensor:
    """Outgoing radiance of surface points with a fitted material under distant lighting.

    Parameters
    ----------
    model : the fitted material (:func:`lobelight.sgbrdf.fit`)
    lighting : :class:`lobelight.envmap.Prefiltered` (exact Gaussian lookups) or
        :class:`MipChain` (eq. 10), or anything with ``integrate(mu, lam) -> (..., 3)``
    normals : (..., 3) unit shading normals, world frame
    views : (..., 3) unit directions towards the viewer, world frame
    tangents : optional (..., 3) tangents (the material's ``x`` axis; orthonormalised against the
        normal), default the tangent of :func:`lobelight.geometry.sphere.frame` (as
        :mod:`lobelight.brdf`)

    Returns
    -------
    (..., 3) radiance, 0 where the viewer is below the surface; on the lighting's device
    """
    if not isinstance(model, SGBRDF):
        raise InputError("model", f"must be an SGBRDF (from fit), got {type(model).__name__}")
    if not hasattr(lighting, "integrate"):
        raise InputError("lighting", "must be a Prefiltered chain or a MipChain")
    dev = getattr(lighting, "device", model.params.device)
    n = _vec(normals, "normals")
    n = n.to(device=dev, dtype=torch.float32)
    o = _vec(views, "views", n)
    n, o = torch.broadcast_tensors(n, o)
    if tangents is None:
        t, b, _ = frame(n)
    else:
        t0 = _vec(tangents, "tangents", n).expand_as(n)
        t = t0 - (t0 * n).sum(-1, keepdim=True) * n
        norm = torch.linalg.vector_norm(t, dim=-1, keepdim=True)
        t = torch.where(norm > 1e-6, t / norm.clamp_min(DIVISOR_F32), frame(n)[0])
        b = torch.cross(n, t, dim=-1)
    o_local = torch.stack([(o * t).sum(-1), (o * b).sum(-1), (o * n).sum(-1)], -1)
    mdl = model.to(dev) if model.params.device != dev else model
    mu, kappa, weight = mdl.lobes(o_local)  # (..., N, 3), (..., N), (..., N, 3)
    tt, bb, nn = (v.unsqueeze(-2) for v in (t, b, n))
    mu_w = mu[..., :1] * tt + mu[..., 1:2] * bb + mu[..., 2:] * nn  # (..., N, 3) world
    light = lighting.integrate(mu_w, kappa)  # (..., N, 3)
    return (weight * light.to(weight.dtype)).sum(-2)


# --------------------------------------------------------------------------------------------
# a sphere image


def sphere_hits(
    width: int, height: int | None = None, /, *, camera: Any = None, device: Any = None
) -> dict[str, torch.Tensor]:
    """Primary-ray hits on the unit sphere at the origin.

    Orthographic by default: the sphere fills the image, seen from +Z (image right = +X, up =
    +Y, every ray along -Z). With a :class:`lobelight.geometry.camera.Camera` the rays are its
    perspective rays and the sphere is intersected analytically.

    Returns
    -------
    dict with ``mask (H, W)`` bool, and, valid where ``mask``: ``normals (H, W, 3)``,
    ``views (H, W, 3)`` (towards the viewer), ``tangents (H, W, 3)`` (the direction of
    increasing azimuth about +Y, ``(n_z, 0, -n_x)`` normalised; the frame tangent at the
    poles), ``rays (H, W, 3)`` (ray directions, for a background)
    """
    h = width if height is None else height
    if width < 1 or h < 1:
        raise InputError("resolution", f"must be positive, got {width}x{h}")
    f32 = torch.float32
    if camera is None:
        x = (torch.arange(width, device=device, dtype=f32) + 0.5) * (2 / width) - 1
        y = 1 - (torch.arange(h, device=device, dtype=f32) + 0.5) * (2 / h)
        yy, xx = torch.meshgrid(y, x, indexing="ij")  # (H, W)
        r2 = xx * xx + yy * yy
        mask = r2 < 1
        n = torch.stack([xx, yy, torch.sqrt((1 - r2).clamp_min(0))], -1)
        rays = torch.zeros(h, width, 3, device=device, dtype=f32)
        rays[..., 2] = -1
    else:
        org, rays = camera.rays(width, h, device=device, dtype=torch.float64)  # (H, W, 3)
        bq = (org * rays).sum(-1)
        disc = bq * bq - ((org * org).sum(-1) - 1)
        mask = disc > 0
        tq = -bq - torch.sqrt(disc.clamp_min(0))
        mask = mask & (tq > 0)
        n = torch.nn.functional.normalize(org + tq.unsqueeze(-1) * rays, dim=-1).to(f32)
        rays = rays.to(f32)
    n = torch.where(mask.unsqueeze(-1), n, torch.tensor([0.0, 0.0, 1.0], device=n.device))
    tan = torch.stack([n[..., 2], torch.zeros_like(n[..., 0]), -n[..., 0]], -1)
    tn = torch.linalg.vector_norm(tan, dim=-1, keepdim=True)
    tan = torch.where(tn > 1e-6, tan / tn.clamp_min(DIVISOR_F32), frame(n)[0])
    return {"mask": mask, "normals": n, "views": -rays, "tangents": tan, "rays": rays}


def render_sphere(
    model: SGBRDF,
    lighting: Any,
    /,
    *,
    width: int = 64,
    height: int | None = None,
    camera: Any = None,
    background: Any = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Render the unit sphere made of ``model`` under ``lighting`` (see :func:`shade`).

    Parameters
    ----------
    model : fitted material;  lighting : Prefiltered or MipChain
    width, height : image size (height defaults to width)
    camera : optional :class:`lobelight.geometry.camera.Camera`; default orthographic from +Z
        (:func:`sphere_hits`)
    background : optional :class:`lobelight.envmap.EnvMap` seen behind the sphere (else 0)

    Returns
    -------
    image : (H, W, 3) float32 linear radiance;  mask : (H, W) bool, pixels on the sphere
    """
    dev = getattr(lighting, "device", None)
    hits = sphere_hits(width, height, camera=camera, device=dev)
    mask = hits["mask"]
    img = torch.zeros(*mask.shape, 3, device=mask.device)
    if bool(mask.any()):
        img[mask] = shade(
            model,
            lighting,
            hits["normals"][mask],
            hits["views"][mask],
            tangents=hits["tangents"][mask],
        )
    if background is not None and bool((~mask).any()):
        img[~mask] = background.radiance(hits["rays"][~mask]).to(img.device)
    return img, mask
