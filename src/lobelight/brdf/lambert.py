"""Lambertian diffuse reflection: :class:`Lambert`."""

from __future__ import annotations

from typing import Any

import torch

from ._base import _COLOR, _PI, BRDF, CosineLobe, _color_as, _mean_color

__all__ = ["Lambert"]


class Lambert(BRDF):
    """Lambertian diffuse reflection ``f = albedo / pi``.

    Parameters
    ----------
    albedo : () or (..., 3) reflectance in [0, 1]
    """

    type_name = "lambert"

    def __init__(self, albedo: Any):
        super().__init__()
        self._set("albedo", albedo, _COLOR, lo=0.0, hi=1.0)

    def _eval(self, wi, wo):
        rho = self._get("albedo", wi)
        z = torch.zeros_like(wi[..., 2] + wo[..., 2]).unsqueeze(-1)
        return z + rho / _PI

    def _pdf(self, wi, wo):
        return wi[..., 2].clamp_min(0) / _PI + torch.zeros_like(wo[..., 2])

    def _sample(self, wo, u):
        r = torch.sqrt(u[..., 0])
        phi = 2 * _PI * u[..., 1]
        z = torch.sqrt((1 - u[..., 0]).clamp_min(0))
        wi = torch.stack(torch.broadcast_tensors(r * torch.cos(phi), r * torch.sin(phi), z), -1)
        wi, _ = torch.broadcast_tensors(wi, wo)
        rho = self._get("albedo", wo)
        weight = torch.zeros_like(wi) + rho
        return wi, weight, z / _PI + torch.zeros_like(wo[..., 2])

    def _albedo_guess(self, wo):
        return _mean_color(self._get("albedo", wo)) + torch.zeros_like(wo[..., 2])

    # ---- capabilities -----------------------------------------------------------------------

    @property
    def isotropic(self) -> bool:
        return True

    @property
    def cosine_lobe_flags(self) -> tuple[bool, ...]:
        return (True,)

    def _cosine_lobes(self, wo):
        # albedo / pi * pos(n.wi)^1: already f_r times the cosine, one exact lobe
        batch = wo.shape[:-1]
        zhat = torch.tensor([0.0, 0.0, 1.0], dtype=wo.dtype, device=wo.device)
        ones = torch.ones(batch, dtype=wo.dtype, device=wo.device)
        albedo = _color_as(self._get("albedo", wo), batch)
        return [CosineLobe(zhat.expand(*batch, 3), ones, albedo / _PI, True)]
