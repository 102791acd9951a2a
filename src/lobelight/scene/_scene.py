"""Scenes: a mesh, its per-vertex materials, an environment and a camera.

Scene files are TOML (or JSON with the same keys); paths inside are relative to the file. The
format, key by key, is in docs/scene-format.md; in short::

    name = "bunny on a table"
    mesh = "bunny.ply"            # OBJ, PLY, STL, glTF/GLB, OFF
    environment = "studio.hdr"    # a file, a bundled map's name, or "builtin"

    [material]                    # one material everywhere (without: a glTF keeps its own) ...
    diffuse = [0.6, 0.5, 0.4]
    model = "ggx"                 # phong, blinn_phong, ward, lafortune, ggx, beckmann, none
    specular = [0.9, 0.9, 0.9]
    alpha = 0.08

    # ... or a gradient between two materials along a direction (the paper's bird)
    # [gradient]
    # axis = [0, 1, 0]
    # from = { diffuse = [0.8, 0.7, 0.1] }
    # to = { diffuse = [0.05, 0.3, 0.05], model = "phong", specular = [0.3, 0.8, 0.3],
    #        exponent = 2000 }

    # ... or, for a glTF mesh, its own materials with some overridden by name
    # [materials.Visor]
    # base_color = [0.9, 0.9, 0.9]
    # metallic = 1.0
    # roughness = 0.1
    # textures = false

    [camera]
    origin = [0, 1, 4]
    target = [0, 0.3, 0]
    up = [0, 1, 0]
    fov = 40

A glTF mesh (``.gltf``/``.glb``, bare or named by a scene file) comes with its own materials:
:func:`lobelight.scene.load_gltf`, then :func:`lobelight.scene.vertex_factors` with
:data:`GLTF_AVERAGE`, then :func:`lobelight.scene.gltf_materials` (every glTF material per-vertex
parameters of one ``ggx_schlick`` model); :attr:`Scene.material_records` lists them.

Built-in scenes (:func:`builtin`) need no files at all.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .. import envmap
from .._io import IMAGE_LIMIT, TEXT_LIMIT, check_input, read_input
from .._tol import SMALL
from ..data import envmap_names, resolve_envmap
from ..errors import InputError
from ..geometry.camera import Camera
from . import _shapes
from ._albedo import AlbedoTexture, albedo_texture
from ._gltf import GLTF_SUFFIXES, GltfMaterial
from ._materials import Materials, _colour, gltf_materials, gradient, parse_material, uniform
from ._mesh import (
    MESH_SUFFIXES,
    GltfAsset,
    Mesh,
    load_gltf,
    load_mesh,
    mesh_from_arrays,
    vertex_factors,
)

try:
    import tomllib
except ImportError:  # Python 3.10: the tomli backport, a dependency there
    import tomli as tomllib  # type: ignore[no-redef]

__all__ = [
    "BARE_MESH_MATERIAL",
    "BUILTIN_SCENES",
    "GLTF_AVERAGE",
    "GLTF_QUADRATURE",
    "GRADIENT_KEYS",
    "MATERIAL_OVERRIDE_KEYS",
    "SCENE_FILE_MATERIAL",
    "SCENE_KEYS",
    "Scene",
    "builtin",
    "default_camera",
    "load",
]

#: The top-level keys of a scene file.
SCENE_KEYS = ("name", "mesh", "environment", "material", "gradient", "materials", "camera")
#: The keys of a scene file's ``[gradient]`` table.
GRADIENT_KEYS = ("axis", "from", "to")
#: The keys of a scene file's ``[materials.NAME]`` table, which overrides the glTF material
#: ``NAME``: its ``baseColorFactor`` (RGB), ``metallicFactor``, ``roughnessFactor`` and, with
#: ``textures = false``, drops its textures.
MATERIAL_OVERRIDE_KEYS = ("base_color", "metallic", "roughness", "textures")
#: How a glTF scene's per-vertex factors are read from its textures
#: (:func:`lobelight.scene.vertex_factors`'s ``average``): averaged over each vertex's one-ring
#: with its hat function, so that the values interpolated across faces keep the texture's mean
#: over the surface; read at the vertex's UV instead, a texture finer than the mesh is
#: point-sampled and its mean over the surface is lost (aliasing). The quadrature follows the
#: texels a face covers (:data:`GLTF_QUADRATURE`); vertex colours (``COLOR_0``), defined at
#: the vertices, multiply the averaged textures at the vertex itself.
GLTF_AVERAGE = "one_ring"
#: The fewest and most sub-triangles per face side of the one-ring quadrature: a face is split
#: into ``n^2`` with ``n`` about the square root of the texels it covers (the 90th percentile
#: over the faces), within these bounds.
GLTF_QUADRATURE = (4, 16)
#: Texture samples per batch of the one-ring quadrature (bounds its memory).
_SAMPLES_PER_BATCH = 1 << 20
#: The material of a bare mesh file (a ``[material]`` table): grey diffuse plus a GGX lobe.
BARE_MESH_MATERIAL = {
    "diffuse": [0.4, 0.4, 0.4],
    "model": "ggx",
    "specular": [0.8, 0.8, 0.8],
    "alpha": 0.15,
}
#: The material of a scene file with neither ``[material]`` nor ``[gradient]``: grey Lambert.
SCENE_FILE_MATERIAL = {"diffuse": [0.5, 0.5, 0.5]}


@dataclass(eq=False)
class Scene:
    """Everything transport sampling and reference rendering need.

    Attributes
    ----------
    mesh : Mesh
    materials : Materials, one entry per mesh vertex
    environment : "builtin" or a path to an HDR/EXR lat-long or cross image
    camera : default viewpoint
    name : for reports and file names
    material_records : the materials a glTF mesh brought, one JSON-ready dict each (empty for
        other scenes): ``name``; ``model`` (the specular model its vertices have);
        ``vertices`` (how many have it); ``textures`` (the texture slots the file gives it,
        e.g. ``["baseColorTexture", "metallicRoughnessTexture"]``); ``override`` (what
        replaced the file's values: ``""`` none, ``"[materials.NAME]"``, ``"[material]"``,
        ``"[gradient]"``, ``"--material"``)
    gltf : the glTF asset whose materials the vertices have (its UVs, per-vertex material
        indices and textures, with the scene file's ``[materials.NAME]`` overrides applied);
        ``None`` for other meshes and where ``[material]`` or ``[gradient]`` replaces them.
        References read its textures whole
    albedo : the diffuse albedo per pixel where ``gltf``'s base colour textures give it
        (:class:`lobelight.scene.AlbedoTexture`), else ``None``
    """

    mesh: Mesh
    materials: Materials
    environment: str = "builtin"
    camera: Camera = field(
        default_factory=lambda: Camera.look_at((0.0, 1.5, 5.0), (0.0, 0.0, 0.0), fov=40.0)
    )
    name: str = "scene"
    material_records: tuple[dict[str, Any], ...] = ()
    gltf: GltfAsset | None = None
    albedo: AlbedoTexture | None = None

    def __post_init__(self) -> None:
        if self.materials.n_vertices != self.mesh.n_vertices:
            raise InputError(
                "materials",
                f"{self.materials.n_vertices} entries for {self.mesh.n_vertices} vertices",
            )
        if self.albedo is not None and self.albedo.n_vertices != self.mesh.n_vertices:
            raise InputError(
                "albedo", f"{self.albedo.n_vertices} entries for {self.mesh.n_vertices} vertices"
            )

    def load_environment(self, *, device=None):
        """The scene's :class:`lobelight.envmap.EnvMap`."""
        env = envmap.builtin() if self.environment == "builtin" else envmap.load(self.environment)
        return env.to(device) if device is not None else env

    def to(self, device) -> Scene:
        return Scene(
            self.mesh.to(device),
            self.materials.to(device),
            self.environment,
            self.camera,
            self.name,
            self.material_records,
            None if self.gltf is None else self.gltf.to(device),
            None if self.albedo is None else self.albedo.to(device),
        )


# --------------------------------------------------------------------------------------------
# built-in scenes


def _knot_scene(*, detail: int = 1, **_: Any) -> Scene:
    """Glossy torus knot (strong self-occlusion) over a diffuse ground plane.

    The knot's material runs from diffuse yellow at the bottom to glossy green at the top (a
    gradient of a Phong lobe, like the paper's bird); the ground is grey and diffuse so its
    vertices carry the knot's shadow in their diffuse transfer.

    The tube has ``72 detail`` rings of ``36 detail`` vertices (2,881 vertices in all at
    ``detail=1``, 11,457 at 2). Per-vertex transport is interpolated across triangles, so the
    tessellation must follow the sharpest lobe across the tube, where the normal turns fastest:
    36 vertices around it (10 degrees of normal per triangle) score clearly better against the
    path tracer than 12 (30 degrees); along the tube, whose centre curve bends slowly, 72 rings
    score about as well as 96 or 144 (the figures are in docs/results.md).
    """
    if detail < 1:
        raise InputError("detail", f"must be >= 1, got {detail}")
    kv, kf = _shapes.torus_knot(nu=72 * detail, nv=36 * detail)
    kv = kv * 0.8
    y0 = float(kv[:, 1].min())
    pv, pf = _shapes.ground_plane(5.0, y0 - 0.05, n=16 * detail + 1)
    v = np.concatenate([kv, pv])
    f = np.concatenate([kf, pf + len(kv)])
    mesh = mesh_from_arrays(v, f, name="knot", weld=False)
    is_knot = torch.zeros(mesh.n_vertices, dtype=torch.bool)
    is_knot[: len(kv)] = True
    y = mesh.vertices[:, 1]
    t = ((y - y.min()) / (float(kv[:, 1].max()) - y0)).clamp(0, 1)
    t = torch.where(is_knot, t, torch.zeros_like(t))
    knot_from = {
        "diffuse": [0.75, 0.6, 0.08],
        "model": "phong",
        "specular": [0.0] * 3,
        "exponent": 30.0,
    }
    knot_to = {
        "diffuse": [0.04, 0.25, 0.06],
        "model": "phong",
        "specular": [0.35, 0.75, 0.35],
        "exponent": 1500.0,
    }
    mats = gradient(knot_from, knot_to, t, name="knot")
    ground = torch.tensor([0.5, 0.5, 0.5])
    mats.diffuse[~is_knot] = ground
    spec = mats.specular
    assert spec is not None
    col = spec.params["specular"].clone()
    col[~is_knot] = 0
    mats = Materials(
        mats.diffuse, spec.map_params(lambda p, k: col if p.shape == col.shape and k == 1 else p)
    )
    cam = Camera.look_at((0.0, 2.2, 4.8), (0.0, -0.2, 0.0), fov=45.0)
    return Scene(mesh, mats, "builtin", cam, "knot")


def _sphere_scene(
    *, subdivisions: int = 3, model: str = "ggx", roughness: float = 0.1, **_: Any
) -> Scene:
    """A glossy sphere of adjustable tessellation (``10 * 4^subdivisions + 2`` vertices)."""
    if not 0 <= subdivisions <= 7:
        raise InputError("subdivisions", f"must be in [0, 7], got {subdivisions}")
    v, f = _shapes.icosphere(subdivisions)
    mesh = mesh_from_arrays(v, f, name=f"sphere{subdivisions}")
    shape = {
        "ggx": {"alpha": roughness},
        "beckmann": {"alpha": roughness},
        "phong": {"exponent": 2 / roughness**2 - 2},
        "blinn_phong": {"exponent": 2 / roughness**2 - 2},
        "ward": {"alpha_x": roughness},
    }
    if model not in shape:
        raise InputError("model", f"built-in sphere supports {sorted(shape)}, got {model!r}")
    spec = {"diffuse": [0.1, 0.1, 0.1], "model": model, "specular": [0.8, 0.8, 0.8], **shape[model]}
    # across the smaller side: the whole sphere in frame at any aspect
    cam = Camera.look_at((0.0, 0.0, 4.0), (0.0, 0.0, 0.0), fov=35.0, fov_axis="smaller")
    return Scene(mesh, uniform(spec, mesh.n_vertices), "builtin", cam, mesh.name)


BUILTIN_SCENES = {"knot": _knot_scene, "sphere": _sphere_scene}


def builtin(name: str = "knot", **options: Any) -> Scene:
    """A built-in scene: ``"knot"`` (options ``detail``) or ``"sphere"`` (``subdivisions``,
    ``model``, ``roughness``).

    A name may carry one option after a colon: ``"sphere:5"`` is five subdivisions,
    ``"knot:2"`` twice the tessellation.
    """
    base, _, arg = name.partition(":")
    if base not in BUILTIN_SCENES:
        raise InputError("scene", f"no built-in scene {name!r}; known: {sorted(BUILTIN_SCENES)}")
    if arg:
        try:
            value = int(arg)
        except ValueError:
            raise InputError("scene", f"option after ':' must be an integer, got {arg!r}") from None
        options = {("detail" if base == "knot" else "subdivisions"): value, **options}
    return BUILTIN_SCENES[base](**options)


# --------------------------------------------------------------------------------------------
# files


def _read_description(p: Path) -> dict[str, Any]:
    text_bytes = read_input(p, limit=TEXT_LIMIT)
    try:
        if p.suffix.lower() == ".json":
            data = json.loads(text_bytes.decode("utf-8"))
        else:
            data = tomllib.loads(text_bytes.decode("utf-8"))
    except Exception as exc:
        raise InputError(str(p), f"not a valid scene file: {exc}") from None
    if not isinstance(data, dict):
        raise InputError(str(p), "a scene file must hold a table of keys")
    unknown = set(data) - set(SCENE_KEYS)
    if unknown:
        known = sorted(SCENE_KEYS)
        raise InputError(str(p), f"unknown key {sorted(unknown)[0]!r}; known: {known}")
    return data


def _camera(d: Any, where: str) -> Camera:
    if not isinstance(d, Mapping):
        raise InputError(where, "camera must be a table with origin, target, up, fov")
    try:
        return Camera.look_at(**dict(d))
    except (TypeError, ValueError, RuntimeError, OverflowError) as exc:  # keys, non-numbers
        raise InputError(where, f"bad camera: {exc}") from None
    except InputError as exc:
        raise InputError(f"{where}.{exc.what}", exc.problem) from None


def _entry_path(p: Path, s: str, d: dict[str, Any], key: str) -> Path:
    """The file named by entry ``key`` of the scene file ``p`` (named ``s``), relative to it."""
    value = d[key]
    if not isinstance(value, str) or not value or "\x00" in value:
        raise InputError(f"{s}: {key}", f"must be a file name, got {value!r:.60}")
    try:
        return (p.parent / value).resolve()
    except (RuntimeError, OSError) as exc:  # a symbolic link loop, a path the system refuses
        raise InputError(f"{s}: {key}", f"cannot resolve {value!r:.60} ({exc})") from None


def default_camera(mesh: Mesh) -> Camera:
    """The camera a scene without one gets: from +Z, raised, the bounding sphere in a 40 degree
    field of view."""
    lo, hi = mesh.bounds
    centre = ((lo + hi) / 2).tolist()
    radius = 0.5 * mesh.scale
    dist = radius / math.sin(math.radians(20)) * 1.05  # fit the bounding sphere in 40 degrees
    origin = [centre[0], centre[1] + 0.3 * dist, centre[2] + dist]
    # 40 degrees across the image's smaller side, so the sphere fits at any aspect
    return Camera.look_at(origin, centre, fov=40.0, fov_axis="smaller")


def load(path_or_name, *, device=None, material=None) -> Scene:
    """A scene from a built-in name, a scene file (``.toml``/``.json``) or a bare mesh file.

    A bare mesh gets :data:`BARE_MESH_MATERIAL` (grey diffuse + GGX, alpha 0.15), the built-in
    environment, and a camera that frames it; a bare glTF (``.gltf``/``.glb``) gets its own
    materials instead (module docstring), recorded in :attr:`Scene.material_records`.

    Parameters
    ----------
    path_or_name : a built-in scene name (``"knot"``, ``"sphere:3"``), a scene file or a mesh
    device : where the scene's tensors go (default: the CPU)
    material : None, a material spec string (:func:`parse_material`, e.g.
        ``"ggx:alpha=0.05,specular=0.9,0.8,0.6"``) or a mapping with the keys of a scene file's
        ``[material]``: one material on every vertex in place of the scene's own (a bare
        mesh's default, a glTF's materials, a scene file's ``[material]``, ``[gradient]`` or
        ``[materials.NAME]``, a built-in's)

    Raises
    ------
    InputError
        naming the file (or key inside it) that is missing or wrong; for a bad ``material``
        spec string, naming ``--material``.
    """
    # a bad override is reported before any file is read: it is the quickest thing to fix
    override = None if material is None else parse_material(material)
    sc = _load(path_or_name)
    if override is not None:
        n = sc.mesh.n_vertices
        by = "--material" if isinstance(material, str) else "material"
        records = tuple({**r, "model": override.model, "override": by} for r in sc.material_records)
        sc = dataclasses.replace(
            sc,
            materials=override.take(torch.zeros(n, dtype=torch.int64)),
            material_records=records,
            gltf=None,  # the file's materials, textures included, are all replaced
            albedo=None,
        )
    return sc.to(device) if device is not None else sc


def _load(path_or_name) -> Scene:
    """The scene ``path_or_name`` stands for, by kind: a built-in name, then a file by its
    suffix (a mesh, or a scene description)."""
    s = str(path_or_name)
    if s.partition(":")[0] in BUILTIN_SCENES and not Path(s).exists():
        return builtin(s)
    p = Path(s)
    if not p.exists():
        raise InputError(
            s, f"no such file, and not a built-in scene ({', '.join(sorted(BUILTIN_SCENES))})"
        )
    suffix = p.suffix.lower()
    if suffix in MESH_SUFFIXES:
        return _bare_mesh_scene(p)
    if suffix not in (".toml", ".json"):
        raise InputError(s, f"unknown scene format {suffix!r}: use .toml, .json or a mesh file")
    return _described_scene(p, s)


def _bare_mesh_scene(p: Path) -> Scene:
    """A mesh file as a scene: :data:`BARE_MESH_MATERIAL` (a glTF: its own materials), the
    built-in environment and :func:`default_camera`."""
    if p.suffix.lower() in GLTF_SUFFIXES:
        asset = load_gltf(p)
        mats, records, asset, albedo = _gltf_scene_materials(asset, {}, "")
        cam = default_camera(asset.mesh)
        return Scene(asset.mesh, mats, "builtin", cam, p.stem, records, asset, albedo)
    mesh = load_mesh(p)
    mats = uniform(BARE_MESH_MATERIAL, mesh.n_vertices)
    return Scene(mesh, mats, "builtin", default_camera(mesh), p.stem)


def _described_scene(p: Path, s: str) -> Scene:
    """The scene of the TOML/JSON description ``p`` (named ``s`` in errors)."""
    d = _read_description(p)
    if "mesh" not in d:
        raise InputError(s, "scene file needs a 'mesh' entry")
    if not isinstance(d.get("name", ""), str):
        raise InputError(f"{s}: name", f"must be a string, got {d['name']!r:.60}")
    mesh_path = _entry_path(p, s, d, "mesh")
    given = [f"[{k}]" for k in ("material", "gradient", "materials") if k in d]
    if len(given) > 1:
        raise InputError(s, f"give one of [material], [gradient] or [materials], not {given}")
    is_gltf = mesh_path.suffix.lower() in GLTF_SUFFIXES
    if "materials" in d and not is_gltf:
        raise InputError(
            f"{s}: materials",
            f"overrides a glTF mesh's materials by name; {mesh_path.name} is not a glTF file "
            "(give [material] or [gradient])",
        )
    try:
        asset = load_gltf(mesh_path) if is_gltf else None
        mesh = asset.mesh if asset is not None else load_mesh(mesh_path)
    except InputError as exc:  # name the scene file as well as the mesh file
        raise InputError(f"{s}: mesh {exc.what}", exc.problem) from None
    records: tuple[dict[str, Any], ...] = ()
    albedo = None
    try:
        if asset is not None and "material" not in d and "gradient" not in d:
            mats, records, asset, albedo = _gltf_scene_materials(asset, d.get("materials", {}), s)
        else:
            mats = _materials(d, mesh)
            if asset is not None:  # the file's materials, all replaced by the scene file's
                by = "[material]" if "material" in d else "[gradient]"
                records = _gltf_records(asset, mats.model, lambda name: by)
                asset = None
    except InputError as exc:
        what = exc.what if exc.what.startswith(f"{s}: ") else f"{s}: {exc.what}"
        raise InputError(what, exc.problem) from None
    env = _environment(p, s, d)
    cam = _camera(d["camera"], f"{s}: camera") if "camera" in d else default_camera(mesh)
    return Scene(mesh, mats, env, cam, d.get("name", p.stem), records, asset, albedo)


# --------------------------------------------------------------------------------------------
# glTF materials


def _texture_slots(mat: GltfMaterial) -> list[str]:
    """The glTF texture slots ``mat`` has a texture in."""
    slots = (
        ("baseColorTexture", mat.base_color_texture),
        ("metallicRoughnessTexture", mat.metallic_roughness_texture),
        ("normalTexture", mat.normal_texture),
    )
    return [name for name, tex in slots if tex is not None]


def _gltf_records(asset: GltfAsset, model: str, override_of) -> tuple[dict[str, Any], ...]:
    """:attr:`Scene.material_records` of ``asset``: every material of the file (the
    specification's default one only where a primitive uses it), ``override_of(name)`` what
    replaced it."""
    counts = torch.bincount(asset.material.cpu(), minlength=len(asset.materials)).tolist()
    last = len(asset.materials) - 1  # the default material, for primitives without one
    return tuple(
        {
            "name": mat.name,
            "model": model,
            "vertices": int(counts[i]),
            "textures": _texture_slots(mat),
            "override": override_of(mat.name),
        }
        for i, mat in enumerate(asset.materials)
        if i < last or counts[i] > 0
    )


def _gltf_names(asset: GltfAsset) -> list[str]:
    """The material names a scene file may override (as :func:`_gltf_records` lists them)."""
    counts = torch.bincount(asset.material.cpu(), minlength=len(asset.materials)).tolist()
    last = len(asset.materials) - 1
    names = [m.name for i, m in enumerate(asset.materials) if i < last or counts[i] > 0]
    return list(dict.fromkeys(names))


def _gltf_scene_materials(
    asset: GltfAsset, overrides: Any, s: str
) -> tuple[Materials, tuple[dict[str, Any], ...], GltfAsset, AlbedoTexture | None]:
    """The per-vertex ``ggx_schlick`` materials of ``asset``, its materials overridden by the
    scene file ``s``'s ``[materials]`` table ``overrides`` (by name), their records, the
    asset with the overrides applied, and its albedo per pixel."""
    if not isinstance(overrides, Mapping):
        raise InputError(f"{s}: materials", "must be a table of [materials.NAME] tables")
    names = _gltf_names(asset)
    for name in overrides:
        if name not in names:
            listed = ", ".join(repr(n) for n in names)
            raise InputError(
                f"{s}: materials.{name}",
                f"{asset.mesh.name} has no material {name!r}; its materials: {listed}",
            )
    checked = {
        name: _override(table, f"{s}: materials.{name}") for name, table in overrides.items()
    }
    if checked:
        asset = dataclasses.replace(
            asset,
            materials=tuple(_overridden(m, checked.get(m.name)) for m in asset.materials),
        )
    f = _vertex_factors(asset)
    # the factors, textures and vertex colours are each in [0, 1], but COLOR_0 given as floats
    # is not clipped by the loader, and the one-ring average rounds in float32
    mats = gltf_materials(f.base_color.clamp(0, 1), f.metallic.clamp(0, 1), f.roughness.clamp(0, 1))
    records = _gltf_records(
        asset, mats.model, lambda name: f"[materials.{name}]" if name in checked else ""
    )
    metallic = f.metallic.clamp(0, 1)
    return mats, records, asset, albedo_texture(asset, mats.diffuse, metallic)


def _quadrature(asset: GltfAsset) -> int:
    """Sub-triangles per face side for :func:`_vertex_factors`: about the square root of the
    texels a face covers (UV area times the texel count of its material's largest texture; the
    90th percentile over the faces), within :data:`GLTF_QUADRATURE`; 1 without textures (the
    factors are then constant over each material)."""
    texels = torch.zeros(len(asset.materials), dtype=torch.float64)
    for i, mat in enumerate(asset.materials):
        for tex in (mat.base_color_texture, mat.metallic_roughness_texture):
            if tex is not None:
                texels[i] = max(float(texels[i]), tex.image.shape[0] * tex.image.shape[1])
    if not bool((texels > 0).any()):
        return 1
    uv = asset.uvs.double().cpu()[asset.mesh.faces.cpu()]  # (F, 3, 2) corner UVs
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    uv_area = 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).abs()  # (F,)
    per_face = uv_area * texels[asset.face_material.cpu()]  # (F,) texels covered
    lo, hi = GLTF_QUADRATURE
    n = math.ceil(math.sqrt(max(float(np.quantile(per_face.numpy(), 0.9)), 0.0)))
    return min(max(n, lo), hi)


def _vertex_factors(asset: GltfAsset):
    """The per-vertex factors of a glTF scene (:data:`GLTF_AVERAGE`): the factors and textures
    averaged over the one-ring, times the vertex colour at the vertex."""
    n = _quadrature(asset)
    plain = dataclasses.replace(asset, colors=torch.ones_like(asset.colors))
    f = vertex_factors(
        plain, average=GLTF_AVERAGE, quadrature=n, batch=max(1, _SAMPLES_PER_BATCH // n**2)
    )
    return dataclasses.replace(f, base_color=f.base_color * asset.colors[:, :3])


def _override(table: Any, where: str) -> dict[str, Any]:
    """A ``[materials.NAME]`` table checked: its keys (:data:`MATERIAL_OVERRIDE_KEYS`) and
    values (``base_color`` a colour, ``metallic``/``roughness`` numbers in [0, 1],
    ``textures`` true or false)."""
    if not isinstance(table, Mapping):
        raise InputError(where, f"must be a table of values, got {type(table).__name__}")
    out: dict[str, Any] = {}
    for key, value in table.items():
        if key not in MATERIAL_OVERRIDE_KEYS:
            known = ", ".join(MATERIAL_OVERRIDE_KEYS)
            raise InputError(f"{where}.{key}", f"unknown key (known: {known})")
        if key == "textures":
            if not isinstance(value, bool):
                raise InputError(f"{where}.textures", f"must be true or false, got {value!r:.60}")
            out[key] = value
        elif key == "base_color":
            colour = _colour(value, f"{where}.base_color")
            if colour.ndim != 1:
                raise InputError(f"{where}.base_color", "must be one number or an RGB triple")
            out[key] = tuple(float(c) for c in colour)
        else:
            ok = isinstance(value, int | float) and not isinstance(value, bool)
            if not ok or not 0.0 <= float(value) <= 1.0:
                raise InputError(f"{where}.{key}", f"must be a number in [0, 1], got {value!r:.60}")
            out[key] = float(value)
    return out


def _overridden(mat: GltfMaterial, o: dict[str, Any] | None) -> GltfMaterial:
    """``mat`` with the factors of the checked override ``o`` (textures dropped where it says
    ``textures = false``)."""
    if not o:
        return mat
    changes: dict[str, Any] = {}
    if "base_color" in o:
        changes["base_color"] = (*o["base_color"], mat.base_color[3])
    if "metallic" in o:
        changes["metallic"] = o["metallic"]
    if "roughness" in o:
        changes["roughness"] = o["roughness"]
    if o.get("textures") is False:
        changes.update(
            base_color_texture=None, metallic_roughness_texture=None, normal_texture=None
        )
    return dataclasses.replace(mat, **changes)


def _environment(p: Path, s: str, d: dict[str, Any]) -> str:
    """The scene file's ``environment``: "builtin", or the path of a file next to the scene
    file or, when there is none of that name, of the bundled map with that stem."""
    env = d.get("environment", "builtin")
    if env == "builtin":
        return env
    env_path = _entry_path(p, s, d, "environment")
    try:
        if os.path.lexists(env_path) and not env_path.is_dir():
            check_input(env_path, limit=IMAGE_LIMIT)  # a pipe or device is not a map file
        found = resolve_envmap(env, relative_to=p.parent)
    except InputError as e:  # a file of another kind: named as this scene file's entry
        raise InputError(f"{s}: environment", f"{env_path} {e.problem}") from None
    if found is not None:
        return found
    raise InputError(
        f"{s}: environment",
        f"no such file {env_path}, and not a bundled map ({', '.join(envmap_names())})",
    )


def _materials(d: dict[str, Any], mesh: Mesh) -> Materials:
    """The scene file's ``[material]`` or ``[gradient]`` on ``mesh``."""
    if "gradient" not in d:
        return uniform(d.get("material", SCENE_FILE_MATERIAL), mesh.n_vertices)
    g = d["gradient"]
    if not isinstance(g, Mapping) or "from" not in g or "to" not in g:
        raise InputError("gradient", "needs 'from' and 'to' materials (and 'axis')")
    unknown = sorted(set(g) - set(GRADIENT_KEYS))
    if unknown:
        raise InputError(f"gradient.{unknown[0]}", f"unknown key; known: {list(GRADIENT_KEYS)}")
    try:
        axis = torch.as_tensor(g.get("axis", [0.0, 1.0, 0.0]), dtype=torch.float64)
    except (TypeError, ValueError, RuntimeError, OverflowError):
        axis = torch.zeros(0)
    if axis.shape != (3,) or not bool(torch.isfinite(axis).all()) or float(axis.norm()) == 0:
        raise InputError("gradient.axis", f"must be a non-zero 3-vector, got {g.get('axis')!r:.60}")
    h = mesh.vertices @ (axis / axis.norm()).to(mesh.vertices)
    t = (h - h.min()) / (h.max() - h.min()).clamp_min(SMALL)
    return gradient(g["from"], g["to"], t)
