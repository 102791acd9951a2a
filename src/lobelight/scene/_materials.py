"""Per-vertex materials: a Lambert diffuse albedo plus one specular lobe with per-vertex parameters.

A material here is ``f = diffuse / pi + f_spec`` where ``f_spec`` is one of the specular models of
:mod:`lobelight.brdf` (phong, blinn_phong, ward, lafortune, ggx, beckmann) whose colour and
shape parameters may differ per vertex. One specular *model* per scene keeps the transport and
the fit vectorised (every vertex evaluates the same formula); the parameters carry the spatial
variation, e.g. the paper's bird that goes from diffuse yellow to highly specular green is a
gradient of ``diffuse``, ``specular`` and ``exponent`` of one Phong model.

Material specs (scene files, built-ins) are plain mappings::

    {"diffuse": [0.7, 0.6, 0.1], "model": "ggx", "specular": [0.9, 0.9, 0.9], "alpha": 0.05}

``model`` may be omitted (or "none") for a purely diffuse material. A gradient blends two specs
along a direction: colours linearly, positive shape parameters (exponents, roughness)
geometrically, which is how their perceived sharpness changes.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import torch

from .. import brdf as _brdf
from ..errors import InputError

__all__ = ["SPECULAR_MODELS", "Materials", "gradient", "uniform"]

#: Specular models a material may use (keys of :func:`lobelight.brdf.from_dict`).
SPECULAR_MODELS = ("phong", "blinn_phong", "ward", "lafortune", "ggx", "beckmann")
#: Parameters interpolated geometrically in a gradient (all others linearly).
_GEOMETRIC = {"exponent", "alpha", "alpha_u", "alpha_v", "alpha_x", "alpha_y"}


@dataclass(eq=False)
class Materials:
    """Materials of every vertex.

    Attributes
    ----------
    diffuse : (V, 3) float32 Lambert albedo in [0, 1]
    specular : BRDF or None, one specular model; each parameter is a scalar, a colour, or has a
        leading per-vertex dimension ``V``
    """

    diffuse: torch.Tensor
    specular: _brdf.BRDF | None = None

    @property
    def n_vertices(self) -> int:
        return int(self.diffuse.shape[0])

    @property
    def model(self) -> str:
        return self.specular.type_name if self.specular is not None else "none"

    def take(self, index: torch.Tensor) -> Materials:
        """Materials of the vertices ``index`` (or of points with interpolated parameters)."""
        spec = self.specular.take(index) if self.specular is not None else None
        return Materials(self.diffuse[index.to(self.diffuse.device)], spec)

    def interpolate(self, vidx: torch.Tensor, bary: torch.Tensor) -> Materials:
        """Barycentric blend of the materials of triangle corners, for points inside triangles.

        Parameters
        ----------
        vidx : (..., 3) int64 corner vertices;  bary : (..., 3) weights
        """
        w = bary.to(self.diffuse.dtype)
        diffuse = (self.diffuse[vidx] * w[..., None]).sum(-2)
        spec = None
        if self.specular is not None:

            def blend(t: torch.Tensor, kind: int) -> torch.Tensor:
                if t.ndim <= kind:
                    return t
                wt = w.to(t.device, t.dtype).reshape(*w.shape, *([1] * kind))
                return (t[vidx.to(t.device)] * wt).sum(w.ndim - 1)

            spec = self.specular.map_params(blend)
        return Materials(diffuse, spec)

    def brdf(self) -> _brdf.BRDF:
        """The full BRDF ``Lambert(diffuse) + specular`` (for path tracing and references)."""
        lam = _brdf.Lambert(self.diffuse)
        return lam if self.specular is None else _brdf.Sum(lam, self.specular)

    def to(self, device) -> Materials:
        spec = self.specular.to(device) if self.specular is not None else None
        return Materials(self.diffuse.to(device), spec)

    def to_dict(self) -> dict[str, Any]:
        return {
            "diffuse": self.diffuse.detach().cpu().tolist(),
            "specular": None if self.specular is None else self.specular.to_dict(),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], n_vertices: int) -> Materials:
        """Inverse of :meth:`to_dict`: ``diffuse`` one RGB triple or ``(n_vertices, 3)``.

        Raises
        ------
        InputError
            naming the entry that is not a mapping, not colours, or not a BRDF.
        """
        if not isinstance(d, Mapping):
            raise InputError("materials", f"must be a mapping, got {type(d).__name__}")
        diffuse = _colour(d.get("diffuse"), "diffuse")
        if diffuse.shape not in ((3,), (n_vertices, 3)):
            raise InputError(
                "diffuse", f"must be (3,) or ({n_vertices}, 3), got {tuple(diffuse.shape)}"
            )
        spec = d.get("specular")
        try:
            spec_brdf = None if spec is None else _brdf.from_dict(spec)
        except InputError as exc:
            raise InputError(f"specular.{exc.what}", exc.problem) from None
        except (KeyError, TypeError, ValueError, OverflowError) as exc:  # keys or values amiss
            raise InputError("specular", f"not a BRDF description ({exc!r:.80})") from None
        return cls(diffuse.expand(n_vertices, 3).contiguous(), spec_brdf)


def _colour(value: Any, name: str) -> torch.Tensor:
    try:
        t = torch.as_tensor(value if value is not None else [0.0, 0.0, 0.0], dtype=torch.float32)
    except (TypeError, ValueError, RuntimeError, OverflowError):  # strings, ragged lists, 1e400
        raise InputError(name, f"must be an RGB triple of numbers, got {value!r:.60}") from None
    if t.ndim == 0:
        t = t.expand(3)
    if t.shape[-1] != 3:
        raise InputError(name, f"must be an RGB triple, got shape {tuple(t.shape)}")
    if not bool(torch.isfinite(t).all()) or float(t.min()) < 0 or float(t.max()) > 1:
        raise InputError(name, f"colour values must be in [0, 1], got {t.tolist()!s:.80}")
    return t


def _split_spec(spec: Mapping[str, Any], name: str) -> tuple[torch.Tensor, str, dict[str, Any]]:
    if not isinstance(spec, Mapping):
        raise InputError(name, f"a material must be a table of values, got {type(spec).__name__}")
    spec = dict(spec)
    diffuse = _colour(spec.pop("diffuse", None), f"{name}.diffuse")
    if diffuse.ndim != 1:
        shape = tuple(diffuse.shape)
        raise InputError(f"{name}.diffuse", f"must be one RGB triple, got shape {shape}")
    model = str(spec.pop("model", "none")).lower()
    if model != "none" and model not in SPECULAR_MODELS:
        raise InputError(f"{name}.model", f"unknown model {model!r}; use one of {SPECULAR_MODELS}")
    if model == "none" and spec:
        raise InputError(f"{name}.{sorted(spec)[0]}", "given without a specular model")
    return diffuse, model, spec


def _make(model: str, params: Mapping[str, Any], name: str) -> _brdf.BRDF:
    try:
        return _brdf.from_dict({"type": model, **params})
    except InputError as exc:
        raise InputError(f"{name}.{exc.what}", exc.problem) from None
    except OverflowError as exc:  # an integer beyond the float range, e.g. exponent = 1e400
        raise InputError(name, f"a parameter is out of range ({exc})") from None


def uniform(spec: Mapping[str, Any], n_vertices: int, *, name: str = "material") -> Materials:
    """One material on every vertex."""
    diffuse, model, params = _split_spec(spec, name)
    spec_brdf = None if model == "none" else _make(model, params, name)
    return Materials(diffuse.expand(n_vertices, 3).contiguous(), spec_brdf)


def gradient(
    a: Mapping[str, Any], b: Mapping[str, Any], t: torch.Tensor, *, name: str = "gradient"
) -> Materials:
    """Per-vertex blend from material ``a`` (``t = 0``) to material ``b`` (``t = 1``).

    Both must use the same specular model, or one of them none (it then gets the other's model
    with a black specular colour and the other's shape).

    Parameters
    ----------
    t : (V,) blend weights in [0, 1]
    """
    da, ma, pa = _split_spec(a, f"{name}.from")
    db, mb, pb = _split_spec(b, f"{name}.to")
    if "none" not in (ma, mb) and ma != mb:
        raise InputError(name, f"both ends need the same specular model, got {ma} and {mb}")
    t = t.to(torch.float32).clamp(0, 1)
    diffuse = (1 - t[:, None]) * da + t[:, None] * db
    model = mb if ma == "none" else ma
    if model == "none":
        return Materials(diffuse, None)
    if model == "lafortune":
        raise InputError(name, "gradients of Lafortune lobes are not supported; use uniform")
    # a missing end takes the other's shape with no specular colour
    pa = {**pb, "specular": [0.0] * 3} if ma == "none" else pa
    pb = {**pa, "specular": [0.0] * 3} if mb == "none" else pb
    # validate each end on its own first: errors then name the end and the parameter
    _make(model, pa, f"{name}.from")
    _make(model, pb, f"{name}.to")
    params: dict[str, Any] = {}
    for key in sorted(set(pa) | set(pb)):
        if key not in pa or key not in pb:
            raise InputError(f"{name}.{key}", "must be given at both ends of a gradient")
        va = torch.as_tensor(pa[key], dtype=torch.float32)
        vb = torch.as_tensor(pb[key], dtype=torch.float32)
        tt = t.reshape(-1, *([1] * va.ndim))
        if key in _GEOMETRIC:
            params[key] = torch.exp(
                (1 - tt) * va.clamp_min(1e-12).log() + tt * vb.clamp_min(1e-12).log()
            )
        else:
            params[key] = (1 - tt) * va + tt * vb
    return Materials(diffuse, _make(model, params, name))
