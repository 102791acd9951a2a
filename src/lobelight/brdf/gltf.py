"""The glTF 2.0 metallic-roughness material: :class:`GGXSchlick`, its specular lobe, and
:func:`metallic_roughness`, which turns a glTF material's factors into a Lambert albedo and
that lobe.

The core glTF 2.0 specification's material (``pbrMetallicRoughness``) with base colour ``c``,
metallic ``m`` and perceptual roughness ``r`` is taken here as::

    f = c (1 - m) / pi  +  F(wo.h) D(h) G1(wi, h) G1(wo, h) / (4 z_i z_o)
    F = F0 + (1 - F0) (1 - wo.h)^5,   F0 = mix(0.04, c, m) = 0.04 (1 - m) + c m

with ``D`` the GGX distribution of ``alpha = r^2`` and ``G1`` Smith's separable masking, as in
:class:`lobelight.brdf.GGX`. The diffuse term is a plain Lambert of ``c (1 - m)``: it carries
no ``(1 - F)`` factor (the specification's informative Appendix B weights it by one minus the
dielectric Fresnel term), so that a material stays lobelight's per-vertex ``diffuse / pi +
f_spec`` whose diffuse transfer the transport bakes. The price: a bright non-metal reflects
more than it receives towards grazing views (the Schlick term goes to 1 there while the
Lambert term stays), so a white non-metal's albedo exceeds 1 towards grazing views. The
specular lobe alone never exceeds 1 (``F <= 1``).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np
import torch

from ..errors import InputError
from ._base import _COLOR, _COLOUR, _NUMBER, _SCALAR, BRDF, _as_param, _check_param
from .microfacet import _Microfacet

__all__ = ["DIELECTRIC_F0", "GGXSchlick", "metallic_roughness"]

#: The reflectance at normal incidence of glTF's non-metals (an index of refraction of 1.5).
DIELECTRIC_F0 = 0.04
#: Roughness clamp, as Mitsuba 3's ``principled`` (``calc_dist_params``: ``max(0.001, r^2)``),
#: which is this lobe's Mitsuba counterpart.
_ALPHA_MIN = 1e-3


class GGXSchlick(_Microfacet):
    """GGX microfacet reflection with Schlick's Fresnel term: the specular lobe of the glTF
    2.0 metallic-roughness material (module docstring)::

        f = F(wo.h) D(h) G1(wi, h) G1(wo, h) / (4 z_i z_o),   F = F0 + (1 - F0) pos(1 - wo.h)^5

    ``D`` and ``G1`` are :class:`lobelight.brdf.GGX`'s (isotropic, ``alpha`` clamped below at
    1e-3 as in Mitsuba 3's ``principled``), and so are the sampling (visible normals,
    ``pdf = D G1(wo) / (4 z_o)``, ``weight = F G1(wi)``), the sun shader's distribution and the
    sun disc's widening. Mitsuba 3's ``principled`` with ``metallic = 1``, ``base_color = F0``
    and ``roughness = sqrt(alpha)`` is this lobe (:meth:`mitsuba_dict`). Build it from glTF
    factors with :func:`metallic_roughness`.

    Parameters
    ----------
    alpha : () or (...) GGX roughness >= 0 (glTF's perceptual roughness squared; default 0.1)
    f0 : () or (..., 3) reflectance at normal incidence in [0, 1] (default 0.04, glTF's
        non-metals)
    """

    type_name = "ggx_schlick"
    beckmann = False
    _sun_id = 0
    schlick = True
    scene_params: ClassVar[Mapping[str, str]] = {"alpha": _NUMBER, "f0": _COLOUR}

    def __init__(self, alpha: Any = 0.1, f0: Any = DIELECTRIC_F0):
        BRDF.__init__(self)  # not _Microfacet's: no alpha_u / alpha_v, eta, k or specular
        self.single_alpha = True
        self.fresnel = False
        self._set("alpha", alpha, _SCALAR, lo=0.0)
        self._set("f0", f0, _COLOR, lo=0.0, hi=1.0)
        self._check_shapes()

    def _alphas(self, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        a = self._get("alpha", like).clamp_min(_ALPHA_MIN)
        return a, a

    def _F(self, cos: torch.Tensor) -> torch.Tensor:
        f0 = self._get("f0", cos)
        m = (1 - cos).clamp(0, 1).unsqueeze(-1)
        return f0 + (1 - f0) * (m * m) * (m * m) * m

    def mitsuba_dict(self) -> dict[str, Any]:
        """Mitsuba 3's ``principled`` with only its metallic lobe: ``metallic = 1``,
        ``base_color = f0``, ``roughness = sqrt(alpha)`` (its Fresnel term is then Schlick's
        from ``base_color``; ``specular`` keeps its default, 0.5, whose dielectric Fresnel
        only has to be non-zero for the lobe to be evaluated)."""
        p = {k: v.reshape(-1).tolist() for k, v in self.params.items()}
        return {
            "type": "principled",
            "base_color": {"type": "rgb", "value": (p["f0"] * 3)[:3]},
            "metallic": 1.0,
            "roughness": float(p["alpha"][0]) ** 0.5,
        }


def metallic_roughness(
    base_color: Any, metallic: Any, roughness: Any
) -> tuple[torch.Tensor, GGXSchlick]:
    """The glTF 2.0 metallic-roughness material (module docstring) as lobelight's
    ``diffuse / pi + f_spec``: the Lambert albedo and the specular lobe.

    Parameters
    ----------
    base_color : () or (..., 3) linear base colour in [0, 1] (``baseColorFactor`` times the
        decoded texture and vertex colour; alpha dropped)
    metallic, roughness : () or (...) in [0, 1] (``metallicFactor`` / ``roughnessFactor``
        times the texture's B / G channel)

    Returns
    -------
    diffuse : (..., 3) ``base_color (1 - metallic)`` (float32 unless ``base_color`` is a
    floating tensor, whose dtype the results take);
    specular : :class:`GGXSchlick` with ``alpha = roughness^2`` and
    ``f0 = 0.04 (1 - metallic) + base_color metallic``

    Raises
    ------
    InputError
        naming the factor that is not finite or outside [0, 1], or whose shapes do not
        broadcast
    """
    c = _as_param(base_color, "base_color")
    m = _as_param(metallic, "metallic").to(c.dtype)
    r = _as_param(roughness, "roughness").to(c.dtype)
    _check_param(c, "base_color", _COLOR, lo=0.0, hi=1.0)
    _check_param(m, "metallic", _SCALAR, lo=0.0, hi=1.0)
    _check_param(r, "roughness", _SCALAR, lo=0.0, hi=1.0)
    if c.ndim == 0:
        c = c.expand(3)
    joint = tuple(c.shape[:-1])
    for name, t in (("metallic", m), ("roughness", r)):
        try:
            joint = np.broadcast_shapes(joint, tuple(t.shape))  # numpy's: no sympy import
        except ValueError:
            raise InputError(
                name, f"per-element shape {tuple(t.shape)} does not broadcast with {joint}"
            ) from None
    mc = m.unsqueeze(-1)
    diffuse = c * (1 - mc)
    f0 = DIELECTRIC_F0 * (1 - mc) + c * mc
    return diffuse, GGXSchlick(r * r, f0)
