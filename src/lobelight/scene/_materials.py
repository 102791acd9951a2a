"""Per-vertex materials: a Lambert diffuse albedo plus one specular lobe with per-vertex parameters.

A material here is ``f = diffuse / pi + f_spec`` where ``f_spec`` is one of the specular models of
:mod:`lobelight.brdf` (:data:`SPECULAR_MODELS`, the registered models with
:attr:`~lobelight.brdf.BRDF.scene_params`: phong, blinn_phong, ward, lafortune, ggx, beckmann,
ggx_schlick)
whose colour and shape parameters may differ per vertex. One specular *model* per scene keeps
the transport and the fit vectorised (every vertex evaluates the same formula); the parameters
carry the spatial variation, e.g. the paper's bird that goes from diffuse yellow to highly
specular green is a gradient of ``diffuse``, ``specular`` and ``exponent`` of one Phong model.

Material specs (scene files, built-ins) are plain mappings::

    {"diffuse": [0.7, 0.6, 0.1], "model": "ggx", "specular": [0.9, 0.9, 0.9], "alpha": 0.05}

``model`` may be omitted (or "none") for a purely diffuse material; :data:`MODEL_PARAMS` lists
the other keys of each model. A gradient blends two specs along a direction: colours linearly,
positive shape parameters (exponents, roughness) geometrically, which is how their perceived
sharpness changes. :func:`parse_material` reads the same spec from a one-line string (a bare
mesh's ``--material``), e.g. ``"ggx:alpha=0.1,specular=0.04,diffuse=0.5,0.5,0.5"``.

A glTF 2.0 metallic-roughness material (base colour, metallic, roughness, per vertex) is the
Lambert albedo ``base_color (1 - metallic)`` plus the ``ggx_schlick`` lobe with
``alpha = roughness^2`` and ``f0 = mix(0.04, base_color, metallic)``
(:func:`lobelight.brdf.metallic_roughness`); :func:`gltf_materials` builds it.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from .. import brdf as _brdf
from .._tol import SMALL
from ..errors import InputError

__all__ = [
    "LOBE_PARAMS",
    "MODEL_PARAMS",
    "SPECULAR_MODELS",
    "Materials",
    "gltf_materials",
    "gradient",
    "material_table",
    "parse_material",
    "uniform",
]

_NUMBER, _COLOUR, _LOBES = "number", "colour", "lobes"


def _specular_classes() -> dict[str, type[_brdf.BRDF]]:
    """The registered models a material may use as its specular lobe, by name."""
    return {n: c for n, c in _brdf.REGISTRY.items() if c.scene_params is not None}


class _SpecularModels(Sequence[str]):
    """The names of :func:`_specular_classes`, read from the registry at each use (a model
    registered later is a specular model too)."""

    def __getitem__(self, index):
        return tuple(_specular_classes())[index]

    def __len__(self) -> int:
        return len(_specular_classes())

    def __iter__(self) -> Iterator[str]:
        return iter(tuple(_specular_classes()))

    def __contains__(self, name: object) -> bool:
        return name in _specular_classes()

    def __repr__(self) -> str:
        return repr(tuple(_specular_classes()))


class _ModelParams(Mapping[str, Mapping[str, str]]):
    """Each specular model's :attr:`~lobelight.brdf.BRDF.scene_params`, read from the registry
    at each use."""

    def __getitem__(self, name: str) -> Mapping[str, str]:
        return _specular_classes()[name].scene_params

    def __iter__(self) -> Iterator[str]:
        return iter(tuple(_specular_classes()))

    def __len__(self) -> int:
        return len(_specular_classes())

    def __repr__(self) -> str:
        return repr(dict(self))


#: Specular models a material may use: the registered models of :mod:`lobelight.brdf` with
#: :attr:`~lobelight.brdf.BRDF.scene_params` (a read-only sequence of their names, in the
#: registry's order; a model registered later is in it).
SPECULAR_MODELS: Sequence[str] = _SpecularModels()
#: The keys of a material spec besides ``diffuse`` and ``model``, per specular model (the
#: arguments of its :mod:`lobelight.brdf` constructor, its
#: :attr:`~lobelight.brdf.BRDF.scene_params`), and what each takes: ``"number"`` one number,
#: ``"colour"`` one number (grey) or an RGB triple, ``"lobes"`` a list of :data:`LOBE_PARAMS`
#: tables. A read-only mapping over :data:`SPECULAR_MODELS`.
MODEL_PARAMS: Mapping[str, Mapping[str, str]] = _ModelParams()
#: The keys of one Lafortune lobe and what each takes (as :data:`MODEL_PARAMS`).
LOBE_PARAMS = {"cx": _NUMBER, "cy": _NUMBER, "cz": _NUMBER, "exponent": _NUMBER, "rho": _COLOUR}
#: Names a material spec string may give for a material with no specular lobe.
_DIFFUSE_MODELS = ("diffuse", "none")
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
    if model != "none":
        _check_counts(spec, MODEL_PARAMS[model], name, model)
        lobes = spec.get("lobes")
        if isinstance(lobes, Sequence) and not isinstance(lobes, str):
            for j, lobe in enumerate(lobes):
                if isinstance(lobe, Mapping):  # other shapes: the BRDF names the problem
                    _check_counts(lobe, LOBE_PARAMS, f"{name}.lobes[{j}]", "a lobe")
    return diffuse, model, spec


def _shape(value: Any) -> tuple[int, ...] | None:
    """The array shape of a number, list or array; None for what is neither (left to the BRDF
    to name), without converting values (an integer beyond the float range stays one)."""
    if isinstance(value, torch.Tensor | np.ndarray):
        return tuple(value.shape)
    if isinstance(value, str | bytes | Mapping):
        return None
    if isinstance(value, Sequence):
        if not value:
            return (0,)
        inner = {_shape(v) for v in value}
        return (len(value), *inner.pop()) if len(inner) == 1 and None not in inner else None
    return ()


def _check_counts(params: Mapping[str, Any], known: Mapping[str, str], name: str, of: str) -> None:
    """Every key of ``params`` is one of ``known`` and holds one number (or RGB triple)."""
    for key, value in params.items():
        if key not in known:
            raise InputError(
                f"{name}.{key}", f"is not a parameter of {of} (known: {', '.join(known)})"
            )
        shape, kind = _shape(value), known[key]
        if shape is None or kind == _LOBES:
            continue
        if kind == _NUMBER and shape != ():
            raise InputError(f"{name}.{key}", f"takes one number, got {_count(shape)}")
        if kind == _COLOUR and shape not in ((), (3,)):
            raise InputError(
                f"{name}.{key}", f"takes one number or an RGB triple, got {_count(shape)}"
            )


def _count(shape: tuple[int, ...]) -> str:
    return f"{shape[0]} values" if len(shape) == 1 else f"an array of shape {shape}"


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


def gltf_materials(
    base_color: Any, metallic: Any, roughness: Any, n_vertices: int | None = None
) -> Materials:
    """The materials of glTF 2.0 metallic-roughness factors (module docstring): Lambert
    ``base_color (1 - metallic)`` plus :class:`lobelight.brdf.GGXSchlick` with
    ``alpha = roughness^2`` and ``f0 = mix(0.04, base_color, metallic)``.

    Parameters
    ----------
    base_color : (3,) or (V, 3) linear RGB in [0, 1] (the factor times the decoded texture
        and vertex colour at each vertex)
    metallic, roughness : () or (V,) in [0, 1]
    n_vertices : the vertex count ``V``; needed only when every factor is one value

    Raises
    ------
    InputError
        naming the factor that is out of range, not finite or of another vertex count
    """
    diffuse, spec = _brdf.metallic_roughness(base_color, metallic, roughness)
    counts: dict[str, int] = {}
    for name, value, kind in (
        ("base_color", base_color, 1),
        ("metallic", metallic, 0),
        ("roughness", roughness, 0),
    ):
        shape = tuple(torch.as_tensor(value).shape)
        batch = shape[: max(len(shape) - kind, 0)]
        if len(batch) > 1:
            what = "(V, 3)" if kind else "(V,)"
            raise InputError(name, f"must be one value or {what}, got shape {shape}")
        if batch:
            counts[name] = batch[0]
    v = n_vertices if n_vertices is not None else next(iter(counts.values()), None)
    if v is None:
        raise InputError("n_vertices", "is needed when every factor is one value")
    for name, count in counts.items():
        if count != v:
            raise InputError(name, f"has {count} vertices, expected {v}")
    return Materials(diffuse.expand(v, 3).contiguous(), spec)


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
    if _LOBES in MODEL_PARAMS[model].values():
        raise InputError(name, f"gradients of {model} lobes are not supported; use uniform")
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
                (1 - tt) * va.clamp_min(SMALL).log() + tt * vb.clamp_min(SMALL).log()
            )
        else:
            params[key] = (1 - tt) * va + tt * vb
    return Materials(diffuse, _make(model, params, name))


# --------------------------------------------------------------------------------------------
# one-line material specs


def material_table(spec: str, *, what: str = "--material") -> dict[str, Any]:
    """The material table (as a scene file's ``[material]``) that a one-line spec stands for.

    ``spec`` is ``[MODEL:]KEY=VALUES,KEY=VALUES,...`` where ``VALUES`` is one number or several
    separated by commas (a comma followed by a number continues the previous key). ``MODEL`` is
    a specular model of :data:`SPECULAR_MODELS`, or ``diffuse`` / ``none`` for no specular lobe
    (then ``color`` is another name for ``diffuse``); without it the spec may name it as
    ``model=NAME`` and is diffuse otherwise. A bare ``MODEL`` takes that model's defaults. The
    keys are those of :data:`MODEL_PARAMS` plus ``diffuse``; a Lafortune lobe is
    ``lobe=cx,cy,cz,exponent,rho`` (7 numbers for an RGB ``rho``), once per lobe. Examples::

        "ggx:alpha=0.05,specular=0.9,0.8,0.6"      -> a coloured GGX metal (black diffuse)
        "ggx:alpha=0.1,specular=0.04,diffuse=0.5"   -> grey plastic
        "diffuse=0.7,0.7,0.7" or "diffuse:color=0.7" -> Lambert only
        "phong:exponent=100,specular=0.5,diffuse=0.2,0.3,0.6"
        "lafortune:diffuse=0.3,lobe=-1,-1,1,30,0.6,lobe=0,0,1,5,0.05"

    Values are checked by :func:`parse_material` (or :func:`uniform`), as a scene file's are;
    here only the syntax, the model and the keys are.

    Raises
    ------
    InputError
        naming ``what`` for an empty spec, an unknown model or key, a repeated key, a value
        that is not a number, or a lobe without 5 or 7 numbers.
    """
    if not isinstance(spec, str):
        raise InputError(what, f"must be a string, got {type(spec).__name__}")
    text = spec.strip()
    if not text:
        raise InputError(what, "is empty; give e.g. 'ggx:alpha=0.1,diffuse=0.5'")
    model, body = _split_model(text)
    items = _spec_items(body, what) if body.strip() else {}
    model, known_keys = _spec_model(model, items, what)
    for key in items:
        if key not in known_keys:
            of = "a diffuse material" if model == "none" else model
            raise InputError(
                what, f"unknown key {key!r} for {of} (known: {', '.join(sorted(known_keys))})"
            )
    if "color" in items:  # the diffuse model's one colour
        if "diffuse" in items:
            raise InputError(what, "gives both color and diffuse")
        items["diffuse"] = items.pop("color")
    table: dict[str, Any] = {}
    if "diffuse" in items:
        table["diffuse"] = _one_or_list(items.pop("diffuse"))
    if model != "none":
        table["model"] = model
    lobes = items.pop("lobe", None)
    if lobes is not None:
        table["lobes"] = [_lobe(v, j, what) for j, v in enumerate(lobes)]
    table.update({k: _one_or_list(v) for k, v in items.items()})
    return table


def _split_model(text: str) -> tuple[str, str]:
    """A spec's ``MODEL`` (lower case; empty when it names none) and its ``KEY=VALUES`` part."""
    head, colon, rest = text.partition(":")
    if colon and "=" not in head:  # MODEL:KEY=VALUES,...
        return head.strip().lower(), rest
    if "=" in text:  # KEY=VALUES,...
        return "", text
    return text.lower(), ""  # a bare model name


def _spec_model(model: str, items: dict[str, Any], what: str) -> tuple[str, set[str]]:
    """The spec's model (``"none"`` for a diffuse one), taking a ``model=`` item out of
    ``items``, and the keys that model takes."""
    if "model" in items:
        given = items.pop("model")
        if model and given != model:
            raise InputError(what, f"names the model twice ({model!r} and {given!r})")
        model = str(given)
    if model in _DIFFUSE_MODELS or not model:
        return "none", {"diffuse", "color"}
    if model not in SPECULAR_MODELS:
        known = ", ".join((*SPECULAR_MODELS, *_DIFFUSE_MODELS))
        raise InputError(what, f"unknown model {model!r}; use one of {known}")
    known_keys = {"diffuse", *MODEL_PARAMS[model]} - {"lobes"}
    if "lobes" in MODEL_PARAMS[model]:  # a spec string gives them one lobe= at a time
        known_keys.add("lobe")
    return model, known_keys


def _spec_items(text: str, what: str) -> dict[str, Any]:
    """``key=v,v,key=v`` -> ``{key: [v, v], ...}`` (``lobe`` may repeat: a list of lists;
    ``model`` keeps its name)."""
    items: dict[str, Any] = {}
    key = None
    for token in (t.strip() for t in text.split(",")):
        if "=" in token:
            key, _, value = (part.strip() for part in token.partition("="))
            key = key.lower()
            if not key:
                raise InputError(what, f"a value without a key in {token!r}")
            if key == "model":
                if not value:
                    raise InputError(what, "model= needs a model name")
                items["model"] = value.lower()
                key = None  # the model takes one name, not numbers
                continue
            if key in items and key != "lobe":
                raise InputError(what, f"gives {key!r} twice")
            if key == "lobe":
                items.setdefault("lobe", []).append([])
        elif not token:
            raise InputError(what, f"an empty item in {text.strip()!r} (a comma too many?)")
        elif key is None:
            raise InputError(what, f"{token!r} is not KEY=VALUE (e.g. 'alpha=0.1')")
        else:
            value = token
        try:
            number = float(value)
        except ValueError:
            raise InputError(what, f"{key}: {value!r} is not a number") from None
        if key == "lobe":
            items["lobe"][-1].append(number)
        else:
            items.setdefault(key, []).append(number)
    return items


def _one_or_list(values: list[float]) -> float | list[float]:
    """One number as a number (as a scene file writes it), several as a list."""
    return values[0] if len(values) == 1 else values


def _lobe(values: list[float], j: int, what: str) -> dict[str, Any]:
    if len(values) not in (5, 7):
        raise InputError(
            what,
            f"lobe {j + 1} takes 5 numbers (cx, cy, cz, exponent, rho) or 7 (an RGB rho), "
            f"got {len(values)}",
        )
    cx, cy, cz, exponent, *rho = values
    return {"cx": cx, "cy": cy, "cz": cz, "exponent": exponent, "rho": _one_or_list(rho)}


def parse_material(
    spec: str | Mapping[str, Any], n_vertices: int = 1, *, what: str | None = None
) -> Materials:
    """The materials of ``n_vertices`` vertices from a one-line spec (:func:`material_table`)
    or a material table, with the checks of a scene file's ``[material]``.

    Parameters
    ----------
    spec : ``"ggx:alpha=0.1,specular=0.04,diffuse=0.5"`` or a mapping with the keys of a scene
        file's ``[material]`` table
    n_vertices : vertices that get it (one by default: the spec checked on its own)
    what : the input errors name (default ``"--material"`` for a string, ``"material"`` for a
        mapping)

    Raises
    ------
    InputError
        naming ``what`` and the problem: an unknown model or key, a wrong number of values, a
        value out of range (colours in [0, 1], exponents and roughness >= 0) or missing.
    """
    if what is None:
        what = "--material" if isinstance(spec, str) else "material"
    table = material_table(spec, what=what) if isinstance(spec, str) else spec
    try:
        return uniform(table, n_vertices, name=what)
    except InputError as exc:  # "--material: alpha: must be >= 0", not "--material.alpha: ..."
        if exc.what.startswith(f"{what}."):
            raise InputError(what, f"{exc.what[len(what) + 1 :]}: {exc.problem}") from None
        raise
