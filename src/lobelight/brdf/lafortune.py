"""Generalised cosine lobes (Lafortune et al. 1997): :class:`Lafortune`."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import torch

from ..errors import InputError
from ._base import (
    _COLOR,
    _LOBES,
    _PI,
    _SCALAR,
    BRDF,
    MAX_EXPONENT,
    CosineLobe,
    _choose,
    _color_as,
    _cospow,
    _mean_color,
    _normalize,
    _sample_cospow,
    _select,
)

__all__ = ["MAX_ALBEDO_BOUND", "Lafortune"]

_LOBE_KEYS = ("cx", "cy", "cz", "exponent", "rho")
#: The largest albedo bound (:meth:`Lafortune.albedo_bound`) of a Lafortune model: a physical
#: material reflects at most the light it receives, and a model file holds Gaussians carrying
#: at most 1e4 (lobelight.model.MAX_LIGHT); lobes with more overflow float32 soon after.
MAX_ALBEDO_BOUND = 1e4


class Lafortune(BRDF):
    """Generalised cosine lobes (Lafortune et al. 1997), anisotropic in the local frame.

    ``f = sum_j rho_j pos(cx_j wi_x wo_x + cy_j wi_y wo_y + cz_j wi_z wo_z)^e_j``.

    Parameters
    ----------
    lobes : sequence of mappings with keys ``cx, cy, cz`` (() or (...) finite coefficients),
        ``exponent`` (() or (...) ``>= 0``) and ``rho`` (() or (..., 3) ``>= 0``, the raw lobe
        factor: not normalised). E.g. ``cx = cy = -1, cz = 1`` is the Phong lobe about the
        mirror direction, ``cx = cy = 0`` a lobe about the normal, ``cx = cy > cz`` retro- and
        off-specular effects.

    An exponent above :data:`lobelight.brdf.MAX_EXPONENT` (5e7, the sharpness of a Beckmann
    lobe of roughness 1e-4) is taken as that, with a warning: sharper lobes are mirrors at any
    image size, and their fits are not finite. Lobes whose :meth:`albedo_bound` exceeds
    :data:`MAX_ALBEDO_BOUND` are refused: their values overflow float32, or carry more light
    than a model file holds.
    """

    type_name = "lafortune"
    scene_params: ClassVar[Mapping[str, str]] = {"lobes": _LOBES}

    def __init__(self, lobes: Sequence[Mapping[str, Any]]):
        super().__init__()
        if isinstance(lobes, Mapping) or not isinstance(lobes, Sequence) or len(lobes) == 0:
            raise InputError(
                "lobes", "must be a non-empty list of lobes (cx, cy, cz, exponent, rho)"
            )
        for j, lobe in enumerate(lobes):
            if not isinstance(lobe, Mapping):
                raise InputError(
                    f"lobes[{j}]", "must be a mapping with keys " + ", ".join(_LOBE_KEYS)
                )
            extra = set(lobe) - set(_LOBE_KEYS)
            if extra:
                raise InputError(f"lobes[{j}].{sorted(extra)[0]}", "unknown lobe parameter")
            missing = [k for k in _LOBE_KEYS if k not in lobe]
            if missing:
                raise InputError(f"lobes[{j}].{missing[0]}", "is missing")
            for c in ("cx", "cy", "cz"):
                self._set(f"lobes[{j}].{c}", lobe[c], _SCALAR)
            self._set(f"lobes[{j}].exponent", lobe["exponent"], _SCALAR, lo=0.0)
            self._clamp(f"lobes[{j}].exponent", hi=MAX_EXPONENT)
            self._set(f"lobes[{j}].rho", lobe["rho"], _COLOR, lo=0.0)
        self.n_lobes = len(lobes)
        self._check_shapes()
        self._check_bound()

    def _check_bound(self) -> None:
        """Refuse lobes whose albedo bound (float64) exceeds :data:`MAX_ALBEDO_BOUND`."""
        with torch.no_grad():
            bound = float(self.to(dtype=torch.float64).albedo_bound().max())
        if not bound <= MAX_ALBEDO_BOUND:  # NaN too
            raise InputError(
                "lobes",
                f"reflect up to {bound:.3g} times the light they receive (the albedo bound "
                f"sum_j 2 pi rho_j max|c_j|^e_j / (e_j + 1)), over {MAX_ALBEDO_BOUND:g}: "
                f"lower rho, the exponents, or the coefficients |cx|, |cy|, |cz| above 1",
            )

    def _lobe(self, j: int, like: torch.Tensor):
        """Lobe ``j``'s (cx, cy, cz, exponent, rho) in the dtype/device of ``like``."""
        return tuple(self._get(f"lobes[{j}].{k}", like) for k in _LOBE_KEYS)

    def _axes(self, wo: torch.Tensor) -> list[tuple[torch.Tensor, torch.Tensor, Any, Any]]:
        """Per lobe: unit axis d^ (..., 3), |d| (...), exponent, rho."""
        out = []
        for j in range(self.n_lobes):
            d, norm, e, rho = self._lobe_vector(j, wo)
            out.append((_normalize(d), norm, e, rho))
        return out

    def _lobe_vector(self, j: int, wo: torch.Tensor):
        """Lobe ``j``'s non-unit axis ``d = (cx wo_x, cy wo_y, cz wo_z)`` (..., 3), its length
        (...), exponent and rho."""
        cx, cy, cz, e, rho = self._lobe(j, wo)
        d = torch.stack(
            torch.broadcast_tensors(cx * wo[..., 0], cy * wo[..., 1], cz * wo[..., 2]), -1
        )
        return d, torch.linalg.vector_norm(d, dim=-1), e, rho

    @staticmethod
    def _scale(norm: torch.Tensor, e: torch.Tensor) -> torch.Tensor:
        """``|d|^e`` with 0 for a zero axis (the lobe vanishes)."""
        tiny = torch.finfo(norm.dtype).tiny
        return torch.where(norm > 0, torch.exp(e * torch.log(norm.clamp_min(tiny))), 0.0)

    def _eval(self, wi, wo):
        f = None
        for dhat, norm, e, rho in self._axes(wo):
            lobe = (self._scale(norm, e) * _cospow(dhat, wi, e)).unsqueeze(-1) * rho
            f = lobe if f is None else f + lobe
        return f

    def _weights(self, axes, like: torch.Tensor) -> list[torch.Tensor]:
        return [
            _mean_color(rho) * self._scale(norm, e) * (2 * _PI) / (e + 1)
            + torch.zeros_like(like[..., 2])
            for _dhat, norm, e, rho in axes
        ]

    def _pdf_axes(self, wi, axes, probs) -> torch.Tensor:
        pdf = None
        for j, (dhat, _norm, e, _rho) in enumerate(axes):
            pj = probs[j] * (e + 1) / (2 * _PI) * _cospow(dhat, wi, e)
            pdf = pj if pdf is None else pdf + pj
        return pdf

    def _pdf(self, wi, wo):
        axes = self._axes(wo)
        _, probs, _ = _choose(self._weights(axes, wo), torch.zeros_like(wo[..., 2]))
        return self._pdf_axes(wi, axes, probs)

    def _sample(self, wo, u):
        axes = self._axes(wo)
        uc = u[..., 2] if u.shape[-1] == 3 else u[..., 0]
        idx, probs, u_new = _choose(self._weights(axes, wo), uc)
        u0 = u[..., 0] if u.shape[-1] == 3 else u_new
        u0 = u0.expand(idx.shape)
        u1 = u[..., 1].expand(idx.shape)
        cands = []
        for dhat, norm, e, _rho in axes:
            zaxis = torch.zeros_like(dhat)
            zaxis[..., 2] = 1
            axis = torch.where((norm > 0).unsqueeze(-1), dhat, zaxis).expand(*idx.shape, 3)
            cands.append(_sample_cospow(axis, e.expand(idx.shape), u0, u1))
        wi = _select(idx, cands)
        pdf = self._pdf_axes(wi, axes, probs)
        f = self._eval(wi, wo)
        tiny = torch.finfo(pdf.dtype).tiny
        weight = f * (wi[..., 2].clamp_min(0) / pdf.clamp_min(tiny)).unsqueeze(-1)
        return wi, weight, pdf

    def _albedo_guess(self, wo):
        axes = self._axes(wo)
        return torch.stack(self._weights(axes, wo)).sum(0)

    def albedo_bound(self) -> torch.Tensor:
        """An upper bound on the directional albedo, per element and channel: ``(..., 3)``.

        ``∫ pos(d.w)^e cos dw <= ∫ pos(d.w)^e dw = 2 pi |d|^e / (e + 1)`` and
        ``|d| <= max(|cx|, |cy|, |cz|)``, so the albedo is at most
        ``sum_j rho_j 2 pi max|c|^e / (e + 1)``. A lobe set with this bound ``<= 1`` conserves
        energy for every ``wo``.
        """
        total = None
        for j in range(self.n_lobes):
            cx, cy, cz, e, rho = (self._p[f"lobes[{j}].{k}"] for k in _LOBE_KEYS)
            cmax = torch.maximum(torch.maximum(cx.abs(), cy.abs()), cz.abs())
            b = (2 * _PI * cmax**e / (e + 1)).unsqueeze(-1) * rho + torch.zeros(
                3, dtype=rho.dtype, device=rho.device
            )
            total = b if total is None else total + b
        return total

    def to_dict(self) -> dict[str, Any]:
        lobes = [
            {k: self._p[f"lobes[{j}].{k}"].detach().cpu().tolist() for k in _LOBE_KEYS}
            for j in range(self.n_lobes)
        ]
        return {"type": self.type_name, "lobes": lobes}

    # ---- capabilities -----------------------------------------------------------------------

    @property
    def isotropic(self) -> bool:
        """True when every lobe has ``cx == cy`` (then it turns with the view about the normal)."""
        return all(
            bool(torch.equal(self._p[f"lobes[{j}].cx"], self._p[f"lobes[{j}].cy"]))
            for j in range(self.n_lobes)
        )

    @property
    def cosine_lobe_flags(self) -> tuple[bool, ...]:
        return (False,) * self.n_lobes

    def _cosine_lobes(self, wo):
        # lobe j is rho_j pos(d_j.wi)^e_j with the non-unit d_j = (cx wo_x, cy wo_y, cz wo_z):
        # unit axis d_j / |d_j| and scale rho_j |d_j|^e_j
        batch = wo.shape[:-1]
        out = []
        for j in range(self.n_lobes):
            d, norm, e, rho = self._lobe_vector(j, wo)
            tiny = torch.finfo(norm.dtype).tiny
            axis = d / norm.clamp_min(tiny).unsqueeze(-1)
            e = e.expand(batch)
            # |d|^e, and 0 for a vanishing vector (the lobe is 0 everywhere)
            mag = torch.where(norm > 0, torch.exp(e * torch.log(norm.clamp_min(tiny))), 0.0)
            out.append(CosineLobe(axis, e, _color_as(rho, batch) * mag.unsqueeze(-1), False))
        return out
