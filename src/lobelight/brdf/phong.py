"""Cosine-power lobes: modified Phong (:class:`Phong`) and normalised Blinn-Phong
(:class:`BlinnPhong`)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

import torch

from ._base import (
    _COLOR,
    _COLOUR,
    _NUMBER,
    _PI,
    _SCALAR,
    BRDF,
    MAX_EXPONENT,
    MAX_HALF_VECTOR_EXPONENT,
    CosineLobe,
    _color_as,
    _cospow,
    _mean_color,
    _normalize,
    _reflect,
    _sample_cospow,
)

__all__ = ["BlinnPhong", "Phong"]


class _ExponentLobe(BRDF):
    """Shared parameters of the cosine-power lobes: a colour ``specular`` and an ``exponent``."""

    scene_params: ClassVar[Mapping[str, str]] = {"specular": _COLOUR, "exponent": _NUMBER}
    sun_param = "exponent"
    #: The largest exponent, the sharpest lobe lobelight models (:mod:`lobelight.brdf`)
    max_exponent: ClassVar[float] = MAX_EXPONENT

    def __init__(self, specular: Any, exponent: Any):
        super().__init__()
        self._set("specular", specular, _COLOR, lo=0.0, hi=1.0)
        self._set("exponent", exponent, _SCALAR, lo=0.0)
        self._clamp("exponent", hi=self.max_exponent)
        self._check_shapes()

    def _albedo_guess(self, wo):
        return _mean_color(self._get("specular", wo)) + torch.zeros_like(wo[..., 2])

    @property
    def isotropic(self) -> bool:
        return True


class Phong(_ExponentLobe):
    """Modified Phong (Lafortune & Willems 1994): ``ks (e + 2)/(2 pi) pos(r.wi)^e``.

    Parameters
    ----------
    specular : () or (..., 3) ``ks`` in [0, 1] (the albedo at normal incidence)
    exponent : () or (...) ``e >= 0``; above :data:`lobelight.brdf.MAX_EXPONENT` (5e7, the
        sharpness of a Beckmann lobe of roughness 1e-4) it is taken as that, with a warning:
        sharper lobes are mirrors at any image size, and their fits are not finite
    """

    type_name = "phong"

    @staticmethod
    def _mirror(wo: torch.Tensor) -> torch.Tensor:
        return wo * torch.tensor([-1.0, -1.0, 1.0], dtype=wo.dtype, device=wo.device)

    def _eval(self, wi, wo):
        e = self._get("exponent", wi)
        lobe = (e + 2) / (2 * _PI) * _cospow(self._mirror(wo), wi, e)
        return lobe.unsqueeze(-1) * self._get("specular", wi)

    def _pdf(self, wi, wo):
        e = self._get("exponent", wi)
        return (e + 1) / (2 * _PI) * _cospow(self._mirror(wo), wi, e)

    def _sample_dir(self, wo, u):
        e = self._get("exponent", wo)
        r, e, u0, u1 = torch.broadcast_tensors(
            self._mirror(wo), e[..., None], u[..., :1], u[..., 1:2]
        )
        return _sample_cospow(r, e[..., 0], u0[..., 0], u1[..., 0])

    # ---- capabilities -----------------------------------------------------------------------

    @property
    def sun_model(self) -> int:
        return 2

    def _sun_widened(self, spread2):
        # a mirror lobe ~ exp(-e theta^2 / 2): its variance 1 / e and the disc's add
        e = self.params["exponent"]
        return self.replace(exponent=e / (1 + e * spread2 / 2))

    @property
    def cosine_lobe_flags(self) -> tuple[bool, ...]:
        return (False,)

    def _cosine_lobes(self, wo):
        # ks (e + 2) / (2 pi) pos(r.wi)^e about the mirror direction r of wo
        batch = wo.shape[:-1]
        e = self._get("exponent", wo).expand(batch)
        ks = _color_as(self._get("specular", wo), batch)
        return [CosineLobe(self._mirror(wo), e, ks * ((e + 2) / (2 * _PI)).unsqueeze(-1), False)]


def _blinn_norm(e: torch.Tensor) -> torch.Tensor:
    """``(e + 2)(e + 4) / (8 pi (2^(-e/2) + e))``: Blinn-Phong albedo at normal incidence = 1."""
    return (e + 2) * (e + 4) / (8 * _PI * (torch.exp2(-e / 2) + e))


class BlinnPhong(_ExponentLobe):
    """Normalised Blinn-Phong ``ks c(e) pos(n.h)^e`` with the exact normalisation ``c(e)``.

    ``c(e) = (e + 2)(e + 4) / (8 pi (2^(-e/2) + e))`` makes the albedo at normal incidence
    exactly ``ks`` (and less elsewhere); see :mod:`lobelight.brdf`.

    Parameters
    ----------
    specular : () or (..., 3) ``ks`` in [0, 1]
    exponent : () or (...) ``e >= 0``; above :data:`lobelight.brdf.MAX_HALF_VECTOR_EXPONENT`
        (2e8, a Beckmann lobe of roughness 1e-4) it is taken as that, with a warning: sharper
        lobes are mirrors at any image size, and their fits are not finite
    """

    type_name = "blinn_phong"
    half_vector_lobe = True
    max_exponent: ClassVar[float] = MAX_HALF_VECTOR_EXPONENT

    @staticmethod
    def _zhat(like: torch.Tensor) -> torch.Tensor:
        return torch.tensor([0.0, 0.0, 1.0], dtype=like.dtype, device=like.device)

    def _eval(self, wi, wo):
        e = self._get("exponent", wi)
        h = _normalize(wi + wo)
        lobe = _blinn_norm(e) * _cospow(self._zhat(h), h, e)
        return lobe.unsqueeze(-1) * self._get("specular", wi)

    def _pdf(self, wi, wo):
        e = self._get("exponent", wi)
        s = wi + wo
        h = _normalize(s)
        wo_h = 0.5 * torch.linalg.vector_norm(s, dim=-1)  # wo.h = |wi + wo| / 2
        pdf_h = (e + 1) / (2 * _PI) * _cospow(self._zhat(h), h, e)
        return pdf_h / (4 * wo_h.clamp_min(torch.finfo(wo_h.dtype).tiny))

    def _sample_dir(self, wo, u):
        e = self._get("exponent", wo)
        z, e, u0, u1 = torch.broadcast_tensors(
            self._zhat(wo).expand_as(wo), e[..., None], u[..., :1], u[..., 1:2]
        )
        h = _sample_cospow(z, e[..., 0], u0[..., 0], u1[..., 0])
        return _reflect(wo.expand_as(h), h)

    # ---- capabilities -----------------------------------------------------------------------

    @property
    def sun_model(self) -> int:
        return 3

    def _sun_widened(self, spread2):
        # through the Beckmann alpha of the lobe, alpha^2 = 2 / (e + 2), widened as a
        # microfacet lobe's (microfacet.py)
        e = self.params["exponent"]
        a2 = 2 / (e + 2) + spread2 / 4
        return self.replace(exponent=(2 / a2 - 2).clamp_min(0))
