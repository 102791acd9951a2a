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

__all__ = ["load_mitsuba", "scene_dict"]

#: Rounding allowed when checking that Lambert plus specular reflectance stays within 1 per
#: channel (values read from float32 materials).
_SUM_SLACK = 1e-6


def load_mitsuba(variant: str | None = "scalar_rgb"):
    """Import Mitsuba and set ``variant`` (None: keep the variant that is set, else
    ``scalar_rgb``); InputError naming what is missing when it cannot."""
    try:
        import mitsuba as mi  # optional: the reference extra
    except ImportError as exc:
        raise InputError("mitsuba", f"is not installed ({exc}); pip install mitsuba") from None
    if variant is None:
        variant = mi.variant() or "scalar_rgb"
    if mi.variant() != variant:
        mi.set_variant(variant)
    return mi


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
        d = diff[v0]
        s = spec.take(torch.tensor([v0])) if spec is not None else None
        has_spec = s is not None and float(s.params.get("specular", torch.ones(1)).abs().max()) > 0
        if has_spec and float(d.max()) > 0:
            out.append((fid, _blend(d, s)))
        elif has_spec:
            out.append((fid, s.mitsuba_dict()))
        else:
            out.append(
                (fid, {"type": "diffuse", "reflectance": {"type": "rgb", "value": d.tolist()}})
            )
    return out


def _blend(diffuse: torch.Tensor, s: _brdf.BRDF) -> dict:
    """Lambert ``diffuse`` (3,) plus the microfacet lobe ``s`` as Mitsuba's ``blendbsdf``.

    ``(1 - w) diffuse(diffuse / (1 - w)) + w roughconductor(specular / w)`` equals the sum for
    any weight ``w`` in (0, 1). ``w = max(specular) / (max(specular) + max(diffuse))`` keeps
    both scaled reflectances within Mitsuba's [0, 1] whenever ``diffuse + specular <= 1`` in
    every channel (``specular``: the lobe's factor, Mitsuba's ``specular_reflectance``), and
    picks each part for sampling in proportion to its largest value.
    """
    micro = s.mitsuba_dict()
    d = diffuse.double().reshape(-1).expand(3)
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
