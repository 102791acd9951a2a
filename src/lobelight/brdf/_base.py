"""The BRDF interface, the helpers the models share, the sum of models and the registry.

The models are documented in :mod:`lobelight.brdf` (the API page); this module holds what every
model builds on: :class:`BRDF` (parameters, the public evaluation and sampling in world
coordinates, the local-frame hooks a model implements, and the capabilities other packages ask
a model about), :class:`Sum`, and the registry of models by ``type`` name that
:func:`from_dict` reads (filled by :mod:`lobelight.brdf` with :func:`register`).
"""

from __future__ import annotations

import abc
import copy
import inspect
import math
import types
import warnings
from collections.abc import Callable, Mapping, Sequence
from typing import Any, ClassVar, NamedTuple

import numpy as np
import torch

from .._backend import as_tensor
from ..errors import InputError
from ..geometry.sphere import frame

_PI = math.pi
#: A given tangent whose part orthogonal to the normal is shorter than this fraction of it is
#: taken as parallel to the normal: the frame then uses frame(n)'s tangent.
_PARALLEL_TANGENT = 1e-6
_SCALAR, _COLOR = 0, 1  # number of trailing (event) dimensions of a parameter kind
#: What a key of a scene file's material takes (:attr:`BRDF.scene_params`): one number, one
#: number (grey) or an RGB triple, a list of lobe tables.
_NUMBER, _COLOUR, _LOBES = "number", "colour", "lobes"

#: The sharpest lobe lobelight models, as a roughness: a Ward (or Beckmann, GGX) ``alpha`` of
#: 1e-4, a lobe about 1e-4 radians wide, a mirror at any image size (a pixel of an image 4,096
#: pixels and 40 degrees wide spans 1.7e-4 radians). Mitsuba clamps its microfacet roughness
#: there; sharper lobes' fits are not finite in float32.
MIN_ROUGHNESS = 1e-4
#: The largest Blinn-Phong exponent: ``2 / alpha^2 - 2`` at :data:`MIN_ROUGHNESS` (its Beckmann
#: equivalent, the same sharpness of the half vector's lobe).
MAX_HALF_VECTOR_EXPONENT = 2 / MIN_ROUGHNESS**2 - 2
#: The largest Phong and Lafortune exponent: ``1 / (2 alpha^2)`` at :data:`MIN_ROUGHNESS`, the
#: sharpness of a Beckmann lobe's reflected directions (``cos^e`` is ``exp(-e theta^2 / 2)``
#: near its axis; the half vector turns by half the reflected direction's angle).
MAX_EXPONENT = 1 / (2 * MIN_ROUGHNESS**2)


# --------------------------------------------------------------------------------------------
# parameters


def _as_param(value: Any, name: str) -> torch.Tensor:
    """A floating tensor from a number, list, numpy array or tensor (tensors keep dtype/device)."""
    if isinstance(value, torch.Tensor):
        return value if value.is_floating_point() else value.to(torch.float32)
    if isinstance(value, bool) or value is None:
        raise InputError(name, f"must be a number or an array of numbers, got {value!r}")
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(name, f"must be a number or an array of numbers, got {value!r}") from None
    return torch.from_numpy(arr).to(torch.float32)


#: Relative slack of a parameter's upper bound: four float32 ulps.
_BOUND_ROUNDING = 4 * 2.0**-23


def _check_param(
    t: torch.Tensor,
    name: str,
    kind: int,
    *,
    lo: float | None = None,
    hi: float | None = None,
    lo_open: bool = False,
) -> None:
    if kind == _COLOR and t.ndim > 0 and t.shape[-1] != 3:
        raise InputError(
            name, f"must be a number or a (..., 3) RGB array, got shape {tuple(t.shape)}"
        )
    if t.numel() == 0:
        return
    with torch.no_grad():
        if not bool(torch.isfinite(t).all()):
            raise InputError(name, "must be finite (found NaN or Inf)")
        vmin, vmax = float(t.min()), float(t.max())
    if lo is not None and (vmin <= lo if lo_open else vmin < lo):
        rel = ">" if lo_open else ">="
        raise InputError(name, f"must be {rel} {lo:g}, got {vmin:g}")
    # an upper bound holds up to float32 rounding: a parameter blended from values at the bound
    # (barycentric weights summing to 1 within an ulp) lands a few ulps above it
    if hi is not None and vmax > hi + _BOUND_ROUNDING * max(abs(hi), 1.0):
        raise InputError(name, f"must be <= {hi:g}, got {vmax:.9g}")


def _broadcasts(a: tuple[int, ...], b: tuple[int, ...]) -> bool:
    try:
        np.broadcast_shapes(a, b)
    except ValueError:
        return False
    return True


def _batch_shape(t: torch.Tensor, kind: int) -> tuple[int, ...]:
    return tuple(t.shape[: max(t.ndim - kind, 0)])


# --------------------------------------------------------------------------------------------
# small vector helpers (local frame: normal = z)


def _dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return (a * b).sum(-1)


def _normalize(v: torch.Tensor) -> torch.Tensor:
    norm = torch.linalg.vector_norm(v, dim=-1, keepdim=True)
    return v / norm.clamp_min(torch.finfo(v.dtype).tiny)


def _reflect(v: torch.Tensor, m: torch.Tensor) -> torch.Tensor:
    """Mirror of ``v`` about the unit vector ``m``: ``2 (v.m) m - v``."""
    return 2 * _dot(v, m).unsqueeze(-1) * m - v


def _cospow(axis: torch.Tensor, w: torch.Tensor, e: torch.Tensor) -> torch.Tensor:
    """``pos(axis.w)^e`` for unit vectors, precise for sharp lobes (large ``e``).

    ``log(axis.w)`` is taken as ``log1p(-|axis - w|^2 / 2)``: near the peak ``1 - axis.w`` is
    tiny and the chord keeps it to full relative precision (the dot product would not).
    """
    c = _dot(axis, w)
    d = axis - w
    h = 0.5 * _dot(d, d)  # 1 - c
    one_minus_eps = 1 - torch.finfo(c.dtype).eps
    h = torch.where(c > 0, h, torch.zeros_like(h)).clamp(max=one_minus_eps)
    val = torch.exp(e * torch.log1p(-h))
    return torch.where(c > 0, val, torch.zeros_like(val))


def _sample_cospow(
    axis: torch.Tensor, e: torch.Tensor, u0: torch.Tensor, u1: torch.Tensor
) -> torch.Tensor:
    """Direction from the density ``(e + 1)/(2 pi) pos(axis.w)^e`` (local coordinates).

    ``1 - cos = 1 - (1 - u0)^(1/(e+1))``, computed with ``expm1``/``log1p`` so that sharp lobes
    keep their width in float32.
    """
    s = -torch.expm1(torch.log1p(-u0) / (e + 1))  # 1 - cos(angle to axis)
    sin = torch.sqrt((s * (2 - s)).clamp_min(0))
    phi = 2 * _PI * u1
    lt, lb, la = frame(axis)
    return (
        (sin * torch.cos(phi)).unsqueeze(-1) * lt
        + (sin * torch.sin(phi)).unsqueeze(-1) * lb
        + (1 - s).unsqueeze(-1) * la
    )


def _choose(
    weights: Sequence[torch.Tensor], u: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Pick an index with probability proportional to ``weights`` (uniform where all are 0).

    Parameters
    ----------
    weights : K tensors (...) >= 0 (broadcast);  u : (...) uniform number

    Returns
    -------
    idx : (...) int64 chosen index;  probs : (K, ...) probabilities;
    u_new : (...) ``u`` stretched from the chosen interval back onto [0, 1)
    """
    w = torch.stack(torch.broadcast_tensors(*weights, u)[:-1]).clamp_min(0)  # (K, ...)
    k = w.shape[0]
    total = w.sum(0, keepdim=True)
    probs = torch.where(total > 0, w / total.clamp_min(torch.finfo(w.dtype).tiny), 1.0 / k)
    cdf = probs.cumsum(0)  # (K, ...)
    u = u.expand(w.shape[1:])
    idx = (u.unsqueeze(0) >= cdf).sum(0).clamp(max=k - 1)  # (...)
    p = probs.gather(0, idx.unsqueeze(0)).squeeze(0)
    lo = (cdf - probs).gather(0, idx.unsqueeze(0)).squeeze(0)
    one_minus = 1 - torch.finfo(u.dtype).eps
    u_new = ((u - lo) / p.clamp_min(torch.finfo(u.dtype).tiny)).clamp(0, one_minus)
    return idx, probs, u_new


def _select(idx: torch.Tensor, options: Sequence[torch.Tensor]) -> torch.Tensor:
    """``options[idx]`` elementwise; ``idx`` is (...) and each option (...) or (..., C)."""
    out = options[0]
    for j in range(1, len(options)):
        opt = options[j]
        mask = idx == j
        if opt.ndim > idx.ndim:
            mask = mask.unsqueeze(-1)
        out = torch.where(mask, opt, out)
    return out


def _rgb(x: torch.Tensor) -> torch.Tensor:
    """``(..., 1)`` (a grey model) -> ``(..., 3)``; ``(..., 3)`` as it is."""
    return x.expand(*x.shape[:-1], 3) if x.shape[-1] == 1 else x


def _mean_color(c: torch.Tensor) -> torch.Tensor:
    """Grey mean of a colour parameter of shape () or (..., 3)."""
    return c if c.ndim == 0 else c.mean(-1)


def _color_as(c: torch.Tensor, batch: tuple[int, ...]) -> torch.Tensor:
    """A colour parameter of shape () / (3,) / (..., 3) expanded to ``(*batch, 3)``."""
    if c.ndim == 0:
        c = c.expand(3)
    return c.expand(*batch, 3)


class _Frame:
    """Orthonormal shading frame ``(t, b, n)``: world <-> local (normal = z)."""

    def __init__(self, n: torch.Tensor, t: torch.Tensor | None):
        if t is None:
            self.t, self.b, self.n = frame(n)
        else:
            # Gram-Schmidt; a tangent (nearly) parallel to n falls back to frame(n)'s tangent
            tp = t - _dot(t, n).unsqueeze(-1) * n
            norm = torch.linalg.vector_norm(tp, dim=-1, keepdim=True)
            tp = tp / norm.clamp_min(torch.finfo(tp.dtype).tiny)
            tp = torch.where(
                norm > _PARALLEL_TANGENT * torch.linalg.vector_norm(t, dim=-1, keepdim=True),
                tp,
                frame(n)[0],
            )
            tp, n = torch.broadcast_tensors(tp, n)
            self.t, self.b, self.n = tp, torch.cross(n, tp, dim=-1), n

    def local(self, v: torch.Tensor) -> torch.Tensor:
        return torch.stack([_dot(v, self.t), _dot(v, self.b), _dot(v, self.n)], -1)

    def world(self, v: torch.Tensor) -> torch.Tensor:
        return v[..., :1] * self.t + v[..., 1:2] * self.b + v[..., 2:] * self.n


def _vec(x: Any, name: str, like: torch.Tensor | None = None) -> torch.Tensor:
    """A direction argument as a floating tensor (numpy keeps its precision, lists -> float32),
    in the dtype and on the device of ``like`` when given."""
    if not isinstance(x, torch.Tensor):
        try:
            x = as_tensor(x)
        except (TypeError, ValueError, RuntimeError):
            raise InputError(name, "must be a (..., 3) array of directions") from None
    if not x.is_floating_point():
        x = x.to(torch.float32 if like is None else like.dtype)
    if like is not None:
        x = x.to(device=like.device, dtype=like.dtype)
    if x.ndim < 1 or x.shape[-1] != 3:
        raise InputError(name, f"must be a (..., 3) array of directions, got {tuple(x.shape)}")
    return x


class CosineLobe(NamedTuple):
    """One lobe of ``f_r(wi, wo) (n.wi)`` as a function of ``wi`` (:meth:`BRDF.cosine_lobes`):
    ``scale pos(axis.wi)^exponent``, times ``pos(n.wi)`` unless ``cosine`` is set.

    Attributes
    ----------
    axis : (..., 3) unit lobe axes;  exponent : (...) ``>= 0``;  scale : (..., 3) RGB factors
    cosine : True where the lobe already is ``f_r (n.wi)`` (the Lambert lobe about the normal,
        exponent 1), False where the cosine factor is still to be multiplied in
    """

    axis: torch.Tensor
    exponent: torch.Tensor
    scale: torch.Tensor
    cosine: bool


# --------------------------------------------------------------------------------------------
# the interface


class BRDF(abc.ABC):
    """A reflectance model: value, sampling density and importance sampling (:mod:`lobelight.brdf`).

    Subclasses implement the ``_eval``, ``_pdf``, ``_albedo_guess`` and ``_sample_dir`` (or
    ``_sample``) hooks in the local frame; the public methods convert frames and enforce the
    one-sided contract. The capabilities (:attr:`isotropic`, :attr:`half_vector_lobe`,
    :attr:`scene_params`, :attr:`sun_model`, :attr:`sun_param`, :meth:`sun_widened`,
    :attr:`fresnel`, :attr:`cosine_lobe_flags`, :meth:`cosine_lobes`, :meth:`mitsuba_dict`)
    answer what the fits, the renderers and the exports need to know of a model; each has a
    default here that means "not supported", which a model overrides where it does better.
    """

    #: The model's name: the ``"type"`` of :meth:`to_dict`, its key in the registry and the
    #: ``model`` of a scene file's material.
    type_name: ClassVar[str] = ""
    #: Whether the lobe is a distribution of half vectors ``h = normalise(wi + wo)`` about the
    #: normal (microfacet-like): the PRT fit then lays its local grid over half vectors, where
    #: such a lobe is round (:func:`lobelight.fit.half_vector_lobes`). False for lobes that
    #: are round in ``wi`` (mirror-symmetric lobes, Lambert).
    half_vector_lobe: ClassVar[bool] = False
    #: The keys a scene file's material gives this model as its specular lobe (the constructor's
    #: arguments) and what each takes: ``"number"`` one number, ``"colour"`` one number (grey)
    #: or an RGB triple, ``"lobes"`` a list of lobe tables (:data:`lobelight.scene.LOBE_PARAMS`).
    #: None: the model is no scene's specular lobe (Lambert is the diffuse part, Sum combines).
    scene_params: ClassVar[Mapping[str, str] | None] = None
    #: The parameter the sun shader reads as its first per-vertex value (``"alpha"`` or
    #: ``"exponent"``; ``lobelight.render._sun_glossy.sun_glossy_vertex_params``); None without
    #: a :attr:`sun_model`.
    sun_param: ClassVar[str | None] = None
    #: Whether the model has a conductor Fresnel term (parameters ``eta`` and ``k``): the sun
    #: shader's ``sun_fresnel``.
    fresnel: bool = False
    #: Whether the model's Fresnel term is Schlick's, ``F0 + (1 - F0) (1 - wo.h)^5`` from its
    #: colour parameter ``f0``: the sun shader's ``sun_fresnel`` 2.
    schlick: ClassVar[bool] = False

    def __init__(self) -> None:
        self._p: dict[str, torch.Tensor] = {}
        self._kind: dict[str, int] = {}

    # ---- parameters -------------------------------------------------------------------------

    def _set(self, name: str, value: Any, kind: int, **limits: Any) -> torch.Tensor:
        t = _as_param(value, name)
        _check_param(t, name, kind, **limits)
        self._p[name] = t
        self._kind[name] = kind
        return t

    def _clamp(self, name: str, *, lo: float | None = None, hi: float | None = None) -> None:
        """Parameter ``name`` clamped into ``[lo, hi]`` (the model's documented range), with one
        ``UserWarning`` naming the value given and the one taken where it was outside."""
        t = self._p[name]
        # the bounds as the parameter's dtype holds them: a float32 1e-4 is a little below it
        lo, hi = (None if b is None else float(torch.tensor(b, dtype=t.dtype)) for b in (lo, hi))
        with torch.no_grad():
            below = lo is not None and float(t.min()) < lo
            above = hi is not None and float(t.max()) > hi
        if not (below or above):
            return
        given, bound = (float(t.min()), lo) if below else (float(t.max()), hi)
        side = "below" if below else "above"
        warnings.warn(
            f"lobelight: {self.type_name} {name} {given:g} is {side} {bound:g}, the sharpest "
            f"lobe lobelight models (a mirror at any image size): taken as {bound:g}",
            UserWarning,
            stacklevel=3,
        )
        self._p[name] = t.clamp(min=lo, max=hi)

    def _batch_shapes(self) -> list[tuple[str, tuple[int, ...]]]:
        """(name, per-element shape) of every parameter."""
        return [(name, _batch_shape(t, self._kind[name])) for name, t in self._p.items()]

    @property
    def per_element_params(self) -> list[str]:
        """The parameters with a per-element dimension (per-vertex materials), a Sum's
        components' included: empty for a material of single values."""
        return [name for name, shape in self._batch_shapes() if shape]

    def _check_shapes(self) -> None:
        """Per-element shapes of all parameters must broadcast together.

        Shapes that broadcast pairwise broadcast together, so one running shape is enough (a
        model of hundreds of parameters, a Lafortune of many lobes, checks in linear time); only
        on a failure are the earlier shapes searched for the one it conflicts with.
        """
        seen: list[tuple[str, tuple[int, ...]]] = []
        joint: tuple[int, ...] = ()
        for name, shape in self._batch_shapes():
            try:
                # numpy's: torch's imports sympy on its first call (a third of a second in
                # every process that reads a model)
                joint = np.broadcast_shapes(joint, shape)
            except ValueError:
                other, oshape = next((o, s) for o, s in seen if not _broadcasts(shape, s))
                raise InputError(
                    name,
                    f"per-element shape {shape} does not broadcast with {other}'s {oshape}",
                ) from None
            seen.append((name, shape))

    def _get(self, name: str, like: torch.Tensor) -> torch.Tensor:
        """Parameter ``name`` in the dtype and on the device of ``like``."""
        return self._p[name].to(device=like.device, dtype=like.dtype)

    @property
    def params(self) -> dict[str, torch.Tensor]:
        """The parameter tensors by name (a new dict; the tensors are shared)."""
        return dict(self._p)

    def _map(self, fn: Callable[[torch.Tensor, int], torch.Tensor]) -> BRDF:
        new = copy.copy(self)
        new._p = {k: fn(v, self._kind[k]) for k, v in self._p.items()}
        new._kind = dict(self._kind)
        return new

    def map_params(self, fn: Callable[[torch.Tensor, int], torch.Tensor]) -> BRDF:
        """A copy with ``fn(tensor, kind)`` applied to every parameter (of every component).

        ``kind`` is the number of trailing non-element dimensions: 0 for scalar parameters,
        1 for colours, so ``tensor.ndim > kind`` means it has per-element dimensions. This is
        the building block of :meth:`take` and :meth:`to`, and of per-point blends of
        per-vertex parameters (e.g. barycentric interpolation).
        """
        return self._map(fn)

    def take(self, index: Any) -> BRDF:
        """The same model with every per-element parameter indexed by ``index``.

        A parameter has a per-element dimension when it has more dimensions than its kind
        (scalar: 0, colour: 1); those are indexed along their first dimension, e.g.
        ``(V,) -> (R,)`` and ``(V, 3) -> (R, 3)`` for ``index`` an ``(R,)`` int64 tensor of
        vertex ids. Scalars and single colours stay as they are.
        """

        def pick(t: torch.Tensor, kind: int) -> torch.Tensor:
            if t.ndim <= kind:
                return t
            ix = index.to(t.device) if isinstance(index, torch.Tensor) else index
            return t[ix]

        return self._map(pick)

    def to(self, device: Any = None, dtype: torch.dtype | None = None) -> BRDF:
        """A copy with every parameter on ``device`` (and of ``dtype`` when given)."""
        return self._map(lambda t, _k: t.to(device=device, dtype=dtype))

    def replace(self, **params: torch.Tensor) -> BRDF:
        """A copy with the named parameters replaced (same kinds; tensors as the others')."""
        for name in params:
            if name not in self._p:
                raise InputError(name, f"{self.type_name} has no parameter {name!r}")
        new = self._map(lambda t, _k: t)
        new._p.update({k: torch.as_tensor(v) for k, v in params.items()})
        return new

    def to_dict(self) -> dict[str, Any]:
        """Plain floats and lists with a ``"type"`` key; :func:`from_dict` reads it back."""
        out: dict[str, Any] = {"type": self.type_name}
        out.update({k: v.detach().cpu().tolist() for k, v in self._p.items()})
        return out

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> BRDF:
        """Build a model from :meth:`to_dict` output (any model when called on ``BRDF``)."""
        model = from_dict(d)
        if cls is not BRDF and not isinstance(model, cls):
            raise InputError("type", f"expected {cls.type_name!r}, got {d.get('type')!r}")
        return model

    @classmethod
    def _from_params(cls, params: dict[str, Any]) -> BRDF:
        """The model from :meth:`to_dict`'s entries besides ``"type"``: the constructor's
        arguments by name, each checked against its signature."""
        kind = cls.type_name
        sig = inspect.signature(cls.__init__).parameters
        allowed = [p for p in sig if p != "self"]
        for key in params:
            if key not in allowed:
                raise InputError(key, f"unknown parameter of {kind} (known: {', '.join(allowed)})")
        for key in allowed:
            if sig[key].default is inspect.Parameter.empty and key not in params:
                raise InputError(key, f"is missing (a {kind} BRDF needs it)")
        return cls(**params)

    def __repr__(self) -> str:
        parts = []
        for k, v in self._p.items():
            parts.append(f"{k}={v.item():g}" if v.numel() == 1 else f"{k}=<{tuple(v.shape)}>")
        return f"{type(self).__name__}({', '.join(parts)})"

    # ---- public evaluation --------------------------------------------------------------------

    def eval(self, wi: Any, wo: Any, n: Any, t: Any = None) -> torch.Tensor:
        """The BRDF value ``f_r(wi, wo)`` (no cosine factor).

        Parameters
        ----------
        wi : (..., 3) unit directions towards the light
        wo : (..., 3) unit directions towards the viewer
        n : (..., 3) unit shading normals
        t : optional (..., 3) tangents (the local x axis of anisotropic models)

        Returns
        -------
        (..., 3) RGB values, 0 where ``n.wi <= 0`` or ``n.wo <= 0``
        """
        wi = _vec(wi, "wi")
        wo, n = _vec(wo, "wo", wi), _vec(n, "n", wi)
        fr = _Frame(n, None if t is None else _vec(t, "t", wi))
        li, lo = fr.local(wi), fr.local(wo)
        f = _rgb(self._eval(li, lo))
        ok = ((li[..., 2] > 0) & (lo[..., 2] > 0)).unsqueeze(-1)
        return torch.where(ok, f, torch.zeros_like(f))

    def pdf(self, wi: Any, wo: Any, n: Any, t: Any = None) -> torch.Tensor:
        """Solid-angle density with which :meth:`sample` returns ``wi`` given ``wo``.

        Parameters
        ----------
        wi, wo, n, t : as in :meth:`eval`

        Returns
        -------
        (...) density per steradian, 0 where ``n.wi <= 0`` or ``n.wo <= 0`` (samples that
        would land there are returned with weight 0, so the density integrates to at most 1
        over the upper hemisphere)
        """
        wi = _vec(wi, "wi")
        wo, n = _vec(wo, "wo", wi), _vec(n, "n", wi)
        fr = _Frame(n, None if t is None else _vec(t, "t", wi))
        li, lo = fr.local(wi), fr.local(wo)
        p = self._pdf(li, lo)
        ok = (li[..., 2] > 0) & (lo[..., 2] > 0) & torch.isfinite(p)
        return torch.where(ok, p, torch.zeros_like(p))

    def sample(
        self, wo: Any, n: Any, u: Any, t: Any = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Importance-sample a light direction ``wi`` for the viewer direction ``wo``.

        Parameters
        ----------
        wo : (..., 3) unit directions towards the viewer;  n : (..., 3) unit normals
        u : (..., 2) or (..., 3) uniform numbers in [0, 1) (the third, when given, is used by
            models that choose a lobe or component; see :mod:`lobelight.brdf`)
        t : optional (..., 3) tangents

        Returns
        -------
        wi : (..., 3) unit sampled directions (finite; the normal where none could be formed);
        weight : (..., 3) ``f(wi, wo) max(n.wi, 0) / pdf``, 0 for an invalid sample (below the
        surface, or ``n.wo <= 0``);  pdf : (...) solid-angle density of ``wi``, 0 for an invalid
        sample
        """
        wo = _vec(wo, "wo")
        n = _vec(n, "n", wo)
        u = torch.as_tensor(u) if not isinstance(u, torch.Tensor) else u
        u = u.to(device=wo.device, dtype=wo.dtype)
        if u.ndim < 1 or u.shape[-1] not in (2, 3):
            raise InputError("u", f"must be a (..., 2) or (..., 3) array, got {tuple(u.shape)}")
        fr = _Frame(n, None if t is None else _vec(t, "t", wo))
        lo = fr.local(wo)
        li, weight, pdf = self._sample(lo, u)
        weight = _rgb(weight)
        ok = (
            (lo[..., 2] > 0)
            & (li[..., 2] > 0)
            & (pdf > 0)
            & torch.isfinite(pdf)
            & torch.isfinite(weight).all(-1)
        )
        zhat = torch.zeros_like(li)
        zhat[..., 2] = 1
        li = torch.where(torch.isfinite(li).all(-1, keepdim=True), li, zhat)
        weight = torch.where(ok.unsqueeze(-1), weight, torch.zeros_like(weight))
        pdf = torch.where(ok, pdf, torch.zeros_like(pdf))
        return fr.world(li), weight, pdf

    # ---- hooks (local frame; values where z <= 0 are masked by the callers) -----------------

    @abc.abstractmethod
    def _eval(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        """(..., 3) BRDF value for local directions (may be garbage below the horizon)."""

    @abc.abstractmethod
    def _pdf(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        """(...) sampling density for local directions."""

    def _sample_dir(self, wo: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """(..., 3) sampled local direction; used by the default :meth:`_sample`."""
        raise NotImplementedError

    def _sample(
        self, wo: torch.Tensor, u: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Sampled local ``wi``, its weight ``f cos / pdf`` and its density."""
        wi = self._sample_dir(wo, u)
        pdf = self._pdf(wi, wo)
        f = self._eval(wi, wo)
        weight = (
            f * (wi[..., 2].clamp_min(0) / pdf.clamp_min(torch.finfo(pdf.dtype).tiny))[..., None]
        )
        return wi, weight, pdf

    @abc.abstractmethod
    def _albedo_guess(self, wo: torch.Tensor) -> torch.Tensor:
        """(...) cheap estimate of the directional albedo (grey), for choosing in a Sum."""

    # ---- capabilities (what other packages ask a model; defaults: not supported) ----------

    @property
    def isotropic(self) -> bool:
        """Whether the model is invariant under rotations about the normal (its lobes depend
        on the view's elevation only), for these parameter values.

        The SG-BRDF fit then needs views in one plane only (``lobelight.sgbrdf``). The default,
        False, is always safe: the fit then takes views all around the normal.
        """
        return False

    @property
    def sun_model(self) -> int | None:
        """The sun shader's formula for this model (``sun_model`` in ``prt.glsl``: 0 GGX,
        1 Beckmann, 2 modified Phong, 3 Blinn-Phong), or None where the shader has none: the
        renderers then leave the sun in the Gaussians' lighting (``lobelight.render``)."""
        return None

    def sun_widened(self, spread: float) -> BRDF:
        """A copy whose lobe is widened by a sun disc of RMS angle ``spread`` radians, for the
        sun shader (a model with a :attr:`sun_model`); ``self`` for ``spread <= 0``.

        The lobe's and the disc's angular variances add, and the lobe stays normalised, so the
        highlight keeps its light and takes the disc's size (``lobelight.render._sun_glossy``).

        Raises
        ------
        InputError
            for ``spread > 0`` on a model without a :attr:`sun_model`
        """
        if spread <= 0.0:
            return self
        if self.sun_model is None:
            raise InputError("brdf", f"{self.type_name} has no sun shading to widen")
        return self._sun_widened(spread * spread)

    def _sun_widened(self, spread2: float) -> BRDF:
        """:meth:`sun_widened` for ``spread2 = spread^2 > 0``."""
        raise NotImplementedError

    @property
    def cosine_lobe_flags(self) -> tuple[bool, ...] | None:
        """Per lobe of :meth:`cosine_lobes`, in order, its ``cosine`` flag: True where the lobe
        already is ``f_r (n.wi)``; None where the model is not a sum of cosine lobes. The
        cosine-lobe shader counts its lobes and cosine products from it (``lobelight.cosine``).
        """
        return None

    def cosine_lobes(self, wo: Any, n: Any, t: Any = None) -> list[CosineLobe] | None:
        """``f_r(wi, wo) (n.wi)`` as a function of ``wi``: a sum of cosine lobes
        ``scale pos(axis.wi)^exponent``, each times ``pos(n.wi)`` unless its ``cosine`` flag is
        set (:class:`CosineLobe`); None where the model is not such a sum (the default).

        Parameters
        ----------
        wo : (..., 3) unit directions towards the viewer;  n : (..., 3) unit normals
        t : optional (..., 3) tangents (the local x axis of anisotropic lobes)

        Returns
        -------
        list of :class:`CosineLobe` with axis (..., 3) in the world frame, exponent (...) and
        scale (..., 3), ``...`` the directions' batch shape (the lobes are not masked where
        ``n.wo <= 0``: the caller does)
        """
        wo = _vec(wo, "wo")
        n = _vec(n, "n", wo)
        fr = _Frame(n, None if t is None else _vec(t, "t", wo))
        lobes = self._cosine_lobes(fr.local(wo))
        if lobes is None:
            return None
        return [CosineLobe(fr.world(a), e, s, cos) for a, e, s, cos in lobes]

    def _cosine_lobes(self, wo: torch.Tensor) -> list[CosineLobe] | None:
        """:meth:`cosine_lobes` in the local frame: ``wo`` (..., 3) local, axes local."""
        return None

    def mitsuba_dict(self) -> dict[str, Any]:
        """The Mitsuba 3 BSDF that is this model, as a ``mi.load_dict`` entry of plain values
        (``lobelight.reference.mitsuba``), for a model with one value per parameter (the first
        element is taken).

        Raises
        ------
        InputError
            naming ``materials`` where Mitsuba has no exact counterpart (the default): a
            reference would then render another material
        """
        raise InputError("materials", f"{self.type_name} has no Mitsuba counterpart")


# --------------------------------------------------------------------------------------------
# sums


class Sum(BRDF):
    """The sum of BRDFs, e.g. ``Sum(Lambert(0.5), GGX(0.2))``; sampled as a mixture.

    Component ``j`` is chosen with probability ``w_j / sum(w)`` per element, where ``w_j`` is
    the component's albedo estimate for ``wo`` (:mod:`lobelight.brdf`); uses ``u[..., 2]`` for the
    choice when given, else reuses ``u[..., 0]``.

    Parameters
    ----------
    *brdfs : at least one BRDF (nested sums are flattened)
    """

    type_name = "sum"

    def __init__(self, *brdfs: BRDF):
        super().__init__()
        flat: list[BRDF] = []
        for j, b in enumerate(brdfs):
            if isinstance(b, Sum):
                flat.extend(b.components)
            elif isinstance(b, BRDF):
                flat.append(b)
            else:
                raise InputError(f"components[{j}]", f"must be a BRDF, got {type(b).__name__}")
        if not flat:
            raise InputError("components", "a Sum needs at least one BRDF")
        self.components: tuple[BRDF, ...] = tuple(flat)
        # per-element parameters of all components must broadcast together
        self._check_shapes()

    def _batch_shapes(self) -> list[tuple[str, tuple[int, ...]]]:
        return [
            (f"components[{j}].{name}", shape)
            for j, c in enumerate(self.components)
            for name, shape in c._batch_shapes()
        ]

    @property
    def params(self) -> dict[str, torch.Tensor]:
        out = {}
        for j, c in enumerate(self.components):
            out.update({f"components[{j}].{k}": v for k, v in c.params.items()})
        return out

    def _map(self, fn):
        new = copy.copy(self)
        new.components = tuple(c._map(fn) for c in self.components)
        return new

    def to_dict(self) -> dict[str, Any]:
        return {"type": self.type_name, "components": [c.to_dict() for c in self.components]}

    @classmethod
    def _from_params(cls, params: dict[str, Any]) -> BRDF:
        comps = params.pop("components")
        if params:
            raise InputError(sorted(params)[0], "unknown parameter of a sum")
        if not isinstance(comps, Sequence) or isinstance(comps, str):
            raise InputError("components", "a sum needs a list of components")
        return Sum(*(from_dict(c) for c in comps))

    def __repr__(self) -> str:
        return f"Sum({', '.join(repr(c) for c in self.components)})"

    def _eval(self, wi, wo):
        f = None
        for c in self.components:
            fj = c._eval(wi, wo)
            f = fj if f is None else f + fj
        return f

    def _probs(self, wo: torch.Tensor, u: torch.Tensor):
        return _choose([c._albedo_guess(wo) for c in self.components], u)

    def _pdf_mix(self, wi, wo, probs) -> torch.Tensor:
        pdf = None
        for j, c in enumerate(self.components):
            pj = probs[j] * torch.nan_to_num(c._pdf(wi, wo), nan=0.0, posinf=0.0)
            pdf = pj if pdf is None else pdf + pj
        return pdf

    def _pdf(self, wi, wo):
        _, probs, _ = self._probs(wo, torch.zeros_like(wo[..., 2]))
        return self._pdf_mix(wi, wo, probs)

    def _sample(self, wo, u):
        uc = u[..., 2] if u.shape[-1] == 3 else u[..., 0]
        idx, probs, u_new = self._probs(wo, uc)
        u0 = (u[..., 0] if u.shape[-1] == 3 else u_new).expand(idx.shape)
        u2 = torch.stack([u0, u[..., 1].expand(idx.shape)], -1)
        cands = [c._sample(wo, u2)[0] for c in self.components]
        wi = _select(idx, cands)
        pdf = self._pdf_mix(wi, wo, probs)
        f = self._eval(wi, wo)
        tiny = torch.finfo(pdf.dtype).tiny
        weight = f * (wi[..., 2].clamp_min(0) / pdf.clamp_min(tiny)).unsqueeze(-1)
        return wi, weight, pdf

    def _albedo_guess(self, wo):
        return torch.stack(
            torch.broadcast_tensors(*[c._albedo_guess(wo) for c in self.components])
        ).sum(0)

    # ---- capabilities: those its components share -------------------------------------------

    @property
    def isotropic(self) -> bool:
        return all(c.isotropic for c in self.components)

    @property
    def cosine_lobe_flags(self) -> tuple[bool, ...] | None:
        flags = [c.cosine_lobe_flags for c in self.components]
        if any(f is None for f in flags):
            return None
        return tuple(flag for f in flags for flag in f)

    def _cosine_lobes(self, wo):
        lobes = []
        for c in self.components:
            lc = c._cosine_lobes(wo)
            if lc is None:
                return None
            lobes += lc
        return lobes


# --------------------------------------------------------------------------------------------
# (de)serialisation


_REGISTRY: dict[str, type[BRDF]] = {}
#: The registered models by ``type`` name, in the order they were registered (read-only: add
#: one with :func:`register`).
REGISTRY: Mapping[str, type[BRDF]] = types.MappingProxyType(_REGISTRY)


def register(cls: type[BRDF]) -> type[BRDF]:
    """Register a model under its :attr:`~BRDF.type_name` (a class decorator too).

    :func:`from_dict` then builds it, and a scene file's material may name it when it has
    :attr:`~BRDF.scene_params`. Registering the same class again changes nothing.

    Raises
    ------
    InputError
        naming ``type_name`` for a class that is no BRDF, has no name, or takes the name of
        another registered class
    """
    if not (isinstance(cls, type) and issubclass(cls, BRDF)):
        raise InputError("type_name", f"only BRDF classes are registered, got {cls!r}")
    name = cls.type_name
    if not name or not isinstance(name, str):
        raise InputError("type_name", f"{cls.__name__} needs a type_name to be registered")
    other = _REGISTRY.get(name)
    if other is not None and other is not cls:
        raise InputError("type_name", f"{name!r} is taken by {other.__module__}.{other.__name__}")
    _REGISTRY[name] = cls
    return cls


def from_dict(d: Mapping[str, Any]) -> BRDF:
    """Build a BRDF from :meth:`BRDF.to_dict` output (plain floats and lists).

    Parameters
    ----------
    d : mapping with ``"type"`` (a registered model's name: lambert, phong, blinn_phong,
        ward, lafortune, ggx, beckmann, sum, ...) and that model's constructor arguments by
        name; a sum has ``"components"``, a list of such mappings

    Raises
    ------
    InputError
        naming the key for an unknown type, an unknown or missing parameter, or a bad value
    """
    if not isinstance(d, Mapping):
        raise InputError("brdf", f"must be a mapping with a 'type' key, got {type(d).__name__}")
    kind = d.get("type")
    if kind not in _REGISTRY:
        raise InputError("type", f"unknown BRDF type {kind!r}; known: {', '.join(_REGISTRY)}")
    return _REGISTRY[kind]._from_params({k: v for k, v in d.items() if k != "type"})
