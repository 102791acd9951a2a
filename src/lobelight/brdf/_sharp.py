"""A sharp specular lobe's shape and light, for shading it per pixel: a mixture of Gaussians
fitted to the lobe's profile, and its directional albedo.

:func:`sharp_lobe` measures a BRDF once: the lobe's profile ``f_s(w, n) cos`` at normal
incidence against five Gaussians of sharpness ``lam0 * 4, lam0, ..., lam0 / 64``
(``lam0`` from the lobe's half-maximum angle), their shares of light by non-negative least
squares, and ``E(n.v) = int f_s cos`` (Fresnel included) at 64 cosines by stratified importance
sampling. The renderers shade such a lobe per pixel (``lobelight.render``; docs/method.md,
"Sharp reflections per pixel").

A measurement is the same in every process: it is kept in memory per material and on disk in
``lobelight._cache.cache_dir() / "brdf"``, one small file per material keyed by a hash of its
parameters, :data:`SHARP_VERSION`, the measurement's settings and the source of the ``brdf``
package (whose code the measurement evaluates). Reading checks the key, the arrays' shapes,
dtypes and values and a hash of them; an entry that fails, or cannot be read, is measured
again and rewritten (atomically: a reader never sees half a file).
"""

from __future__ import annotations

import functools
import hashlib
import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from .. import __version__
from .._cache import UNREADABLE, cache_dir, regular_entry
from .._io import atomic_writer
from .._tol import DIVISOR_F32
from .gltf import GGXSchlick

__all__ = [
    "ALBEDO_SAMPLES",
    "ALBEDO_STEPS",
    "MIXTURE",
    "SHARP_LAM",
    "SHARP_VERSION",
    "SPLIT_ALPHAS",
    "SPLIT_ALPHA_RANGE",
    "VARYING_ALPHA_REF",
    "SharpLobe",
    "schlick_split",
    "sharp_lobe",
    "varying_reference",
]

logger = logging.getLogger(__name__)

#: Gaussians in the lobe's shape mixture, sharpness ``lam0 * 4^(1 - i)``, down to ``lam0 / 64``:
#: a GGX lobe's tail holds a third of its light beyond where one Gaussian of its width reaches,
#: and a bright source seen in the tail lights what the tail reaches (at alpha 0.03 the fit
#: gives ``lam0 / 64`` 6 % of the light, and a sixth Gaussian, ``lam0 / 256``, none).
MIXTURE = 5
#: The sharpest lobe kept in fitted Gaussians: lobes whose half-maximum sharpness ``lam0`` is
#: at least this (a GGX or Beckmann alpha up to about 0.065) are shaded per pixel. Measured
#: better per pixel at alpha 0.03 (docs/results.md); wider lobes keep the fitted Gaussians,
#: which match the references there.
SHARP_LAM = 200.0
#: The roughness at which a glTF lobe varying over the mesh has its mixture measured
#: (:func:`_varying`).
VARYING_ALPHA_REF = 0.03
#: Roughness levels of :func:`schlick_split`'s table, log-spaced over
#: :data:`SPLIT_ALPHA_RANGE` (glTF's clamp, 1e-3, to the roughest lobe).
SPLIT_ALPHAS = 24
SPLIT_ALPHA_RANGE = (1e-3, 1.0)
#: Entries of the directional-albedo table over ``n.v`` in ``(0, 1]``.
ALBEDO_STEPS = 64
#: Importance samples per table entry (a stratified grid: the table's error is far below a
#: percent for the lobes shaded here).
ALBEDO_SAMPLES = 64
#: Version of the measurement, part of a disk entry's key: raise it when :func:`_measure`
#: changes what it computes.
SHARP_VERSION = 1


@dataclass(frozen=True)
class SharpLobe:
    """A material's sharp lobe (module docstring).

    A material constant over the mesh has one lobe: ``lam (M,)`` and its ``albedo`` table. A
    glTF lobe (:class:`lobelight.brdf.GGXSchlick`) whose roughness and F0 vary per vertex has
    a lobe per vertex (:func:`sharp_lobe`): ``lam (V, M)``, the vertices' ``alpha (V,)`` and
    ``f0 (V, 3)``, ``sharp (V,)`` the vertices sharp enough to be shaded per pixel, and its
    albedo from :func:`schlick_split`; :meth:`at` takes it at points (``lam (P, M)``, ``alpha
    (P,)``, ``f0 (P, 3)``, no ``sharp``).

    Attributes
    ----------
    weights : (M,) the shape mixture's share of light per Gaussian (sum 1)
    lam : (M,), (V, M) or (P, M) their sharpness at normal incidence
    warp : whether the sharpness divides by ``n.v`` (microfacet and Blinn-Phong lobes)
    albedo : (T, 3) directional albedo at ``n.v = (k + 0.5) / T``; None where ``split`` gives it
    split : None, or (T, S, 2) the Schlick lobe's albedo scale and bias (:func:`schlick_split`)
    alpha : None, or (V,) / (P,) GGX roughness
    f0 : None, or (V, 3) / (P, 3) reflectance at normal incidence
    sharp : None, or (V,) bool: the vertices shaded per pixel (the others keep the Gaussians)
    """

    weights: torch.Tensor
    lam: torch.Tensor
    warp: bool
    albedo: torch.Tensor | None
    split: torch.Tensor | None = None
    alpha: torch.Tensor | None = None
    f0: torch.Tensor | None = None
    sharp: torch.Tensor | None = None

    def directional_albedo(self, nv: torch.Tensor) -> torch.Tensor:
        """``E(n.v)``: (..., 3), linear in the table (clamped at its ends); for a lobe taken at
        points, ``nv (P,)`` at its points, ``f0 A(n.v, alpha) + B(n.v, alpha)``, bilinear in
        ``n.v`` and ``log alpha``."""
        if self.split is None:
            t = self.albedo.shape[0]
            x = (nv.clamp(0, 1) * t - 0.5).clamp(0, t - 1)
            i0 = x.floor().long().clamp(max=t - 2)
            f = (x - i0)[..., None]
            a = self.albedo.to(nv.device)
            return a[i0] * (1 - f) + a[i0 + 1] * f
        tab = self.split.to(nv.device)  # (T, S, 2)
        t, s = tab.shape[:2]
        x = (nv.clamp(0, 1) * t - 0.5).clamp(0, t - 1)
        lo, hi = (math.log(a) for a in SPLIT_ALPHA_RANGE)
        y = (self.alpha.to(nv.device).clamp_min(SPLIT_ALPHA_RANGE[0]).log() - lo) / (hi - lo)
        y = (y * (s - 1)).clamp(0, s - 1)
        i0, j0 = x.floor().long().clamp(max=t - 2), y.floor().long().clamp(max=s - 2)
        fx, fy = (x - i0)[..., None], (y - j0)[..., None]
        ab = (tab[i0, j0] * (1 - fx) + tab[i0 + 1, j0] * fx) * (1 - fy)
        ab = ab + (tab[i0, j0 + 1] * (1 - fx) + tab[i0 + 1, j0 + 1] * fx) * fy  # (P, 2)
        return self.f0.to(nv.device) * ab[..., :1] + ab[..., 1:]

    def sharpness(self, nv: torch.Tensor) -> torch.Tensor:
        """(..., M) the mixture's sharpness at ``n.v`` (floored at 0.02: a grazing view's lobe
        does not become a point)."""
        lam = self.lam.to(nv.device)
        if not self.warp:
            return lam.expand(*nv.shape, -1)
        return lam / nv.clamp_min(0.02)[..., None]

    def at(self, corners: torch.Tensor, bary: torch.Tensor, *,
           sharp_only: bool = False) -> SharpLobe:  # fmt: skip
        """The lobe at points of corners ``corners (P, 3)`` and barycentrics ``bary (P, 3)``:
        itself for a material constant over the mesh; else the corners' roughness blended as
        variances (``alpha^2``, the sharpness's inverse) and their F0 linearly, over the sharp
        corners alone with ``sharp_only``."""
        if self.sharp is None:
            return self
        dev = bary.device
        w = bary * self.sharp.to(dev)[corners] if sharp_only else bary
        w = w / w.sum(-1, keepdim=True).clamp_min(DIVISOR_F32)
        var = (w[..., None] / self.lam.to(dev)[corners]).sum(1)  # (P, M)
        a2 = (w * self.alpha.to(dev)[corners] ** 2).sum(-1)
        f0 = (w[..., None] * self.f0.to(dev)[corners]).sum(1)
        return SharpLobe(
            weights=self.weights, lam=1 / var.clamp_min(DIVISOR_F32), warp=self.warp,
            albedo=None, split=self.split, alpha=a2.sqrt(), f0=f0,
        )  # fmt: skip

    def take(self, index: torch.Tensor) -> SharpLobe:
        """A lobe taken at points, at the points ``index`` (itself when constant)."""
        if self.lam.ndim == 1:
            return self
        return SharpLobe(
            weights=self.weights, lam=self.lam[index], warp=self.warp, albedo=None,
            split=self.split, alpha=self.alpha[index], f0=self.f0[index],
        )  # fmt: skip


def sharp_lobe(spec, *, per_vertex: bool = True) -> SharpLobe | None:
    """The lobe of a specular BRDF (module docstring), or None where it is not one the
    renderers shade per pixel: no BRDF, no shader formula (:attr:`BRDF.sun_model`),
    parameters varying over the mesh other than a glTF lobe's roughness and F0, or a lobe
    wider than :data:`SHARP_LAM` (at every vertex, for a glTF lobe varying over the mesh:
    :func:`_varying`). ``per_vertex=False``: None for a lobe varying over the mesh too (for
    a consumer that shades one lobe per material: the web page, the glTF export's record).
    Kept per material (by its parameters) for later calls."""
    if spec is None or (not per_vertex and spec.per_element_params):
        return None
    key = _params_key(spec)
    if key not in _CACHE:
        _CACHE[key] = _varying(spec) if spec.per_element_params else _stored_or_measured(spec, key)
    return _CACHE[key]


def _params_key(spec) -> str:
    """A material's key: its parameters as JSON, or for parameters per element the hash of
    their values (a frame asks for its lobe; tens of thousands of numbers are not JSON)."""
    if not spec.per_element_params:
        return json.dumps(spec.to_dict(), sort_keys=True)
    h = hashlib.sha256(spec.type_name.encode())
    for name, v in sorted(spec.params.items()):
        h.update(name.encode())
        h.update(str(tuple(v.shape)).encode())
        h.update(v.detach().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()


def _varying(spec) -> SharpLobe | None:
    """The per-vertex lobe of a glTF lobe (:class:`lobelight.brdf.GGXSchlick`) whose roughness
    or F0 varies over the mesh, or None where no vertex's lobe is as sharp as
    :data:`SHARP_LAM` or the material is another.

    A GGX lobe's profile is self-similar in ``theta / alpha`` for small ``alpha``
    (``D ~ alpha^2 / (pi (alpha^2 + theta^2)^2)``): the mixture measured once at
    :data:`VARYING_ALPHA_REF` serves every vertex with its sharpness scaled by
    ``(alpha_ref / alpha)^2`` (the half-maximum sharpness times ``alpha^2`` is within 1 % from
    alpha 0.003 to 0.065, and the weights within 0.001), and the albedo is Schlick's split,
    ``f0 A + B`` (:func:`schlick_split`)."""
    if not getattr(spec, "schlick", False) or not set(spec.per_element_params) <= {"alpha", "f0"}:
        return None
    p = spec.params
    alpha = p["alpha"].detach().reshape(-1).float().cpu().clamp_min(SPLIT_ALPHA_RANGE[0])
    ref = varying_reference()
    lam = ref.lam[None] * (VARYING_ALPHA_REF / alpha)[:, None] ** 2  # (V, M)
    sharp = lam[:, 1] >= SHARP_LAM
    if not bool(sharp.any()):
        return None
    f0 = p["f0"].detach().float().cpu()
    f0 = (f0.reshape(-1, 1) if f0.shape[-1:] != (3,) else f0.reshape(-1, 3)).expand(
        alpha.shape[0], 3
    )
    return SharpLobe(
        weights=ref.weights, lam=lam, warp=True, albedo=None, split=schlick_split(),
        alpha=alpha, f0=f0.contiguous(), sharp=sharp,
    )  # fmt: skip


def varying_reference() -> SharpLobe:
    """The lobe a glTF lobe varying per vertex scales (:func:`_varying`): the glTF lobe at
    :data:`VARYING_ALPHA_REF`, F0 1."""
    return sharp_lobe(GGXSchlick(alpha=VARYING_ALPHA_REF, f0=1.0))


@functools.cache
def schlick_split() -> torch.Tensor:
    """The glTF lobe's directional albedo as scale and bias of F0: (T, S, 2), ``E(n.v, alpha,
    f0) = f0 A + B`` (Schlick's Fresnel is linear in F0) at ``n.v = (k + 0.5) / T`` and
    :data:`SPLIT_ALPHAS` roughnesses log-spaced over :data:`SPLIT_ALPHA_RANGE`, by the
    stratified importance sampling of :func:`_albedo_table` (one set of samples: the
    sampling does not depend on F0; ``A`` weighs each by ``1 - (1 - wo.h)^5``, ``B`` by
    ``(1 - wo.h)^5``). Kept on disk as the lobes are (module docstring)."""
    shape = (ALBEDO_STEPS, SPLIT_ALPHAS, 2)
    try:
        key = _entry_key(json.dumps({"split": [SPLIT_ALPHAS, *SPLIT_ALPHA_RANGE]}))
    except OSError as exc:
        logger.info("not caching the Schlick split: %s", exc)
        return _measure_split()
    path = cache_dir() / "brdf" / f"schlick-split-{key[:16]}.npz"
    if regular_entry(path):
        try:
            with np.load(path, allow_pickle=False) as z:
                found, table = str(z["key"][()]), z["table"]
            if (
                found == key
                and table.dtype == np.float32
                and table.shape == shape
                and bool(np.isfinite(table).all() and (table >= 0).all())
            ):
                return torch.from_numpy(table)
        except (*UNREADABLE, TypeError, AttributeError, IndexError) as exc:
            logger.info("ignoring the unreadable Schlick split %s (%r)", path, exc)
    table = _measure_split()
    try:
        with atomic_writer(path) as f:
            np.savez(f, key=np.array(key), table=table.numpy())
    except OSError as exc:
        logger.warning("could not write the Schlick split to %s: %s", path, exc)
    return table


def _measure_split() -> torch.Tensor:
    """:func:`schlick_split`'s measurement: (T, S, 2) float32."""
    t, s = ALBEDO_STEPS, ALBEDO_SAMPLES
    lo, hi = (math.log(a) for a in SPLIT_ALPHA_RANGE)
    alpha = torch.linspace(lo, hi, SPLIT_ALPHAS, dtype=torch.float64).exp()
    nv = (torch.arange(t, dtype=torch.float64) + 0.5) / t
    wo = torch.stack([(1 - nv**2).sqrt(), torch.zeros_like(nv), nv], -1)  # (T, 3)
    g = (torch.arange(s, dtype=torch.float64) + 0.5) / s
    u1, u2 = torch.meshgrid(g, g, indexing="ij")
    u = torch.stack([u1, u2, torch.full_like(u1, 0.5)], -1).reshape(-1, 3)  # (K, 3)
    out = torch.empty(t, SPLIT_ALPHAS, 2, dtype=torch.float64)
    n = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    for j, a in enumerate(alpha.tolist()):  # bounded memory: one roughness's T x K samples
        wo_b = wo[:, None].expand(-1, u.shape[0], 3)
        spec = GGXSchlick(alpha=a, f0=1.0).to("cpu", torch.float64)
        wi, weight, _ = spec.sample(wo_b, n.expand_as(wo_b), u[None].expand(t, -1, 3))
        h = torch.nn.functional.normalize(wi + wo_b, dim=-1)
        m = (1 - (h * wo_b).sum(-1)).clamp(0, 1) ** 5
        w = weight[..., 0]  # F = 1 at f0 = 1: the rest of the sample's weight
        out[:, j, 0] = (w * (1 - m)).mean(1)
        out[:, j, 1] = (w * m).mean(1)
    return out.float()


def _stored_or_measured(spec, params: str) -> SharpLobe | None:
    """:func:`sharp_lobe` of a material with parameters ``params`` (its ``to_dict`` as JSON):
    read from its disk entry (module docstring), else measured and written there."""
    if spec.sun_model is None or spec.per_element_params:
        return None  # no measurement to keep
    try:
        key = _entry_key(params)
    except OSError as exc:  # the package's source unreadable: no key, no entry
        logger.info("not caching the sharp lobe: %s", exc)
        return _measure(spec)
    path = cache_dir() / "brdf" / f"sharp-lobe-{key[:16]}.npz"
    found, lobe = _read_entry(path, key)
    if found:
        return lobe
    lobe = _measure(spec)
    try:
        _write_entry(path, key, lobe)
    except OSError as exc:  # a cache that cannot be written only costs the next run time
        logger.warning("could not write the sharp lobe to %s: %s", path, exc)
    return lobe


def _measure(spec) -> SharpLobe | None:
    """:func:`sharp_lobe`'s measurement."""
    if spec.sun_model is None or spec.per_element_params:
        return None
    spec = spec.to("cpu", torch.float64)
    lam0 = _half_max_sharpness(spec)
    if lam0 < SHARP_LAM:
        return None
    lam = torch.tensor([lam0 * 4.0 ** (1 - i) for i in range(MIXTURE)], dtype=torch.float64)
    weights = _shape_mixture(spec, lam)
    return SharpLobe(
        weights=weights.float(),
        lam=lam.float(),
        warp=spec.sun_model != 2,  # modified Phong's lobe keeps its width about R
        albedo=_albedo_table(spec).float(),
    )


#: :func:`sharp_lobe`'s results by material (a frame must not integrate the tables again;
#: materials are few).
_CACHE: dict[str, SharpLobe | None] = {}


def _profile(spec, theta: torch.Tensor) -> torch.Tensor:
    """``f_s(w, n) cos`` (luminance-like mean over RGB) at normal incidence for ``w`` at angles
    ``theta`` from the normal (the mirror direction): (T,)."""
    z = torch.zeros_like(theta)
    w = torch.stack([torch.sin(theta), z, torch.cos(theta)], -1)
    n = torch.tensor([0.0, 0.0, 1.0], dtype=theta.dtype).expand_as(w)
    return spec.eval(w, n, n).mean(-1) * torch.cos(theta)


def _half_max_sharpness(spec) -> float:
    """The sharpness of the Gaussian with the lobe's half-maximum angle at normal incidence,
    ``ln 2 / (1 - cos theta_half)``."""
    theta = torch.linspace(0, math.pi / 2, 20001, dtype=torch.float64)
    f = _profile(spec, theta)
    half = int((f >= 0.5 * f[0]).nonzero().max())
    th = float(theta[max(half, 1)])
    return math.log(2) / (1 - math.cos(th))


def _shape_mixture(spec, lam: torch.Tensor) -> torch.Tensor:
    """Non-negative shares of light ``a_i`` (sum 1) of Gaussians of sharpness ``lam`` whose sum
    best matches the lobe's profile at normal incidence, weighted by solid angle."""
    theta = torch.linspace(0, math.pi / 2, 8001, dtype=torch.float64)
    f = _profile(spec, theta)
    sw = torch.sin(theta).sqrt()[:, None]
    basis = torch.exp(lam[None] * (torch.cos(theta)[:, None] - 1))  # (T, M)
    active = torch.ones(lam.shape[0], dtype=torch.bool)
    c = torch.zeros(lam.shape[0], dtype=torch.float64)
    for _ in range(lam.shape[0]):  # least squares, dropping negative terms (at most M rounds)
        sol = torch.linalg.lstsq(basis[:, active] * sw, (f[:, None] * sw)).solution[:, 0]
        c = torch.zeros_like(c)
        c[active] = sol
        if bool((sol >= 0).all()):
            break
        active &= c > 0
    light = c.clamp_min(0) * 2 * math.pi * (1 - torch.exp(-2 * lam)) / lam
    return light / light.sum().clamp_min(DIVISOR_F32)


def _albedo_table(spec) -> torch.Tensor:
    """``E(n.v) = int f_s cos`` at :data:`ALBEDO_STEPS` cosines by stratified importance
    sampling of the BRDF: (T, 3)."""
    t, s = ALBEDO_STEPS, ALBEDO_SAMPLES
    nv = (torch.arange(t, dtype=torch.float64) + 0.5) / t
    wo = torch.stack([(1 - nv**2).sqrt(), torch.zeros_like(nv), nv], -1)  # (T, 3)
    g = (torch.arange(s, dtype=torch.float64) + 0.5) / s
    u1, u2 = torch.meshgrid(g, g, indexing="ij")
    u = torch.stack([u1, u2, torch.full_like(u1, 0.5)], -1).reshape(-1, 3)  # (S^2, 3)
    n = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    wo_b = wo[:, None].expand(-1, u.shape[0], 3)
    _, weight, _ = spec.sample(wo_b, n.expand_as(wo_b), u[None].expand(t, -1, 3))
    return weight.mean(1)  # (T, 3)


def _entry_key(params: str) -> str:
    """Hex sha256 naming the disk entry of a material's lobe (module docstring)."""
    head = {
        "version": SHARP_VERSION,
        "params": params,
        "settings": [MIXTURE, SHARP_LAM, ALBEDO_STEPS, ALBEDO_SAMPLES],
        "lobelight": __version__,
        "code": _code_digest(),
    }
    return hashlib.sha256(json.dumps(head, sort_keys=True).encode()).hexdigest()


@functools.cache
def _code_digest() -> str:
    """Hex sha256 of the ``brdf`` package's source files (this one's included). Raises
    OSError where one cannot be read."""
    h = hashlib.sha256()
    for f in sorted(Path(__file__).parent.glob("*.py")):
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()


#: A disk entry's arrays: name, dtype and shape.
_ENTRY = {
    "weights": (np.float32, (MIXTURE,)),
    "lam": (np.float32, (MIXTURE,)),
    "albedo": (np.float32, (ALBEDO_STEPS, 3)),
}


def _values_digest(arrays: dict[str, np.ndarray], warp: bool) -> str:
    h = hashlib.sha256(b"warp" if warp else b"no warp")
    for name in _ENTRY:
        h.update(np.ascontiguousarray(arrays[name]).tobytes())
    return h.hexdigest()


def _read_entry(path: Path, key: str) -> tuple[bool, SharpLobe | None]:
    """``(True, lobe)`` from the entry at ``path`` (``lobe`` None for a lobe too wide to shade
    per pixel), or ``(False, None)`` when the entry is missing, not a regular file,
    unreadable, or not exactly a whole lobe named ``key`` (the module docstring's checks)."""
    if not regular_entry(path):
        return False, None
    try:
        with np.load(path, allow_pickle=False) as z:
            head = json.loads(str(z["header"][()]))
            arrays = {name: z[name] for name in _ENTRY if name in z.files}
    except (*UNREADABLE, TypeError, AttributeError, IndexError) as exc:
        logger.info("ignoring the unreadable sharp lobe %s (%r)", path, exc)
        return False, None
    if not isinstance(head, dict) or head.get("key") != key:
        return False, None
    if head.get("lobe") is False and not arrays:
        return True, None
    if not (head.get("lobe") is True and _entry_fine(arrays, head)):
        logger.info("ignoring the sharp lobe %s: not the lobe asked for", path)
        return False, None
    lobe = SharpLobe(
        weights=torch.from_numpy(arrays["weights"]),
        lam=torch.from_numpy(arrays["lam"]),
        warp=head["warp"],
        albedo=torch.from_numpy(arrays["albedo"]),
    )
    return True, lobe


def _entry_fine(arrays: dict[str, np.ndarray], head: dict) -> bool:
    """An entry's arrays of their dtypes and shapes, finite, with non-negative weights and
    albedo and positive sharpness, matching the hash of them in ``head``."""
    if set(arrays) != set(_ENTRY) or not isinstance(head.get("warp"), bool):
        return False
    for name, (dtype, shape) in _ENTRY.items():
        a = arrays[name]
        if a.dtype != dtype or a.shape != shape or not bool(np.isfinite(a).all()):
            return False
    plausible = (arrays["weights"] >= 0).all() and (arrays["lam"] > 0).all()
    plausible = plausible and (arrays["albedo"] >= 0).all()
    return bool(plausible) and head.get("values") == _values_digest(arrays, head["warp"])


def _write_entry(path: Path, key: str, lobe: SharpLobe | None) -> None:
    """Store ``lobe`` (or that there is none) as ``path``, atomically (the folder is created).
    Raises OSError."""
    if lobe is None:
        head, arrays = {"key": key, "lobe": False}, {}
    else:
        arrays = {
            "weights": lobe.weights.cpu().numpy().astype(np.float32),
            "lam": lobe.lam.cpu().numpy().astype(np.float32),
            "albedo": lobe.albedo.cpu().numpy().astype(np.float32),
        }
        head = {"key": key, "lobe": True, "warp": bool(lobe.warp)}
        head["values"] = _values_digest(arrays, lobe.warp)
    with atomic_writer(path) as f:
        np.savez(f, header=np.array(json.dumps(head, sort_keys=True)), **arrays)
