"""Mitsuba 3 versions of our scenes, for independent reference renders.

:func:`scene_dict` turns a :class:`lobelight.scene.Scene` (with materials that are uniform over
groups of faces), an environment file and a camera into a ``mi.load_dict`` scene: one PLY shape
per material group (vertex normals included, so Mitsuba shades with the same smooth normals),
``envmap`` lighting, a ``perspective`` sensor with a box pixel filter (the reference renderer's
pixel footprint) and the ``path`` integrator. Materials map one to one: Lambert -> ``diffuse``,
a specular model -> its own :meth:`~lobelight.brdf.BRDF.mitsuba_dict` (GGX/Beckmann ->
``roughconductor``, same parameters by construction of :mod:`lobelight.brdf`), and a Lambert +
specular sum -> a ``blendbsdf`` of the two with their reflectances scaled by the blend weights,
which is the sum exactly (:func:`_blend`; refused where the two parts add up to more than 1 in
a channel, beyond Mitsuba's reflectance range). Specular models without a Mitsuba counterpart
are refused rather than approximated.

The glTF material, Lambert plus :class:`lobelight.brdf.GGXSchlick`, is Mitsuba's ``diffuse``
plus a ``principled`` BSDF with only its metallic lobe (``metallic = 1``, ``base_color = f0``),
which has no reflectance factor to scale into a ``blendbsdf``; and no weights of a blend make
Lambert plus that lobe within Mitsuba's [0, 1] reflectances (the lobe's Fresnel term goes to 1
at grazing angles and so takes a blend's whole weight). :func:`load_mitsuba` therefore
registers one small BSDF of its own, ``lobelight_sum`` (:data:`SUM_PLUGIN`): the plain sum of
its nested Mitsuba BSDFs ``bsdf_0``, ``bsdf_1``, ..., sampled as their mixture with the fixed
probabilities ``prob_0``, ``prob_1``, ... Every value and sample comes from Mitsuba's own
plugins; the sum only adds them. The llvm variants compile its Python into their kernels; the
scalar ones call it per ray, which is far slower.

Mitsuba is optional (``pip install mitsuba``; the ``reference`` extra). :func:`scene_dict`
builds the scene in the variant that is set (``scalar_rgb`` when none is); any RGB variant
renders it.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import torch
import trimesh

from .. import brdf as _brdf
from ..errors import InputError
from ..geometry.camera import Camera
from ..scene import Scene

__all__ = ["SUM_PLUGIN", "load_mitsuba", "material_dict", "scene_dict"]

#: Rounding allowed when checking that Lambert plus specular reflectance stays within 1 per
#: channel (values read from float32 materials).
_SUM_SLACK = 1e-6
#: The name of the sum of BSDFs that :func:`load_mitsuba` registers (module docstring).
SUM_PLUGIN = "lobelight_sum"
#: The variants the sum is registered in (a registration holds for one variant).
_REGISTERED: set[str] = set()


def load_mitsuba(variant: str | None = "scalar_rgb"):
    """Import Mitsuba, set ``variant`` (None: keep the variant that is set, else
    ``scalar_rgb``) and register :data:`SUM_PLUGIN` in it; InputError naming what is missing
    when it cannot."""
    try:
        import mitsuba as mi  # optional: the reference extra
    except ImportError as exc:
        raise InputError("mitsuba", f"is not installed ({exc}); pip install mitsuba") from None
    if variant is None:
        variant = mi.variant() or "scalar_rgb"
    if mi.variant() != variant:
        mi.set_variant(variant)
    if variant not in _REGISTERED:
        cls = _sum_class(mi)
        mi.register_bsdf(SUM_PLUGIN, lambda props: cls(props))
        _REGISTERED.add(variant)
    return mi


def _sum_class(mi):
    """The class of :data:`SUM_PLUGIN` for the variant that is set."""
    import drjit as dr  # optional: comes with mitsuba

    class SumBSDF(mi.BSDF):
        """``f = sum_j f_j`` of the nested BSDFs ``bsdf_j``, sampled as the mixture
        ``sum_j prob_j pdf_j`` (one part's sample, then the whole sum's value and density)."""

        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            keys = set(props.keys())
            count = sum(1 for k in keys if k.startswith("bsdf_"))
            self.parts = [props[f"bsdf_{j}"] for j in range(count)]
            probs = [
                float(props[f"prob_{j}"]) if f"prob_{j}" in keys else 1.0 for j in range(count)
            ]
            total = sum(probs)
            self.probs = [p / total for p in probs]
            flags, comps = 0, []
            for part in self.parts:
                flags |= int(part.flags())
                comps += [part.flags(i) for i in range(part.component_count())]
            self.m_flags = flags
            self.m_components = comps

        def eval(self, ctx, si, wo, active=True):
            value = self.parts[0].eval(ctx, si, wo, active)
            for part in self.parts[1:]:
                value += part.eval(ctx, si, wo, active)
            return value

        def pdf(self, ctx, si, wo, active=True):
            pdf = self.probs[0] * self.parts[0].pdf(ctx, si, wo, active)
            for p, part in zip(self.probs[1:], self.parts[1:], strict=True):
                pdf += p * part.pdf(ctx, si, wo, active)
            return pdf

        def eval_pdf(self, ctx, si, wo, active=True):
            return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

        def sample(self, ctx, si, sample1, sample2, active=True):
            bs, lo = None, 0.0
            last = len(self.parts) - 1
            for j, (p, part) in enumerate(zip(self.probs, self.parts, strict=True)):
                chosen = active & (sample1 >= lo)
                if j < last:
                    chosen = chosen & (sample1 < lo + p)
                u = dr.clip((sample1 - lo) / p, 0.0, 0.99999994)
                bs_j, _ = part.sample(ctx, si, u, sample2, chosen)
                if bs is None:
                    bs = bs_j
                else:
                    bs.wo = dr.select(chosen, bs_j.wo, bs.wo)
                    bs.sampled_type = dr.select(chosen, bs_j.sampled_type, bs.sampled_type)
                    bs.sampled_component = dr.select(
                        chosen, bs_j.sampled_component, bs.sampled_component
                    )
                lo += p
            value, pdf = self.eval_pdf(ctx, si, bs.wo, active)
            bs.pdf = pdf
            ok = active & (pdf > 0)
            return bs, dr.select(ok, value / dr.select(ok, pdf, 1.0), 0.0)

        def traverse(self, callback):
            for j, part in enumerate(self.parts):
                callback.put(f"bsdf_{j}", part, mi.ParamFlags.Differentiable)

        def to_string(self):
            return f"SumBSDF[{len(self.parts)} parts]"

    return SumBSDF


def _groups(scene: Scene) -> list[tuple[np.ndarray, dict]]:
    """Faces grouped by identical material: ``[(face ids, mitsuba bsdf dict)]``."""
    mats = scene.materials
    faces = scene.mesh.faces.cpu()
    diff = mats.diffuse.cpu()
    spec = mats.specular
    key_parts = [diff]
    if spec is not None:
        for t in spec.params.values():
            if t.ndim >= 1 and t.shape[0] == diff.shape[0]:  # a per-vertex parameter
                key_parts.append(t.cpu().reshape(t.shape[0], -1))
    key = torch.cat([p.reshape(diff.shape[0], -1) for p in key_parts], 1)  # (V, k)
    fkey = key[faces]  # (F, 3, k)
    if not bool((fkey == fkey[:, :1]).all()):
        raise InputError(
            "materials", "vary inside triangles; Mitsuba export needs per-group materials"
        )
    uniq, inv = torch.unique(fkey[:, 0], dim=0, return_inverse=True)
    out = []
    for g in range(uniq.shape[0]):
        fid = (inv == g).nonzero().squeeze(-1).numpy()
        v0 = int(faces[fid[0], 0])
        s = spec.take(torch.tensor([v0])) if spec is not None else None
        out.append((fid, material_dict(diff[v0], s)))
    return out


def _blend(diffuse: torch.Tensor, s: _brdf.BRDF) -> dict:
    """Lambert ``diffuse`` (3,) plus the microfacet lobe ``s`` as Mitsuba's ``blendbsdf``.

    ``(1 - w) diffuse(diffuse / (1 - w)) + w roughconductor(specular / w)`` equals the sum for
    any weight ``w`` in (0, 1). ``w = max(specular) / (max(specular) + max(diffuse))`` keeps
    both scaled reflectances within Mitsuba's [0, 1] whenever ``diffuse + specular <= 1`` in
    every channel (``specular``: the lobe's factor, Mitsuba's ``specular_reflectance``), and
    picks each part for sampling in proportion to its largest value. A lobe whose Mitsuba BSDF
    has no such factor (:class:`lobelight.brdf.GGXSchlick`'s ``principled``) is summed with
    the Lambert part instead (:func:`_sum`).
    """
    micro = s.mitsuba_dict()
    d = diffuse.double().reshape(-1).expand(3)
    if "specular_reflectance" not in micro:  # no factor to scale: the sum (module docstring)
        return _sum(d, micro)
    spec = torch.tensor(micro["specular_reflectance"]["value"], dtype=torch.float64)  # (3,)
    if bool((d + spec > 1 + _SUM_SLACK).any()):
        raise InputError(
            "materials",
            f"Lambert {d.tolist()} + specular {spec.tolist()} exceed 1 in a channel: no exact "
            "Mitsuba BSDF (blendbsdf reflectances are limited to [0, 1])",
        )
    w = float(spec.max() / (spec.max() + d.max()))
    micro["specular_reflectance"] = {"type": "rgb", "value": (spec / w).clamp(0, 1).tolist()}
    base = {
        "type": "diffuse",
        "reflectance": {"type": "rgb", "value": (d / (1 - w)).clamp(0, 1).tolist()},
    }
    return {"type": "blendbsdf", "weight": w, "bsdf_0": base, "bsdf_1": micro}


def _sum(d: torch.Tensor, micro: dict) -> dict:
    """Lambert ``d`` (3,) plus the ``principled`` metallic lobe ``micro`` as
    :data:`SUM_PLUGIN`, each part sampled in proportion to its mean reflectance (the lobe's
    Schlick term at 60 degrees, ``F0 + (1 - F0) / 32``)."""
    f0 = micro["base_color"]["value"]
    lobe = sum(b + (1 - b) / 32 for b in f0) / len(f0)
    diff = float(d.mean())
    total = lobe + diff if lobe + diff > 0 else 1.0
    base = {"type": "diffuse", "reflectance": {"type": "rgb", "value": d.tolist()}}
    return {
        "type": SUM_PLUGIN,
        "bsdf_0": base,
        "bsdf_1": micro,
        "prob_0": diff / total,
        "prob_1": lobe / total,
    }


def material_dict(diffuse, spec: _brdf.BRDF | None) -> dict:
    """The Mitsuba BSDF (a ``mi.load_dict`` entry) of one material: Lambert ``diffuse``
    (an RGB triple) plus the specular lobe ``spec`` with one value per parameter (or None), as
    :func:`scene_dict` exports it (module docstring; :func:`load_mitsuba` registers what it
    may use).

    Raises
    ------
    InputError
        naming ``materials`` for a lobe without a Mitsuba counterpart, or a Lambert plus
        conductor whose reflectances add up to more than 1 in a channel
    """
    d = torch.as_tensor(diffuse, dtype=torch.float64).reshape(-1).expand(3)
    has_spec = (
        spec is not None and float(spec.params.get("specular", torch.ones(1)).abs().max()) > 0
    )
    if has_spec and float(d.max()) > 0:
        return _blend(d, spec)
    if has_spec:
        return spec.mitsuba_dict()
    return {"type": "diffuse", "reflectance": {"type": "rgb", "value": d.tolist()}}


def scene_dict(
    scene: Scene,
    env_path: str | Path,
    camera: Camera | None = None,
    *,
    width: int = 128,
    height: int = 96,
    spp: int = 64,
    max_depth: int = 4,
    seed: int = 0,
    workdir: str | Path | None = None,
    variant: str | None = None,
) -> dict:
    """A ``mi.load_dict`` scene equivalent to ours (PLY files are written to ``workdir``).

    Parameters
    ----------
    env_path : lat-long ``.exr``/``.hdr`` file of the lighting (Mitsuba's ``envmap``)
    max_depth : path length as Mitsuba counts it (2 = direct lighting)
    variant : the Mitsuba variant to set (None: keep the one that is set, else ``scalar_rgb``)
    """
    mi = load_mitsuba(variant)
    cam = camera or scene.camera
    work = Path(workdir or tempfile.mkdtemp(prefix="lobelight-mi-"))
    v = scene.mesh.vertices.cpu().numpy().astype(np.float64)
    n = scene.mesh.normals.cpu().numpy().astype(np.float64)
    f = scene.mesh.faces.cpu().numpy()
    d: dict = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": int(max_depth)},
        "sensor": {
            "type": "perspective",
            "fov": float(cam.fov),
            "fov_axis": cam.fov_axis,
            "to_world": mi.ScalarTransform4f().look_at(
                origin=list(cam.origin), target=list(cam.target), up=list(cam.up)
            ),
            "film": {
                "type": "hdrfilm",
                "width": int(width),
                "height": int(height),
                "rfilter": {"type": "box"},
                "pixel_format": "rgb",
            },
            "sampler": {"type": "independent", "sample_count": int(spp), "seed": int(seed)},
        },
        "env": {"type": "envmap", "filename": str(env_path)},
    }
    for g, (fid, bsdf) in enumerate(_groups(scene)):
        used = np.unique(f[fid])
        remap = np.full(len(v), -1)
        remap[used] = np.arange(len(used))
        tm = trimesh.Trimesh(v[used], remap[f[fid]], vertex_normals=n[used], process=False)
        path = work / f"group{g}.ply"
        ply = trimesh.exchange.ply.export_ply(
            tm, encoding="binary", vertex_normal=True, include_attributes=False
        )
        path.write_bytes(ply)
        d[f"shape{g}"] = {"type": "ply", "filename": str(path), "bsdf": bsdf, "face_normals": False}
    return d
