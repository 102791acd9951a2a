"""A fitted model as a glTF 2.0 binary (``.glb``), and back.

:func:`export_gltf` writes one file that ordinary viewers open as a mesh with a fallback
metallic-roughness material, and that carries every (vertex, view) record of the model as
application-specific accessors (names beginning with ``_``) described by the extension
``LOBELIGHT_prt`` (in ``extensionsUsed``, never in ``extensionsRequired``: viewers that do not
know it still load the file). :func:`import_gltf` reads such a file back as a
:class:`lobelight.model.Model`. The layout, every accessor and the extension's schema are in
``docs/gltf-export.md``.

- The mesh: ``POSITION``, ``NORMAL``, ``TEXCOORD_0`` (the albedo textures' UVs where the model
  has them), ``COLOR_0`` (the fallback base colour per vertex) and uint32 indices; one
  primitive per albedo layer (the faces of a layer's vertices), all sharing the vertex
  accessors.
- The fallback material (:func:`fallback_material`): base colour per vertex, and where the
  model has albedo textures its base colour textures (8-bit sRGB PNG, as the model holds
  them); one metallic and one roughness factor for the whole mesh, from the specular model's
  parameters.
- The lobe data: glTF 2.0 has no half-float component type, so with ``float16=True`` the
  Gaussians, the SH transfer and the hit distances are IEEE binary16 bit patterns in
  ``UNSIGNED_SHORT`` accessors (a relative rounding of at most ``2**-11``); with
  ``float16=False`` they are ``FLOAT`` accessors. Records no rendering can see are left out,
  as the model file leaves them out (a view whose weight and its neighbours' are all zero).
- With ``lighting``: the map as an image-based light of ``EXT_lights_image_based`` (its
  order-3 irradiance SH and the prefiltered chain's mips, one per resolution, as RGBD PNG
  faces), and the order-5 radiance SH the model's diffuse transfer is lit with in the
  extension.

Writes are atomic (:func:`lobelight._io.atomic_writer`), never over a file read as an input
(:func:`lobelight._io.check_outputs`); the binary chunk is streamed from the arrays, so a
write holds the arrays once.
"""

from __future__ import annotations

import importlib
import io
import json
import math
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from PIL import Image

from .._io import atomic_writer, check_outputs, read_input
from .._tol import SHARPNESS_MIN
from ..brdf import sharp_lobe
from ..envmap import EnvMap
from ..errors import InputError
from ..geometry import sphere
from ..lobes import sg
from ..lobes.sg import Gaussians
from ..model import Model
from ..scene import WRAP_MODES, AlbedoTexture, Materials, Mesh
from ._lighting import Lighting

if TYPE_CHECKING:
    import pygltflib

__all__ = [
    "GLTF_EXTENSION",
    "GLTF_EXTENSION_VERSION",
    "GLTF_MAX_BYTES",
    "GLTF_MAX_EXPANDED_BYTES",
    "export_gltf",
    "fallback_material",
    "import_gltf",
    "kept_records",
]

#: The extension that describes the lobe data (in ``extensionsUsed`` only).
GLTF_EXTENSION = "LOBELIGHT_prt"
#: The version of its schema (``docs/gltf-export.md``).
GLTF_EXTENSION_VERSION = 1
#: The largest file :func:`import_gltf` reads, in bytes.
GLTF_MAX_BYTES = 1 << 34
#: The most memory the Gaussians of a model read take once expanded to every (vertex, view)
#: record (7 float32 per Gaussian), in bytes, as for a model file: a file whose counts add
#: up to more is refused before they are allocated.
GLTF_MAX_EXPANDED_BYTES = 8 << 30

_IBL = "EXT_lights_image_based"
_FLOAT, _USHORT, _UBYTE, _UINT = 5126, 5123, 5121, 5125
_NCOMP = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
_DTYPE = {_FLOAT: "<f4", _USHORT: "<u2", _UBYTE: "u1", _UINT: "<u4"}
# glTF sampler codes of the albedo layers' wrap modes (WRAP_MODES order) and filters
_WRAP_CODES = (10497, 33071, 33648)
_NEAREST, _LINEAR = 9728, 9729
# the widest width a half float holds
_SIGMA_F16 = 65504.0
# the irradiance of a radiance SH band l is A_l times it (cosine convolution), l = 0, 1, 2
_COSINE_BANDS = (math.pi, 2 * math.pi / 3, math.pi / 4)
# the dielectric reflectance of the glTF metallic-roughness model
_F0_DIELECTRIC = 0.04
# RGBD's largest value: the PNG's alpha D = 1/255 divides the RGB up to 255
_RGBD_RANGE = 255.0


def _pygltflib():
    """pygltflib, imported when a glTF file is written or read rather than with this module:
    its import (dataclasses-json's schemas) would otherwise be part of every command's start."""
    return importlib.import_module("pygltflib")


# --------------------------------------------------------------------------------------------
# writing


@dataclass
class _Doc:
    """The document being built: accessors, buffer views and images, with the binary chunk
    kept as a list of byte strings (streamed to the file, never concatenated)."""

    gltf: pygltflib.GLTF2 = field(default_factory=lambda: _pygltflib().GLTF2())
    chunks: list[bytes] = field(default_factory=list)
    size: int = 0

    def view(self, data: bytes, target: int | None = None) -> int:
        pygltflib = _pygltflib()
        pad = -self.size % 4
        if pad:
            self.chunks.append(b"\0" * pad)
            self.size += pad
        self.gltf.bufferViews.append(
            pygltflib.BufferView(
                buffer=0, byteOffset=self.size, byteLength=len(data), target=target
            )
        )
        self.chunks.append(data)
        self.size += len(data)
        return len(self.gltf.bufferViews) - 1

    def accessor(self, arr: np.ndarray, kind: str, ctype: int, *, name: str | None = None,
                 target: int | None = None, minmax: bool = False) -> int:  # fmt: skip
        """An accessor of ``arr`` (count rows of ``kind``), stored as ``ctype``."""
        pygltflib = _pygltflib()
        a = np.ascontiguousarray(arr, dtype=_DTYPE[ctype]).reshape(-1, _NCOMP[kind])
        acc = pygltflib.Accessor(
            bufferView=self.view(a.tobytes(), target), componentType=ctype, count=len(a),
            type=kind, name=name,
        )  # fmt: skip
        if minmax and len(a):
            acc.min = a.min(0).astype(np.float64).tolist()
            acc.max = a.max(0).astype(np.float64).tolist()
        self.gltf.accessors.append(acc)
        return len(self.gltf.accessors) - 1

    def floats(self, arr: torch.Tensor | np.ndarray, kind: str, name: str, f16: bool) -> dict:
        """Lobe data: float32 ``FLOAT`` or binary16 bits in ``UNSIGNED_SHORT``; returns its
        entry of the extension (accessor and encoding)."""
        a = arr.detach().cpu().numpy() if isinstance(arr, torch.Tensor) else np.asarray(arr)
        if f16:
            with np.errstate(over="raise"):
                bits = a.astype(np.float16).view(np.uint16)
            return {
                "accessor": self.accessor(bits, kind, _USHORT, name=name),
                "encoding": "float16",
            }
        return {"accessor": self.accessor(a, kind, _FLOAT, name=name), "encoding": "float32"}

    def image(self, png: bytes, name: str | None = None) -> int:
        pygltflib = _pygltflib()
        self.gltf.images.append(
            pygltflib.Image(bufferView=self.view(png), mimeType="image/png", name=name)
        )
        return len(self.gltf.images) - 1


def _png(rgb: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb)).save(buf, format="PNG")
    return buf.getvalue()


def kept_records(w: torch.Tensor) -> torch.Tensor:
    """(V, J) records some rendering sees: weight at the view or at a geodesic neighbour."""
    live = w.amax((-1, -2)) > 0  # (V, J)
    nbr = sphere.geodesic_neighbor_table(device=w.device)  # (J, 6), -1 padded
    near = live[:, nbr.clamp_min(0)] & (nbr >= 0)  # (V, J, 6)
    return live | near.any(-1)


def _spec_params(spec) -> tuple[torch.Tensor | None, torch.Tensor | None]:
    """(f0 (V or 1, 3), alpha (V or 1,)) of a specular model where its parameters map to a
    microfacet reflectance and roughness: ``f0``/``specular`` colours (a conductor's ``eta``
    and ``k`` by Fresnel at normal incidence); ``alpha`` (or the
    mean of ``alpha_u, alpha_v`` / ``alpha_x, alpha_y``), or a Phong exponent ``e`` as the
    Beckmann roughness ``sqrt(2 / (e + 2))``. None for what does not map."""
    if spec is None:
        return None, None
    p = {k: v.detach().float().cpu() for k, v in spec.params.items() if torch.is_tensor(v)}
    f0 = p.get("f0", p.get("specular"))
    if f0 is None and "eta" in p:  # a conductor's Fresnel reflectance at normal incidence
        eta, k = p["eta"], p.get("k", torch.zeros(()))
        f0 = ((eta - 1) ** 2 + k**2) / ((eta + 1) ** 2 + k**2)
    if f0 is not None:
        f0 = f0.reshape(-1, 3) if f0.shape[-1:] == (3,) else f0.reshape(-1, 1).expand(-1, 3)
    alpha = p.get("alpha")
    for a, b in (("alpha_u", "alpha_v"), ("alpha_x", "alpha_y")):
        if alpha is None and a in p:
            alpha = (p[a] + p.get(b, p[a])) / 2
    if alpha is None and "exponent" in p:
        alpha = torch.sqrt(2 / (p["exponent"] + 2))
    return f0, None if alpha is None else alpha.reshape(-1)


def _metallic(d: float, f: float) -> float:
    """The metallic ``m`` of the glTF model whose mean diffuse albedo is ``d`` and mean
    reflectance ``f``: ``d = b (1 - m)``, ``f = 0.04 (1 - m) + b m``; with ``u = 1 - m``,
    ``0.04 u^2 - (d + f) u + d = 0``, the root in [0, 1]."""
    s = d + f
    disc = max(s * s - 4 * _F0_DIELECTRIC * d, 0.0)
    u = (s - math.sqrt(disc)) / (2 * _F0_DIELECTRIC)
    return float(min(max(1 - u, 0.0), 1.0))


def fallback_material(
    materials: Materials, albedo: AlbedoTexture | None = None
) -> tuple[torch.Tensor, float, float]:
    """The fallback metallic-roughness material of a model for other viewers.

    Returns ``(base (V, 3) float32 in [0, 1], metallic, roughness)``: one metallic and one
    roughness for the mesh (a glTF material's factors are uniform), the base colour per vertex.

    - ``roughness = sqrt(mean alpha)`` (glTF's ``alpha = roughness^2``) where the specular
      model has a roughness (:func:`_spec_params`), 1 without a specular lobe;
    - ``metallic`` solves the glTF model for the mean diffuse albedo and mean reflectance
      (``f0`` or ``specular``; 0 without a specular lobe);
    - ``base = diffuse + f0 - 0.04 (1 - metallic)``, per vertex: exact for a glTF material
      (``lobelight.brdf.metallic_roughness``) whatever the metallic. A vertex read from an albedo
      texture takes ``factor / (1 - metallic)`` (``factor`` for a metallic over 0.999), so that
      the viewer's ``base x texture x (1 - metallic)`` is the model's diffuse albedo.
    """
    d = materials.diffuse.detach().float().cpu()  # (V, 3)
    f0, alpha = _spec_params(materials.specular)
    rough = 1.0 if alpha is None else float(alpha.clamp(0, 1).mean().sqrt())
    metal = 0.0
    base = d
    if f0 is not None:
        metal = _metallic(float(d.mean()), float(f0.mean()))
        base = d + (f0 - _F0_DIELECTRIC * (1 - metal)).expand_as(d)
    if albedo is not None:
        textured = (albedo.layer.cpu() > 0)[:, None]
        scale = 1 / (1 - metal) if metal < 1 - 1e-3 else 1.0
        fac = albedo.factor.detach().float().cpu() * scale
        base = torch.where(textured, fac, base)
    return base.clamp(0, 1).contiguous(), metal, rough


def _mesh(doc: _Doc, model: Model, base: torch.Tensor) -> dict[str, int]:
    """The vertex accessors: POSITION, NORMAL, COLOR_0, and TEXCOORD_0 and the albedo's own
    per-vertex attributes where the model has albedo textures."""
    m = model.mesh
    attrs = {
        "POSITION": doc.accessor(m.vertices.detach().cpu().numpy(), "VEC3", _FLOAT,
                                 target=34962, minmax=True),
        "NORMAL": doc.accessor(m.normals.detach().cpu().numpy(), "VEC3", _FLOAT, target=34962),
        "COLOR_0": doc.accessor(base.numpy(), "VEC3", _FLOAT, target=34962),
    }  # fmt: skip
    a = model.albedo
    if a is not None:
        attrs["TEXCOORD_0"] = doc.accessor(a.uvs.cpu().numpy(), "VEC2", _FLOAT, target=34962)
        attrs["_LOBELIGHT_ALBEDO_FACTOR"] = doc.accessor(
            a.factor.cpu().numpy(), "VEC3", _FLOAT, target=34962
        )
        attrs["_LOBELIGHT_ALBEDO_LAYER"] = doc.accessor(
            a.layer.cpu().numpy(), "SCALAR", _FLOAT, target=34962
        )  # FLOAT: a vertex attribute's elements align to 4 bytes; whole numbers below 2**24
    return attrs


def _albedo_textures(doc: _Doc, albedo: AlbedoTexture) -> list[dict]:
    """Each albedo layer as a PNG image, a sampler and a texture; the extension's records."""
    pygltflib = _pygltflib()
    layers = []
    for i, img in enumerate(albedo.images):
        ws, wt = (int(c) for c in albedo.wrap[i])
        near = bool(albedo.nearest[i])
        doc.gltf.samplers.append(
            pygltflib.Sampler(
                magFilter=_NEAREST if near else _LINEAR,
                wrapS=_WRAP_CODES[ws],
                wrapT=_WRAP_CODES[wt],
            )
        )
        image = doc.image(_png(img.cpu().numpy()), name=f"_LOBELIGHT_ALBEDO_{i}")
        doc.gltf.textures.append(pygltflib.Texture(source=image, sampler=i))
        layers.append({
            "texture": len(doc.gltf.textures) - 1,
            "wrap": [WRAP_MODES[ws], WRAP_MODES[wt]],
            "transform": albedo.transform[i].tolist(),
            "nearest": near,
        })  # fmt: skip
        if albedo.specular is not None:  # the layer's F0 image, on the same sampler
            spec = albedo.specular[i].cpu().numpy()
            image = doc.image(_png(spec), name=f"_LOBELIGHT_SPECULAR_{i}")
            doc.gltf.textures.append(pygltflib.Texture(source=image, sampler=i))
            layers[-1]["specular_texture"] = len(doc.gltf.textures) - 1
    return layers


def _primitives(doc: _Doc, model: Model, attrs: dict, metal: float, rough: float, ext: dict):
    """One primitive per albedo layer (a face's layer is its first corner's), each with its
    material; the faces' order where the grouping changes it."""
    pygltflib = _pygltflib()
    faces = model.mesh.faces.cpu()
    group = torch.zeros(faces.shape[0], dtype=torch.int64)
    if model.albedo is not None:
        group = model.albedo.layer.cpu()[faces[:, 0]]
    order = torch.argsort(group, stable=True)
    if not bool((order == torch.arange(len(order))).all()):
        ext["face_order"] = doc.accessor(
            order.numpy(), "SCALAR", _UINT, name="_LOBELIGHT_FACE_ORDER"
        )
    prims = []
    for g in torch.unique(group).tolist():
        sel = order[group[order] == g]
        pbr = pygltflib.PbrMetallicRoughness(
            baseColorFactor=[1.0, 1.0, 1.0, 1.0], metallicFactor=metal, roughnessFactor=rough
        )
        if g > 0:
            pbr.baseColorTexture = pygltflib.TextureInfo(index=ext["albedo"][g]["texture"])
        doc.gltf.materials.append(pygltflib.Material(
            name=f"lobelight_{g}", pbrMetallicRoughness=pbr, doubleSided=False))  # fmt: skip
        idx = doc.accessor(faces[sel].numpy(), "SCALAR", _UINT, target=34963)
        prims.append(pygltflib.Primitive(
            attributes=pygltflib.Attributes(**attrs), indices=idx,
            material=len(doc.gltf.materials) - 1, mode=4))  # fmt: skip
    return prims


def _lobes(doc: _Doc, model: Model, f16: bool) -> dict:
    """The extension's lobe data: the kept records' Gaussians, the views, the transfer."""
    g = model.gaussians
    keep = kept_records(g.w)  # (V, J)
    lam = g.lam.clamp_min(SHARPNESS_MIN)
    light = g.w * sg.integral(lam.double()).to(g.w.dtype)[..., None]  # (V, J, N, 3)
    sigma = lam.rsqrt().clamp_max(_SIGMA_F16)  # (V, J, N)
    if f16 and float(light.abs().max()) > 65504:
        raise InputError("float16", "Gaussian integrals exceed the half-float range")
    out = {
        "keep": doc.accessor(keep.cpu().numpy(), "SCALAR", _UBYTE, name="_LOBELIGHT_KEEP"),
        "views": doc.accessor(model.views.cpu().numpy(), "VEC3", _FLOAT, name="_LOBELIGHT_VIEWS"),
        "light": doc.floats(light[keep], "VEC3", "_LOBELIGHT_LOBE_LIGHT", f16),
        "mean": doc.floats(g.mu[keep], "VEC3", "_LOBELIGHT_LOBE_MEAN", f16),
        "sigma": doc.floats(sigma[keep], "SCALAR", "_LOBELIGHT_LOBE_SIGMA", f16),
        "diffuse": doc.floats(model.diffuse, "VEC3", "_LOBELIGHT_DIFFUSE", f16),
        "records": int(keep.sum()),
    }  # fmt: skip
    if model.bounce is not None:
        out["bounce"] = doc.floats(model.bounce, "VEC3", "_LOBELIGHT_BOUNCE", f16)
    return out


def _tiles(doc: _Doc, model: Model) -> dict:
    """The visibility and hit tiles where the model holds them (or its material's lobe is
    shaded per pixel, for which they are computed as :meth:`Model.save` does)."""
    if sharp_lobe(model.materials.specular, per_vertex=False) is not None:
        model.visibility()
        model.hits()
    out = {}
    vis, hits = model.visibility_held, model.hits_held
    if vis is not None:
        out["visibility"] = doc.accessor(vis.cpu().numpy(), "SCALAR", _UBYTE,
                                         name="_LOBELIGHT_VISIBILITY")  # fmt: skip
        out["tile_res"] = int(vis.shape[-1])
    if hits is not None:
        face = (hits[0].cpu().long() + 1).numpy()  # -1 (none) becomes 0
        out["hit_face"] = doc.accessor(face, "SCALAR", _UINT, name="_LOBELIGHT_HIT_FACE")
        out["hit_distance"] = doc.floats(hits[1].float(), "SCALAR", "_LOBELIGHT_HIT_DISTANCE", True)
        out["tile_res"] = int(hits[0].shape[-1])
    return out


def _rgbd(x: np.ndarray) -> np.ndarray:
    """Linear RGB ``(..., 3)`` as Babylon.js's RGBD: ``D = floor(max(255 / max(rgb), 1)) / 255``,
    RGB ``(rgb D)^(1/2.2)``; decoded as ``rgb^2.2 / D``. (..., 4) uint8."""
    m = np.maximum(x.max(-1, keepdims=True), 1e-8)
    d = np.clip(np.floor(np.maximum(_RGBD_RANGE / m, 1.0)) / 255.0, 1 / 255, 1.0)
    rgb = np.clip(x * d, 0, 1) ** (1 / 2.2)
    return np.round(np.concatenate([rgb, d], -1) * 255).astype(np.uint8)


def _ibl(doc: _Doc, lighting: Lighting) -> dict:
    """The map as ``EXT_lights_image_based``'s light 0 (module docstring); the extension's
    lighting entry."""
    sh_full = lighting.sh.detach().double().cpu()  # (n, 3) radiance SH of the diffuse part
    if lighting.sun is not None:
        sh_full = sh_full + lighting.sun_sh_rotated(torch.eye(3)).double()
    irr = torch.cat([sh_full[l * l : (l + 1) ** 2] * a for l, a in enumerate(_COSINE_BANDS)])
    pf = lighting.prefiltered
    mips, lams, res = [], [], None
    for k, level in enumerate(pf.levels):
        r = int(level.shape[1])
        if (res is None or r * 2 == res) and r >= 1:
            faces = level.detach().float().cpu().numpy()[:, ::-1]  # rows flipped: top is t = 1
            mips.append([doc.image(_png(_rgbd(faces[f]))) for f in range(6)])
            lams.append(float(pf.lambdas[k]))
            res = r
    light = {
        "name": lighting.name,
        "rotation": [0.0, 0.0, 0.0, 1.0],
        "intensity": 1.0,
        "irradianceCoefficients": irr.tolist(),
        "specularImageSize": int(pf.levels[0].shape[1]),
        "specularImages": mips,
    }
    doc.gltf.extensions[_IBL] = {"lights": [light]}
    doc.gltf.scenes[0].extensions = {_IBL: {"light": 0}}
    doc.gltf.extensionsUsed.append(_IBL)
    return {"name": lighting.name, "sh": sh_full.tolist(), "ibl_light": 0,
            "mip_lambdas": lams, "sun": lighting.sun is not None}  # fmt: skip


def _lighting_of(lighting) -> Lighting | None:
    if lighting is None or isinstance(lighting, Lighting):
        return lighting
    if isinstance(lighting, EnvMap):
        return Lighting(lighting)
    raise InputError("lighting", f"expected a Lighting or an EnvMap, got {type(lighting).__name__}")


def _write_glb(path: Path, doc: _Doc) -> int:
    """The GLB container: header, JSON chunk (pygltflib's document), binary chunk streamed."""
    pygltflib = _pygltflib()
    doc.gltf.buffers = [pygltflib.Buffer(byteLength=doc.size + (-doc.size % 4))]
    js = doc.gltf.to_json(separators=(",", ":")).encode()
    js += b" " * (-len(js) % 4)
    bin_len = doc.size + (-doc.size % 4)
    total = 12 + 8 + len(js) + 8 + bin_len
    with atomic_writer(path) as f:
        f.write(b"glTF" + struct.pack("<II", 2, total))
        f.write(struct.pack("<II", len(js), 0x4E4F534A) + js)
        f.write(struct.pack("<II", bin_len, 0x004E4942))
        for c in doc.chunks:
            f.write(c)
        f.write(b"\0" * (bin_len - doc.size))
    return total


def export_gltf(model: Model, path, *, lighting=None, float16: bool = True) -> dict[str, Any]:
    """Write ``model`` as a glTF 2.0 binary at ``path`` (module docstring,
    ``docs/gltf-export.md``).

    Parameters
    ----------
    model : Model;  path : the ``.glb`` to write (its folder must exist)
    lighting : optional :class:`Lighting` (or :class:`lobelight.envmap.EnvMap`): written as an
        ``EXT_lights_image_based`` light with its SH
    float16 : the lobe data as binary16 bits (half the size) rather than float32

    Returns
    -------
    dict: ``bytes`` written, ``records`` kept of ``records_total``

    Raises
    ------
    InputError
        naming ``path``: not ``.glb``, its folder missing, or a file read as an input; or the
        model's light beyond half floats with ``float16``.
    """
    pygltflib = _pygltflib()
    p = Path(path)
    if p.suffix.lower() != ".glb":
        raise InputError(str(p), "a glTF export is a binary .glb file")
    if not p.parent.is_dir():
        raise InputError(str(p), f"the directory {str(p.parent)!r} does not exist")
    check_outputs(p)
    if not isinstance(model, Model):
        raise InputError("model", f"expected a Model, got {type(model).__name__}")
    light = _lighting_of(lighting)
    doc = _Doc()
    doc.gltf.asset = pygltflib.Asset(version="2.0", generator="lobelight")
    doc.gltf.scenes = [pygltflib.Scene(nodes=[0])]
    doc.gltf.scene = 0
    doc.gltf.nodes = [pygltflib.Node(mesh=0, name=model.mesh.name)]
    base, metal, rough = fallback_material(model.materials, model.albedo)
    attrs = _mesh(doc, model, base)
    ext: dict[str, Any] = {"version": GLTF_EXTENSION_VERSION}
    if model.albedo is not None:
        ext["albedo"] = _albedo_textures(doc, model.albedo)
    prims = _primitives(doc, model, attrs, metal, rough, ext)
    doc.gltf.meshes = [pygltflib.Mesh(primitives=prims, name=model.mesh.name)]
    lobes = _lobes(doc, model, float16)
    ext.update({
        "n_vertices": model.mesh.n_vertices,
        "n_views": int(model.views.shape[0]),
        "n_gaussians": model.n_gaussians,
        "indirect_gaussians": model.indirect_gaussians,
        "sh_order": model.sh_order,
        "weights": "integral",
        "materials": model.materials.to_dict(),
        "sharp_lobe": _sharp_record(model),
        "fallback": {"metallic": metal, "roughness": rough},
        "provenance": model.provenance,
        **lobes,
        **_tiles(doc, model),
    })  # fmt: skip
    if light is not None:
        ext["lighting"] = _ibl(doc, light)
    doc.gltf.extensions[GLTF_EXTENSION] = ext
    doc.gltf.extensionsUsed.append(GLTF_EXTENSION)
    try:
        json.dumps(ext)
    except (TypeError, ValueError) as exc:  # a provenance value JSON cannot hold
        raise InputError(str(p), f"cannot write the model's metadata: {exc}") from None
    total = _write_glb(p, doc)
    v, j = model.gaussians.shape[:2]
    return {"bytes": total, "records": lobes["records"], "records_total": v * j}


def _sharp_record(model: Model) -> dict | None:
    """The material's sharp lobe as the renderers shade it per pixel (None for none)."""
    s = sharp_lobe(model.materials.specular, per_vertex=False)
    if s is None:
        return None
    return {"weights": s.weights.tolist(), "lam": s.lam.tolist(), "warp": bool(s.warp),
            "albedo": s.albedo.tolist()}  # fmt: skip


# --------------------------------------------------------------------------------------------
# reading


def _need(cond: bool, name: str, problem: str) -> None:
    if not cond:
        raise InputError(name, problem)


def _parse_glb(data: bytes, name: str) -> tuple[pygltflib.GLTF2, memoryview]:
    """The document and the binary chunk of a GLB container."""
    pygltflib = _pygltflib()
    _need(len(data) >= 20 and data[:4] == b"glTF", name, "not a binary glTF (.glb) file")
    version, total = struct.unpack_from("<II", data, 4)
    _need(version == 2 and total <= len(data), name, "not a whole glTF 2.0 binary")
    js_len, js_type = struct.unpack_from("<II", data, 12)
    _need(js_type == 0x4E4F534A and 20 + js_len <= total, name, "its JSON chunk is malformed")
    try:
        gltf = pygltflib.GLTF2.from_json(bytes(data[20 : 20 + js_len]).decode())
    except (ValueError, TypeError, KeyError, UnicodeDecodeError) as exc:
        raise InputError(name, f"its JSON chunk is malformed: {exc}") from None
    blob = memoryview(b"")
    at = 20 + js_len
    if at + 8 <= total:
        b_len, b_type = struct.unpack_from("<II", data, at)
        _need(
            b_type == 0x004E4942 and at + 8 + b_len <= total, name, "its binary chunk is malformed"
        )
        blob = memoryview(data)[at + 8 : at + 8 + b_len]
    return gltf, blob


@dataclass
class _Reader:
    gltf: pygltflib.GLTF2
    blob: memoryview
    name: str

    def accessor(self, i: Any, kind: str, ctype: int | tuple[int, ...], count: int) -> np.ndarray:
        """Accessor ``i`` checked against its expected type, component type and count:
        ``(count, ncomp)`` as stored (a copy)."""
        accs = self.gltf.accessors
        _need(isinstance(i, int) and 0 <= i < len(accs), self.name, f"no accessor {i!r:.20}")
        a = accs[i]
        what = f"accessor {a.name or i}"
        ctypes = ctype if isinstance(ctype, tuple) else (ctype,)
        _need(a.type == kind and a.componentType in ctypes and a.count == count, self.name,
              f"{what} must be {count} {kind} of component type {ctypes}, got {a.count} "
              f"{a.type} of {a.componentType}")  # fmt: skip
        _need(a.bufferView is not None and 0 <= a.bufferView < len(self.gltf.bufferViews),
              self.name, f"{what} has no buffer view")  # fmt: skip
        bv = self.gltf.bufferViews[a.bufferView]
        dt = np.dtype(_DTYPE[a.componentType])
        n = _NCOMP[kind]
        start = (bv.byteOffset or 0) + (a.byteOffset or 0)
        nbytes = count * n * dt.itemsize
        _need(bv.byteStride in (None, 0, n * dt.itemsize), self.name, f"{what} is interleaved")
        _need(start + nbytes <= (bv.byteOffset or 0) + bv.byteLength <= len(self.blob),
              self.name, f"{what} reaches beyond its buffer")  # fmt: skip
        return np.frombuffer(self.blob[start : start + nbytes], dt).reshape(count, n).copy()

    def floats(self, entry: Any, kind: str, count: int) -> torch.Tensor:
        """A lobe array of the extension (``{"accessor", "encoding"}``) as float32, finite."""
        _need(isinstance(entry, dict), self.name, f"{GLTF_EXTENSION} lacks an array")
        enc = entry.get("encoding")
        _need(enc in ("float16", "float32"), self.name, f"unknown encoding {enc!r:.30}")
        ctype = _USHORT if enc == "float16" else _FLOAT
        a = self.accessor(entry.get("accessor"), kind, ctype, count)
        out = (a.view(np.float16) if enc == "float16" else a).astype(np.float32)
        _need(bool(np.isfinite(out).all()), self.name, "lobe data holds NaN or Inf")
        return torch.from_numpy(out)


def _count(ext: dict, key: str, lo: int, hi: int, name: str) -> int:
    x = ext.get(key)
    ok = isinstance(x, int) and not isinstance(x, bool) and lo <= x <= hi
    _need(ok, name, f"{GLTF_EXTENSION}.{key} must be a whole number in {lo}..{hi}, got {x!r:.30}")
    return x


def _read_mesh(r: _Reader, ext: dict, v: int) -> Mesh:
    prims = r.gltf.meshes[0].primitives if r.gltf.meshes else []
    _need(len(prims) > 0, r.name, "has no mesh primitive")
    at = prims[0].attributes
    verts = r.accessor(at.POSITION, "VEC3", _FLOAT, v)
    normals = r.accessor(at.NORMAL, "VEC3", _FLOAT, v)
    parts = []
    for p in prims:
        acc = r.gltf.accessors[p.indices] if isinstance(p.indices, int) else None
        _need(acc is not None and acc.count % 3 == 0, r.name, "a primitive's indices are amiss")
        parts.append(r.accessor(p.indices, "SCALAR", _UINT, acc.count).reshape(-1, 3))
    faces = torch.from_numpy(np.concatenate(parts).astype(np.int64))
    _need(faces.numel() > 0 and int(faces.max()) < v, r.name, "face index out of range")
    if "face_order" in ext:
        order = torch.from_numpy(r.accessor(ext["face_order"], "SCALAR", _UINT, len(faces)))
        order = order.reshape(-1).long()
        _need(bool((torch.sort(order).values == torch.arange(len(faces))).all()), r.name,
              "face_order is not a permutation")  # fmt: skip
        out = torch.empty_like(faces)
        out[order] = faces
        faces = out
    name = str((ext.get("provenance") or {}).get("scene", Path(r.name).stem))
    return Mesh(vertices=torch.from_numpy(verts), faces=faces,
                normals=torch.from_numpy(normals), name=name)  # fmt: skip


def _read_gaussians(r: _Reader, ext: dict, v: int, j: int, n: int) -> Gaussians:
    keep = torch.from_numpy(r.accessor(ext.get("keep"), "SCALAR", _UBYTE, v * j)).reshape(v, j)
    keep = keep > 0
    k = int(keep.sum())
    _need(ext.get("records") == k, r.name, "records and keep disagree")
    light = r.floats(ext.get("light"), "VEC3", k * n).reshape(k, n, 3)
    mean = r.floats(ext.get("mean"), "VEC3", k * n).reshape(k, n, 3)
    sigma = r.floats(ext.get("sigma"), "SCALAR", k * n).reshape(k, n)
    _need(bool((sigma > 0).all()) and bool((light >= 0).all()), r.name,
          "Gaussian widths must be positive and their light non-negative")  # fmt: skip
    _need(bool((mean.norm(dim=-1) > 1e-6).all()), r.name, "a Gaussian mean is a zero vector")
    lam_k = sigma.pow(-2)
    w = torch.zeros(v, j, n, 3)
    w[keep] = light / sg.integral(lam_k.double()).float()[..., None]
    mu = torch.zeros(v, j, n, 3)
    mu[..., 1] = 1.0  # records left out: zero weight, any unit mean
    mu[keep] = torch.nn.functional.normalize(mean, dim=-1)
    lam = torch.ones(v, j, n)
    lam[keep] = lam_k
    return Gaussians(w, mu, lam)


def _image(r: _Reader, t: Any) -> torch.Tensor:
    """Texture ``t``'s image, decoded to ``(H, W, 3)`` uint8 (the sRGB codes as stored)."""
    g = r.gltf
    _need(isinstance(t, int) and 0 <= t < len(g.textures), r.name, f"no texture {t!r:.20}")
    src = g.textures[t].source
    _need(isinstance(src, int) and 0 <= src < len(g.images), r.name, f"texture {t} has no image")
    bvi = g.images[src].bufferView
    _need(isinstance(bvi, int) and 0 <= bvi < len(g.bufferViews), r.name,
          f"image {src} is not in the file's buffer")  # fmt: skip
    bv = g.bufferViews[bvi]
    start = bv.byteOffset or 0
    _need(start + bv.byteLength <= len(r.blob), r.name, f"image {src} reaches beyond the buffer")
    try:
        with Image.open(io.BytesIO(bytes(r.blob[start : start + bv.byteLength]))) as im:
            return torch.from_numpy(np.asarray(im.convert("RGB")).copy())
    except (OSError, ValueError, Image.DecompressionBombError) as exc:
        raise InputError(r.name, f"image {src} cannot be read: {exc}") from None


def _read_albedo(r: _Reader, ext: dict, v: int) -> AlbedoTexture | None:
    layers = ext.get("albedo")
    if layers is None:
        return None
    at = vars(r.gltf.meshes[0].primitives[0].attributes)  # custom attributes included
    extra = at.get("_LOBELIGHT_ALBEDO_FACTOR"), at.get("_LOBELIGHT_ALBEDO_LAYER")
    uvs = r.accessor(at.get("TEXCOORD_0"), "VEC2", _FLOAT, v)
    factor = r.accessor(extra[0], "VEC3", _FLOAT, v)
    layer_f = r.accessor(extra[1], "SCALAR", _FLOAT, v).reshape(-1)
    _need(bool((layer_f == np.round(layer_f)).all()) and bool((layer_f >= 0).all()), r.name,
          "_LOBELIGHT_ALBEDO_LAYER holds values that are not layers")  # fmt: skip
    layer = layer_f.astype(np.int64)
    _need(isinstance(layers, list) and all(isinstance(x, dict) for x in layers), r.name,
          "albedo must be a list of layer records")  # fmt: skip
    images = [_image(r, rec.get("texture")) for rec in layers]
    with_spec = ["specular_texture" in rec for rec in layers]
    _need(all(with_spec) or not any(with_spec), r.name,
          "albedo layers must all have a specular_texture or none")  # fmt: skip
    specular = None
    if all(with_spec) and layers:
        specular = tuple(_image(r, rec["specular_texture"]) for rec in layers)
    try:
        return AlbedoTexture(
            uvs=torch.from_numpy(uvs),
            layer=torch.from_numpy(layer),
            factor=torch.from_numpy(factor),
            images=tuple(images),
            wrap=torch.tensor([[WRAP_MODES.index(m) for m in rec["wrap"]] for rec in layers]),
            transform=torch.tensor([rec["transform"] for rec in layers], dtype=torch.float32),
            nearest=torch.tensor([bool(rec["nearest"]) for rec in layers]),
            specular=specular,
        )
    except (KeyError, TypeError, ValueError, RuntimeError, InputError) as exc:
        raise InputError(r.name, f"bad albedo layer records: {exc}") from None


def import_gltf(path, *, device=None) -> Model:
    """Read a model written by :func:`export_gltf` (its ``LOBELIGHT_prt`` extension; the
    lighting it may hold is for other viewers and is not read, and the visibility and hit
    tiles are computed from the mesh again when a renderer needs them, as for a model file
    without them).

    Raises
    ------
    InputError
        naming the file: missing, over :data:`GLTF_MAX_BYTES`, not a glTF binary, without
        the extension (a glTF scene to bake, not an exported model), or with arrays that do not
        match its counts.
    """
    name = str(path)
    data = read_input(path, limit=GLTF_MAX_BYTES)
    gltf, blob = _parse_glb(data, name)
    ext = (gltf.extensions or {}).get(GLTF_EXTENSION)
    _need(isinstance(ext, dict), name,
          f"has no {GLTF_EXTENSION} extension: a glTF scene, not an exported lobelight model "
          "(bake it first, lobelight bake)")  # fmt: skip
    _need(ext.get("version") == GLTF_EXTENSION_VERSION, name,
          f"{GLTF_EXTENSION} version {ext.get('version')!r:.20}; this lobelight reads "
          f"{GLTF_EXTENSION_VERSION}")  # fmt: skip
    r = _Reader(gltf, blob, name)
    v = _count(ext, "n_vertices", 3, 1 << 26, name)
    j = _count(ext, "n_views", sphere.N_VIEWS, sphere.N_VIEWS, name)
    n = _count(ext, "n_gaussians", 1, 8, name)
    order = _count(ext, "sh_order", 1, 10, name)
    expanded = 28 * v * j * n
    _need(expanded <= GLTF_MAX_EXPANDED_BYTES, name,
          f"{v:,} vertices with {n} Gaussian(s) per view take {expanded / 2**30:.1f} GiB, over "
          f"the reader's limit of {GLTF_MAX_EXPANDED_BYTES / 2**30:g} GiB")  # fmt: skip
    mesh = _read_mesh(r, ext, v)
    views = torch.from_numpy(r.accessor(ext.get("views"), "VEC3", _FLOAT, j))
    g = _read_gaussians(r, ext, v, j, n)
    diffuse = r.floats(ext.get("diffuse"), "VEC3", v * order * order).reshape(v, -1, 3)
    bounce = None
    if "bounce" in ext:
        bounce = r.floats(ext["bounce"], "VEC3", v * order * order).reshape(v, -1, 3)
    try:
        mats = Materials.from_dict(ext.get("materials"), v)
    except (KeyError, TypeError, InputError) as exc:
        raise InputError(name, f"bad materials entry: {exc}") from None
    return Model(
        mesh=mesh,
        views=views,
        gaussians=g,
        diffuse=diffuse,
        materials=mats,
        provenance=dict(ext.get("provenance") or {}),
        bounce=bounce,
        indirect_gaussians=_count(ext, "indirect_gaussians", 0, n - 1, name),
        albedo=_read_albedo(r, ext, v),
    ).to(device if device is not None else "cpu")
