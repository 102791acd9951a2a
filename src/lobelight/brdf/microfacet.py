"""Rough conductors as Mitsuba 3's ``roughconductor``: :class:`GGX` and :class:`Beckmann`."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, ClassVar

import torch

from ..errors import InputError
from ._base import (
    _COLOR,
    _COLOUR,
    _NUMBER,
    _PI,
    _SCALAR,
    BRDF,
    MIN_ROUGHNESS,
    _dot,
    _normalize,
    _reflect,
)

__all__ = ["GGX", "Beckmann"]


def _fresnel_conductor(cos_i: torch.Tensor, eta: torch.Tensor, k: torch.Tensor) -> torch.Tensor:
    """Unpolarised Fresnel reflectance of a conductor with index ``eta + i k`` (Mitsuba's
    ``fresnel_conductor``, after Moeller, "Optics", 1988).

    Parameters
    ----------
    cos_i : (...) cosine of incidence (> 0);  eta, k : () or (..., 3)

    Returns
    -------
    (..., 3)
    """
    c = cos_i.unsqueeze(-1)
    c2 = c * c
    s2 = 1 - c2
    s4 = s2 * s2
    temp1 = eta * eta - k * k - s2
    a2pb2 = torch.sqrt((temp1 * temp1 + 4 * k * k * eta * eta).clamp_min(0))
    a = torch.sqrt((0.5 * (a2pb2 + temp1)).clamp_min(0))
    term1 = a2pb2 + c2
    term2 = 2 * c * a
    rs = (term1 - term2) / (term1 + term2)
    term3 = a2pb2 * c2 + s4
    term4 = term2 * s2
    rp = rs * (term3 - term4) / (term3 + term4)
    return 0.5 * (rs + rp)


# Mitsuba's MicrofacetDistribution::configure() clamp, lobelight's sharpest lobe
_ALPHA_MIN = MIN_ROUGHNESS
#: ``D(m) cos(theta_m)`` at or below this is 0, as Mitsuba's ``MicrofacetDistribution::eval``
#: sets it against numerical trouble in the later stages (``pdf``, the sampling weights).
_D_CUTOFF = 1e-20
#: Beckmann visible-normal sampling keeps its uniforms this far inside (0, 1), as Mitsuba's
#: ``sample_visible_11`` does: ``log(u)`` and ``erfinv`` stay finite.
_U_MARGIN = 1e-6


class _Microfacet(BRDF):
    """Mitsuba 3 ``roughconductor`` with visible-normal sampling (:mod:`lobelight.brdf`).

    ``single_alpha`` is True when the model was built with one ``alpha`` (its parameter then;
    else ``alpha_u`` and ``alpha_v``), ``fresnel`` when with ``eta`` or ``k``. A roughness
    below :data:`lobelight.brdf.MIN_ROUGHNESS` (1e-4; 0 included, a mirror) is kept as given
    and evaluated at 1e-4, as Mitsuba does, without a warning.
    """

    beckmann: ClassVar[bool] = False
    _sun_id: ClassVar[int] = 0  # the sun shader's sun_model (prt.glsl)
    half_vector_lobe = True
    scene_params: ClassVar[Mapping[str, str]] = {
        "alpha": _NUMBER,
        "alpha_u": _NUMBER,
        "alpha_v": _NUMBER,
        "eta": _COLOUR,
        "k": _COLOUR,
        "specular": _COLOUR,
    }
    sun_param = "alpha"

    def __init__(
        self,
        alpha: Any = None,
        *,
        alpha_u: Any = None,
        alpha_v: Any = None,
        eta: Any = None,
        k: Any = None,
        specular: Any = 1.0,
    ):
        super().__init__()
        if alpha is not None and (alpha_u is not None or alpha_v is not None):
            raise InputError("alpha", "give either alpha or alpha_u and alpha_v, not both")
        if (alpha_u is None) != (alpha_v is None):
            missing = "alpha_v" if alpha_v is None else "alpha_u"
            raise InputError(missing, "alpha_u and alpha_v must be given together")
        self.single_alpha = alpha_u is None
        if self.single_alpha:
            self._set("alpha", 0.1 if alpha is None else alpha, _SCALAR, lo=0.0)
        else:
            self._set("alpha_u", alpha_u, _SCALAR, lo=0.0)
            self._set("alpha_v", alpha_v, _SCALAR, lo=0.0)
        self.fresnel = eta is not None or k is not None
        if self.fresnel:
            self._set("eta", 0.0 if eta is None else eta, _COLOR, lo=0.0)
            self._set("k", 1.0 if k is None else k, _COLOR, lo=0.0)
        self._set("specular", specular, _COLOR, lo=0.0, hi=1.0)
        self._check_shapes()

    # ---- the distribution (microfacet.h) ----------------------------------------------------

    def _alphas(self, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        if self.single_alpha:
            a = self._get("alpha", like).clamp_min(_ALPHA_MIN)
            return a, a
        return (
            self._get("alpha_u", like).clamp_min(_ALPHA_MIN),
            self._get("alpha_v", like).clamp_min(_ALPHA_MIN),
        )

    def _D(self, m: torch.Tensor, au: torch.Tensor, av: torch.Tensor) -> torch.Tensor:
        mx, my, mz = m.unbind(-1)
        cos2 = mz * mz
        if self.beckmann:
            r = torch.exp(-((mx / au) ** 2 + (my / av) ** 2) / cos2) / (_PI * au * av * cos2 * cos2)
        else:
            r = 1 / (_PI * au * av * ((mx / au) ** 2 + (my / av) ** 2 + cos2) ** 2)
        return torch.where(r * mz > _D_CUTOFF, r, torch.zeros_like(r))

    def _G1(self, v: torch.Tensor, m: torch.Tensor, au: torch.Tensor, av: torch.Tensor):
        vx, vy, vz = v.unbind(-1)
        xy = (au * vx) ** 2 + (av * vy) ** 2
        tan2 = xy / (vz * vz)
        if self.beckmann:
            a = torch.rsqrt(tan2)
            a2 = a * a
            r = (3.535 * a + 2.181 * a2) / (1 + 2.276 * a + 2.577 * a2)
            r = torch.where(a >= 1.6, torch.ones_like(r), r)
        else:
            r = 2 / (1 + torch.sqrt(1 + tan2))
        r = torch.where(xy == 0, torch.ones_like(r), r)
        return torch.where(_dot(v, m) * vz <= 0, torch.zeros_like(r), r)

    def _F(self, cos: torch.Tensor) -> torch.Tensor:
        spec = self._get("specular", cos)
        if not self.fresnel:
            return spec + torch.zeros_like(cos).unsqueeze(-1)
        return spec * _fresnel_conductor(cos, self._get("eta", cos), self._get("k", cos))

    # ---- BRDF hooks (Mitsuba's si.wi is our wo, its wo our wi) ------------------------------

    def _eval(self, wi, wo):
        au, av = self._alphas(wi)
        h = _normalize(wi + wo)
        d = self._D(h, au, av)
        g = self._G1(wo, h, au, av) * self._G1(wi, h, au, av)
        val = d * g / (4 * wo[..., 2] * wi[..., 2])
        return self._F(_dot(wo, h)) * val.unsqueeze(-1)

    def _pdf(self, wi, wo):
        au, av = self._alphas(wi)
        h = _normalize(wi + wo)
        ok = (_dot(wo, h) > 0) & (_dot(wi, h) > 0)
        pdf = self._D(h, au, av) * self._G1(wo, h, au, av) / (4 * wo[..., 2])
        return torch.where(ok, pdf, torch.zeros_like(pdf))

    def _visible_11(self, cos_i: torch.Tensor, u: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """Slope of a visible normal for unit roughness (Mitsuba's ``sample_visible_11``)."""
        u0, u1 = u[..., 0], u[..., 1]
        if self.beckmann:
            tan_i = torch.sqrt((1 - cos_i * cos_i).clamp_min(0)) / cos_i
            cot_i = 1 / tan_i
            maxval = torch.erf(cot_i)
            u0 = u0.clamp(_U_MARGIN, 1 - _U_MARGIN)
            u1 = u1.clamp(_U_MARGIN, 1 - _U_MARGIN)
            x = maxval - (maxval + 1) * torch.erf(torch.sqrt(-torch.log(u0)))
            inv_sqrt_pi = 1 / math.sqrt(_PI)
            u0 = u0 * (1 + maxval + inv_sqrt_pi * tan_i * torch.exp(-cot_i * cot_i))
            for _ in range(3):  # Newton iterations
                slope = torch.erfinv(x)
                value = 1 + x + inv_sqrt_pi * tan_i * torch.exp(-slope * slope) - u0
                x = x - value / (1 - slope * tan_i)
            return torch.erfinv(x), torch.erfinv(2 * u1 - 1)
        # GGX (Heitz 2018): uniform disk (concentric map), squeezed onto the visible half
        px, py = 2 * u0 - 1, 2 * u1 - 1
        quad13 = px.abs() < py.abs()
        r = torch.where(quad13, py, px)
        rp = torch.where(quad13, px, py)
        r_safe = torch.where(r == 0, torch.ones_like(r), r)
        phi = 0.25 * _PI * rp / r_safe
        phi = torch.where(quad13, 0.5 * _PI - phi, phi)
        phi = torch.where((px == 0) & (py == 0), torch.zeros_like(phi), phi)
        x, y = r * torch.cos(phi), r * torch.sin(phi)
        s = 0.5 * (1 + cos_i)
        low = torch.sqrt((1 - x * x).clamp_min(0))
        y = low * (1 - s) + y * s
        z = torch.sqrt((1 - x * x - y * y).clamp_min(0))
        sin_i = torch.sqrt((1 - cos_i * cos_i).clamp_min(0))
        norm = 1 / (sin_i * y + cos_i * z)
        return (cos_i * y - sin_i * z) * norm, x * norm

    def _sample(self, wo, u):
        au, av = self._alphas(wo)
        # 1. stretch wo
        wp = _normalize(
            torch.stack(torch.broadcast_tensors(au * wo[..., 0], av * wo[..., 1], wo[..., 2]), -1)
        )
        s2 = wp[..., 0] ** 2 + wp[..., 1] ** 2
        inv = torch.rsqrt(s2.clamp_min(torch.finfo(s2.dtype).tiny))
        flat = s2 <= 2 * torch.finfo(s2.dtype).eps  # Mitsuba: 4 * dr::Epsilon = 4 * 2^-24
        cos_phi = torch.where(flat, torch.ones_like(s2), (wp[..., 0] * inv).clamp(-1, 1))
        sin_phi = torch.where(flat, torch.zeros_like(s2), (wp[..., 1] * inv).clamp(-1, 1))
        # 2. sample the unit-roughness slope distribution, 3. rotate and unstretch
        sx, sy = self._visible_11(wp[..., 2], u)
        mx = (cos_phi * sx - sin_phi * sy) * au
        my = (sin_phi * sx + cos_phi * sy) * av
        # 4. normal, reflected direction, density and weight
        mx, my = torch.broadcast_tensors(mx, my)
        m = _normalize(torch.stack([-mx, -my, torch.ones_like(mx)], -1))
        wo_b = wo.expand_as(m)
        wo_m = _dot(wo_b, m)
        pdf_m = self._D(m, au, av) * self._G1(wo_b, m, au, av) * wo_m.abs() / wo_b[..., 2]
        wi = _reflect(wo_b, m)
        pdf = pdf_m / (4 * _dot(wi, m))
        pdf = torch.where(pdf_m != 0, pdf, torch.zeros_like(pdf))
        weight = self._F(wo_m) * self._G1(wi, m, au, av).unsqueeze(-1)
        return wi, weight, pdf

    def _albedo_guess(self, wo):
        return self._F(wo[..., 2].clamp(0, 1)).mean(-1)

    # ---- capabilities -----------------------------------------------------------------------

    @property
    def isotropic(self) -> bool:
        return self.single_alpha or bool(torch.equal(self._p["alpha_u"], self._p["alpha_v"]))

    @property
    def sun_model(self) -> int | None:
        # the shader reads one alpha (sun_param)
        return self._sun_id if self.single_alpha else None

    def _sun_widened(self, spread2):
        # the lobe's slopes and the disc's half-vector offsets (sigma / 2) add their variances
        return self.replace(alpha=(self.params["alpha"] ** 2 + spread2 / 4).sqrt())

    def mitsuba_dict(self) -> dict[str, Any]:
        p = {k: v.reshape(-1).tolist() for k, v in self.params.items()}
        d: dict[str, Any] = {"type": "roughconductor", "distribution": self.type_name}
        if "alpha" in p:
            d["alpha"] = float(p["alpha"][0])
        else:
            d["alpha_u"], d["alpha_v"] = float(p["alpha_u"][0]), float(p["alpha_v"][0])
        if "eta" in p:
            d["eta"] = {"type": "rgb", "value": (p["eta"] * 3)[:3]}
            d["k"] = {"type": "rgb", "value": (p["k"] * 3)[:3]}
        else:
            d["material"] = "none"
        col = p.get("specular", [1.0])
        d["specular_reflectance"] = {"type": "rgb", "value": (col * 3)[:3]}
        return d


class GGX(_Microfacet):
    """Rough conductor with the GGX (Trowbridge-Reitz) distribution, as Mitsuba 3's
    ``roughconductor`` with ``distribution="ggx"``.

    Parameters
    ----------
    alpha : () or (...) isotropic roughness >= 0 (default 0.1, Mitsuba's default); or
    alpha_u, alpha_v : () or (...) roughness along the tangent / bitangent (both or neither)
    eta, k : () or (..., 3) complex index of refraction ``eta + i k`` (>= 0) per RGB channel;
        both None means Fresnel = 1 (Mitsuba's ``material="none"``); only ``eta`` -> ``k = 1``,
        only ``k`` -> ``eta = 0``, as in Mitsuba
    specular : () or (..., 3) ``specular_reflectance`` factor in [0, 1] (default 1)
    """

    type_name = "ggx"
    beckmann = False
    _sun_id = 0


class Beckmann(_Microfacet):
    """Rough conductor with the Beckmann distribution, as Mitsuba 3's ``roughconductor`` with
    ``distribution="beckmann"`` (``alpha`` is the RMS slope). Parameters as :class:`GGX`."""

    type_name = "beckmann"
    beckmann = True
    _sun_id = 1
