"""Lighting for rendering: the prefiltered chain, the SH projection and the map itself.

A lighting rotation ``R`` turns the environment: radiance from ``d`` becomes ``L(R^T d)``.
Nothing is re-prefiltered for it (the paper, section 5): a Gaussian with mean ``mu`` sees the
rotated lighting as the original seen by ``R^T mu``, the SH diffuse term rotates its 25
coefficients, and the background looks up ``R^T d``.
"""

from __future__ import annotations

import math

import torch

from .. import sh
from ..envmap import EnvMap, Prefiltered, prefilter
from ..errors import InputError

__all__ = ["Lighting", "as_rotation"]


def as_rotation(r, *, device=None) -> torch.Tensor:
    """A ``(3, 3)`` float32 rotation from ``None`` (identity), a matrix, or an angle in degrees
    about +y (the vertical of the lat-long maps: a turn of the sky)."""
    if r is None:
        return torch.eye(3, device=device)
    if isinstance(r, (int, float)):
        a = math.radians(float(r))
        c, s = math.cos(a), math.sin(a)
        return torch.tensor([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]], device=device)
    m = torch.as_tensor(r, dtype=torch.float32, device=device)
    if m.shape != (3, 3) or not bool(torch.isfinite(m).all()):
        raise InputError("light_rotation", f"must be a finite 3x3 matrix, got {tuple(m.shape)}")
    if (
        float((m @ m.T - torch.eye(3, device=m.device)).abs().max()) > 1e-4
        or float(torch.det(m)) < 0
    ):
        raise InputError("light_rotation", "must be a rotation (orthogonal, determinant +1)")
    return m


class Lighting:
    """An environment ready to render with.

    Parameters
    ----------
    env : EnvMap
    base_res : face resolution of the sharpest prefiltered level (power of two): lobes up to
        ``lam = (base_res / 5)**2`` are resolved (655 at 128, 10486 at 512)
    sh_order : order of the diffuse SH projection (5 = 25 coefficients, the transfer's order)
    device : torch device

    Attributes
    ----------
    prefiltered : Prefiltered;  sh : (sh_order**2, 3) float32;  env : EnvMap
    """

    def __init__(
        self,
        env: EnvMap,
        *,
        base_res: int = 128,
        sh_order: int = 5,
        device=None,
        prefiltered: Prefiltered | None = None,
    ):
        if not isinstance(env, EnvMap):
            raise InputError("env", f"expected an EnvMap, got {type(env).__name__}")
        self.env = env.to(device) if device is not None else env
        self.device = self.env.device
        self.prefiltered = (
            prefiltered
            if prefiltered is not None
            else prefilter(self.env, base_res=base_res, device=self.device)
        )
        self.sh = sh.project_envmap(self.env, sh_order, res=64).to(torch.float32)
        self.name = env.name

    def sh_rotated(self, rot: torch.Tensor) -> torch.Tensor:
        """``(n, 3)`` SH coefficients of the rotated lighting ``L(R^T w)``."""
        return sh.rotate(self.sh, rot.to(self.sh.device, torch.float64)).to(torch.float32)

    def integrate(self, mu: torch.Tensor, lam: torch.Tensor, rot: torch.Tensor) -> torch.Tensor:
        """``int G(w; mu, lam) L(R^T w) dw``, ``(..., 3)``: the lookup at ``R^T mu``."""
        return self.prefiltered.integrate(mu @ rot.to(mu.device, mu.dtype), lam)

    def background(self, dirs: torch.Tensor, rot: torch.Tensor) -> torch.Tensor:
        """Radiance seen along ``dirs (..., 3)`` in the rotated environment, ``(..., 3)``."""
        return self.env.radiance(dirs @ rot.to(dirs.device, dirs.dtype))
