"""Mitsuba 3 versions of our scenes, for independent reference renders.

:func:`scene_dict` turns a :class:`lobelight.scene.Scene` (with materials that are uniform over
groups of faces, or a glTF asset: below), an environment file and a camera into a
``mi.load_dict`` scene: one PLY shape per material group (vertex normals included, so Mitsuba
shades with the same smooth normals),
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

A scene with a glTF asset (:attr:`lobelight.scene.Scene.gltf`) is exported with its true
textured materials, not the per-vertex values the transport bakes (:func:`gltf_bsdf`): one PLY
shape per glTF material, with the asset's normals and ``TEXCOORD_0``; its diffuse part
``baseColor (1 - metallic)`` and the lobe's ``F0 = mix(0.04, baseColor, metallic)`` and
roughness as ``bitmap`` textures of linear data (``raw``), with the sampler's magnification
filter (no mipmaps: the base level, as :func:`lobelight.scene.sample_texture` reads it), its
wrap mode and the ``KHR_texture_transform`` as the bitmap's ``to_uv``. Mitsuba multiplies no
textures, so each slot is one image composed texel by texel from the base colour texture
(times its factor and the material's constant ``COLOR_0``) and the metallic-roughness texture
(B metal and G rough, times their factors): exact where one of the two is untextured (the
slot is then linear in the other texture, which bilinear filtering keeps), and where both are,
wherever the textures are constant across the bilinear footprint (a product of
interpolations is not the interpolation of the product between differing texels). A texture
whose texels are all equal is read as a factor (its value, whatever its sampler). Refused with
an :class:`~lobelight.errors.InputError` naming the material: two textures of one material
with different UV transforms, wrap modes or filters, and vertex colours that vary within a
material. A sampler that wraps U and V differently (Mitsuba's bitmap has one wrap mode) is
expressed by laying the image out over every texel the material's UVs reach, each wrapped by
its own axis, read with clamping (refused where that would take more than four times the
image's texels). A ``doubleSided`` material
is wrapped in ``twosided``. Normal, occlusion and emissive textures are not exported (as
lobelight's renderers, which do not read them).

Mitsuba is optional (``pip install mitsuba``; the ``reference`` extra). :func:`scene_dict`
builds the scene in the variant that is set (``scalar_rgb`` when none is); any RGB variant
renders it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from .. import brdf as _brdf
from ..errors import InputError
from ..geometry.camera import Camera
from ..scene import GltfAsset, GltfMaterial, Scene, Texture, sample_texture, wrap_texels

__all__ = ["SUM_PLUGIN", "gltf_bsdf", "load_mitsuba", "material_dict", "scene_dict"]

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


def _gltf_groups(asset: GltfAsset) -> list[tuple[np.ndarray, dict]]:
    """Faces grouped by glTF material: ``[(face ids, mitsuba bsdf dict)]``."""
    fmat = asset.face_material.cpu()
    faces = asset.mesh.faces.cpu()
    out = []
    for m in torch.unique(fmat).tolist():
        fid = (fmat == m).nonzero().squeeze(-1).numpy()
        used = torch.unique(faces[torch.from_numpy(fid)])
        mat, colors, uvs = asset.materials[m], asset.colors[used].cpu(), asset.uvs[used].cpu()
        out.append((fid, gltf_bsdf(mat, colors, uvs)))
    return out


def _texture_key(tex: Texture) -> tuple:
    """What must agree for two textures to be composed into one image."""
    return tex.sampler.wrap_s, tex.sampler.wrap_t, tex.sampler.mag_filter, tex.uv_transform


def _grid(textures: list[Texture], where: str) -> tuple[int, int]:
    """The (H, W) of the image composed from ``textures`` (the finest of them), after
    checking that they can be composed (module docstring)."""
    keys = {_texture_key(t) for t in textures}
    if len(keys) > 1:
        raise InputError(
            where,
            "its base colour and metallic-roughness textures differ in UV transform, wrap "
            f"modes or filter ({sorted(map(str, keys))}): Mitsuba cannot compose them",
        )
    return max(t.image.shape[0] for t in textures), max(t.image.shape[1] for t in textures)


def _on_grid(tex: Texture, h: int, w: int) -> torch.Tensor:
    """``tex``'s image (h, w, C) float64: itself when it has that size, else read at the
    texel centres of an h x w grid by its own sampler."""
    img = tex.image.detach().cpu().double()
    if img.shape[:2] == (h, w):
        return img
    plain = Texture(img, tex.sampler, tex.source)  # no UV transform: the grid is texture space
    v, u = torch.meshgrid(
        (torch.arange(h, dtype=torch.float64) + 0.5) / h,
        (torch.arange(w, dtype=torch.float64) + 0.5) / w,
        indexing="ij",
    )
    return sample_texture(plain, torch.stack([u, v], -1))  # (h, w, C)


def _bitmap(mi, data: torch.Tensor, tex: Texture, uvs, where: str) -> dict:
    """A ``bitmap`` texture of linear ``data`` (H, W, C) read as ``tex``'s sampler says (the
    material's ``uvs`` (k, 2) for :func:`_unwrapped`, where the sampler wraps U and V
    differently)."""
    s = tex.sampler
    rows = np.eye(3)
    if tex.uv_transform is not None:
        rows[:2] = np.asarray(tex.uv_transform, dtype=np.float64)
    wrap = s.wrap_s
    if s.wrap_s != s.wrap_t:
        data, rows, wrap = *_unwrapped(data, tex, rows, uvs, where), "clamp"
    d = {
        "type": "bitmap",
        "data": mi.TensorXf(np.ascontiguousarray(data.float().numpy())),
        "raw": True,
        "filter_type": "nearest" if s.mag_filter == "nearest" else "bilinear",
        "wrap_mode": wrap,
    }
    if not np.array_equal(rows, np.eye(3)):
        d["to_uv"] = mi.ScalarTransform3f(mi.ScalarMatrix3f(rows.tolist()))
    return d


#: Most texels an image unwrapped by :func:`_unwrapped` may have, in units of its own texels.
_UNWRAP_GROWTH = 4


def _unwrapped(data: torch.Tensor, tex: Texture, rows: np.ndarray, uvs, where: str):
    """``data`` (H, W, C) laid out over every texel the material's ``uvs`` (k, 2) reach
    (after the UV transform ``rows`` (3, 3)), each wrapped by its own axis's mode, and the UV
    transform that reads it there: the same texels with the same bilinear or nearest weights,
    so that one clamped wrap mode expresses a sampler that wraps U and V differently."""
    s = tex.sampler
    if uvs is None or len(uvs) == 0:
        raise InputError(
            where,
            f"wraps U by {s.wrap_s!r} and V by {s.wrap_t!r}: Mitsuba's bitmap has one wrap mode",
        )
    h, w = data.shape[:2]
    t = np.asarray(uvs, dtype=np.float64) @ rows[:2, :2].T + rows[:2, 2]  # (k, 2) texture UVs
    lo = np.floor(t.min(0) * (w, h) - 0.5).astype(np.int64)  # first texel read, (x, y)
    hi = np.floor(t.max(0) * (w, h) - 0.5).astype(np.int64) + 1  # last texel read
    nw, nh = (hi - lo + 1).tolist()
    if nw * nh > _UNWRAP_GROWTH * w * h:
        raise InputError(
            where,
            f"wraps U by {s.wrap_s!r} and V by {s.wrap_t!r} and its UVs span {nw} x {nh} "
            f"texels: too many to lay out for Mitsuba's one wrap mode",
        )
    xs = wrap_texels(torch.arange(int(lo[0]), int(hi[0]) + 1), w, s.wrap_s)  # (nw,)
    ys = wrap_texels(torch.arange(int(lo[1]), int(hi[1]) + 1), h, s.wrap_t)  # (nh,)
    shift = np.array([[w / nw, 0, -lo[0] / nw], [0, h / nh, -lo[1] / nh], [0, 0, 1]])
    return data[ys][:, xs], shift @ rows


def _vertex_colour(mat: GltfMaterial, colors: torch.Tensor) -> torch.Tensor:
    """The material's one ``COLOR_0`` RGB (3,) float64 (``colors``: (k, 4) of its vertices);
    InputError when it varies."""
    rgb = colors[:, :3].double()
    if len(rgb) and not bool((rgb == rgb[:1]).all()):
        raise InputError(
            f"material {mat.name!r}",
            "has vertex colours (COLOR_0) that vary: Mitsuba cannot multiply them into its "
            "textures",
        )
    return rgb[0] if len(rgb) else torch.ones(3, dtype=torch.float64)


def gltf_bsdf(material: GltfMaterial, colors=None, uvs=None) -> dict:
    """The Mitsuba BSDF (a ``mi.load_dict`` entry) of one glTF metallic-roughness material
    with its textures (module docstring): Lambert ``baseColor (1 - metallic)`` plus the
    :class:`lobelight.brdf.GGXSchlick` lobe (``principled`` with ``metallic = 1``), summed by
    :data:`SUM_PLUGIN`; wrapped in ``twosided`` when the material is double-sided. Builds
    Mitsuba objects, so the variant must be set (:func:`load_mitsuba`).

    Parameters
    ----------
    material : the glTF material (:class:`lobelight.scene.GltfMaterial`)
    colors : (k, 4) linear ``COLOR_0`` of the material's vertices (None: white)
    uvs : (k, 2) ``TEXCOORD_0`` of the material's vertices, needed only where a sampler wraps
        U and V differently (the texture is then laid out over the texels they reach)

    Raises
    ------
    InputError
        naming the material, for what Mitsuba cannot express (module docstring)
    """
    import mitsuba as mi  # optional: the reference extra

    where = f"material {material.name!r}"
    colour = torch.ones(3, dtype=torch.float64)
    if colors is not None:
        colour = _vertex_colour(material, torch.as_tensor(colors))
    base_factor = torch.tensor(material.base_color[:3], dtype=torch.float64) * colour  # (3,)
    metal_factor, rough_factor = material.metallic, material.roughness
    bt, mt = material.base_color_texture, material.metallic_roughness_texture
    # a texture of one value everywhere reads that value whatever its sampler: a factor
    one = None if bt is None else _uniform(bt)
    if one is not None:
        base_factor, bt = base_factor * one[:3], None
    one = None if mt is None else _uniform(mt)
    if one is not None:
        metal_factor, rough_factor = metal_factor * float(one[2]), rough_factor * float(one[1])
        mt = None
    textures = [t for t in (bt, mt) if t is not None]
    if not textures:
        diffuse, spec = _brdf.metallic_roughness(
            base_factor.clamp(0, 1), min(metal_factor, 1.0), min(rough_factor, 1.0)
        )
        d = _sum(diffuse.double(), spec.mitsuba_dict())
        return _sided(d, material)
    h, w = _grid(textures, where)
    base = base_factor.expand(h, w, 3)
    if bt is not None:
        base = base * _on_grid(bt, h, w)[..., :3]
    metal = torch.full((h, w, 1), metal_factor, dtype=torch.float64)
    rough = torch.full((h, w, 1), rough_factor, dtype=torch.float64)
    if mt is not None:
        mr = _on_grid(mt, h, w)
        metal, rough = metal * mr[..., 2:3], rough * mr[..., 1:2]
    base, metal, rough = base.clamp(0, 1), metal.clamp(0, 1), rough.clamp(0, 1)
    diffuse = base * (1 - metal)  # (h, w, 3)
    f0 = _brdf.DIELECTRIC_F0 * (1 - metal) + base * metal  # (h, w, 3)
    lead = textures[0]
    lobe = {
        "type": "principled",
        "base_color": _bitmap(mi, f0, lead, uvs, where),
        "metallic": 1.0,
        "roughness": (
            _bitmap(mi, rough, lead, uvs, where) if mt is not None else min(rough_factor, 1.0)
        ),
    }
    d = _sum(diffuse.mean((0, 1)), lobe, f0=f0.mean((0, 1)).tolist())
    d["bsdf_0"]["reflectance"] = _bitmap(mi, diffuse, lead, uvs, where)
    return _sided(d, material)


def _uniform(tex: Texture) -> torch.Tensor | None:
    """The one texel value (C,) float64 of a texture whose texels are all equal, else None."""
    img = tex.image.detach().cpu().double()
    first = img[0, 0]
    return first if bool((img == first).all()) else None


def _sided(d: dict, material: GltfMaterial) -> dict:
    return {"type": "twosided", "bsdf": d} if material.double_sided else d


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


def _sum(d: torch.Tensor, micro: dict, f0: list[float] | None = None) -> dict:
    """Lambert ``d`` (3,) plus the ``principled`` metallic lobe ``micro`` as
    :data:`SUM_PLUGIN`, each part sampled in proportion to its mean reflectance (the lobe's
    Schlick term at 60 degrees, ``F0 + (1 - F0) / 32``; ``f0``: the lobe's mean F0 where its
    ``base_color`` is a texture)."""
    f0 = micro["base_color"]["value"] if f0 is None else f0
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
    workdir: str | Path,
    variant: str | None = None,
) -> dict:
    """A ``mi.load_dict`` scene equivalent to ours (PLY files are written to ``workdir``).

    Parameters
    ----------
    env_path : lat-long ``.exr``/``.hdr`` file of the lighting (Mitsuba's ``envmap``)
    workdir : an existing directory for the meshes' PLY files, which Mitsuba reads when the
        dict is loaded; the caller owns it (and removes it after ``mi.load_dict``)
    max_depth : path length as Mitsuba counts it (2 = direct lighting)
    variant : the Mitsuba variant to set (None: keep the one that is set, else ``scalar_rgb``)
    """
    mi = load_mitsuba(variant)
    cam = camera or scene.camera
    work = Path(workdir)
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
    if scene.gltf is not None:
        groups = _gltf_groups(scene.gltf)
        uv = scene.gltf.uvs.cpu().numpy().astype(np.float64)
    else:
        groups, uv = _groups(scene), None
    for g, (fid, bsdf) in enumerate(groups):
        used = np.unique(f[fid])
        remap = np.full(len(v), -1)
        remap[used] = np.arange(len(used))
        path = work / f"group{g}.ply"
        path.write_bytes(_ply(v[used], n[used], remap[f[fid]], None if uv is None else uv[used]))
        d[f"shape{g}"] = {"type": "ply", "filename": str(path), "bsdf": bsdf, "face_normals": False}
    return d


def _ply(v: np.ndarray, n: np.ndarray, f: np.ndarray, uv: np.ndarray | None) -> bytes:
    """A binary PLY of vertices ``v`` (k, 3), normals ``n`` (k, 3), faces ``f`` (m, 3) and,
    given, texture coordinates ``uv`` (k, 2) as Mitsuba reads them (``u``, ``v``: the
    glTF's, unflipped; Mitsuba's bitmap puts V = 0 at the image's first row, as glTF does)."""
    names = ["x", "y", "z", "nx", "ny", "nz"] + ([] if uv is None else ["u", "v"])
    cols = [v, n] + ([] if uv is None else [uv])
    vert = np.ascontiguousarray(np.concatenate(cols, 1), dtype="<f4")  # (k, 6 or 8)
    face = np.zeros(len(f), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    face["n"], face["i"] = 3, f
    head = ["ply", "format binary_little_endian 1.0", f"element vertex {len(v)}"]
    head += [f"property float {c}" for c in names]
    head += [f"element face {len(f)}", "property list uchar int vertex_indices", "end_header"]
    return ("\n".join(head) + "\n").encode() + vert.tobytes() + face.tobytes()
