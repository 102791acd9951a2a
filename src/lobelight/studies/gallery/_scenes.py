"""The gallery's scenes: their declarations, the data folder and the prepared meshes.

Most scenes are a mesh with one material (:data:`MATERIALS`). A glTF scene (a ``.glb`` mesh,
material :data:`GLTF_MATERIAL`) is a textured asset with its own materials
(:func:`lobelight.scene.load`), looked for in ``$LOBELIGHT_GLTF``, else the data folder's
``gltf/``, else the repository's ``assets/gltf/`` (:data:`GLTF_ASSETS`, with the assets' sources
and licences in its ``LICENSES.md``), as ``NAME/NAME.glb``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from ...data import DATA_ENV
from ...errors import InputError
from ...geometry.camera import Camera
from ...scene import (
    GLTF_SUFFIXES,
    Mesh,
    Scene,
    load,
    load_gltf,
    load_mesh,
    mesh_from_arrays,
    parse_material,
)
from ._settings import SHARP_REFERENCE_SAMPLES

__all__ = [
    "GALLERY_DATA",
    "GAUSSIANS",
    "GLTF_ASSETS",
    "GLTF_ENV",
    "GLTF_MATERIAL",
    "MAPS",
    "MATERIALS",
    "PREPARATION",
    "SCENES",
    "GalleryScene",
    "data_folder",
    "default_camera",
    "find_map",
    "find_mesh",
    "geometry_sha256",
    "prepare_mesh",
    "scene_hash",
    "select",
    "sha256_file",
    "to_scene",
]

_REPO_DATA_NAME = "gallery-data"
#: The repository's own gallery data (``meshes/``, ``envmaps/``, their sources and licences in
#: its ``LICENSES.md``): the folder ``gallery-data`` at the root of the source tree this package
#: runs from, None when it is not there (an installed package). A scene's files are looked for
#: in the data folder first, then here.
GALLERY_DATA: Path | None = Path(__file__).resolve().parents[4] / _REPO_DATA_NAME
if not GALLERY_DATA.is_dir():
    GALLERY_DATA = None

#: The environment variable naming a folder of glTF assets, looked in first for a glTF scene's
#: file (``NAME/NAME.glb`` under it).
GLTF_ENV = "LOBELIGHT_GLTF"
#: The repository's glTF assets (``NAME/NAME.glb``, their sources and licences in its
#: ``LICENSES.md``): the folder ``assets/gltf`` at the root of the source tree this package
#: runs from, None when it is not there (an installed package).
GLTF_ASSETS: Path | None = Path(__file__).resolve().parents[4] / "assets" / "gltf"
if not GLTF_ASSETS.is_dir():
    GLTF_ASSETS = None
#: The material of a glTF scene: the asset's own (its glTF materials and textures).
GLTF_MATERIAL = "gltf"

#: Version of the mesh preparation (:func:`prepare_mesh`); part of every scene's hash, so a
#: change to it marks the references rendered before it as stale.
PREPARATION = 1

#: The gallery's materials, as :func:`lobelight.scene.parse_material` specs.
MATERIALS = {
    # gold-coloured metals: GGX with no Fresnel term (the specular is the metal's colour)
    "sharp_metal": "ggx:alpha=0.03,specular=0.95,0.8,0.6",
    "rough_metal": "ggx:alpha=0.25,specular=0.95,0.8,0.6",
    "diffuse": "diffuse:color=0.7",
    # a dielectric-looking coat: a grey 0.04 specular (Fresnel none) over a Lambert base
    "plastic": "ggx:alpha=0.1,specular=0.04,diffuse=0.5",
}
#: The gallery's maps: file names in the data folder's ``envmaps/``.
MAPS = {
    "park": "rooitou_park_1k.hdr",  # clear sky, small unclipped sun
    "studio": "studio_small_03_1k.hdr",  # softbox and round light
    "overcast": "potsdamer_platz_1k.hdr",  # overcast city square, low frequency
    "grace": "probulator_lowres/grace.hdr",  # Grace Cathedral probe, 256 x 128
    "dawn": "kiara_1_dawn_1k.hdr",  # dawn over a valley: a soft sun 4 degrees above the horizon
    "interior": "st_fagans_interior_1k.hdr",  # a lobby: ceiling lights, a bright glazed stairwell
}


@dataclass(frozen=True)
class GalleryScene:
    """One scene of the gallery: a mesh with one material (or a glTF asset with its own), under
    one map, seen by one camera.

    Attributes
    ----------
    name : unique, used for file names (``[a-z0-9-]``)
    bake : the name of its (mesh, material) bake; scenes of one bake share the model
    mesh : file name in the data folder's ``meshes/`` (or the folder itself); a glTF asset's
        ``NAME/NAME.glb`` in a glTF folder (module docstring)
    envmap : file name in the data folder's ``envmaps/`` (or the folder itself)
    material : a material spec (:func:`lobelight.scene.parse_material`), or
        :data:`GLTF_MATERIAL` for a glTF asset's own materials
    camera : the viewpoint (None: :func:`default_camera`)
    subdivisions : Loop subdivisions of the mesh before anything else
    max_vertices : decimate the mesh to about this many vertices (``fast-simplification``)
    gaussians : the bake's fitted Gaussians per view (:data:`GAUSSIANS`; None: fit_model's
        default)
    description : what the scene shows and how its mesh is prepared
    reference_samples : the reference is rendered with this many times the settings' samples
        per pixel (:data:`SHARP_REFERENCE_SAMPLES` for the sharp metals)
    """

    name: str
    bake: str
    mesh: str
    envmap: str
    material: str
    camera: Camera | None = None
    subdivisions: int = 0
    max_vertices: int | None = None
    gaussians: int | None = None
    description: str = ""
    reference_samples: int = 1

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["camera"] = None if self.camera is None else self.camera.to_dict()
        return d

    def bake_definition(self) -> dict:
        """What the bake depends on: the mesh, its preparation and the material (not the map
        or the camera)."""
        keys = ("bake", "mesh", "material", "subdivisions", "max_vertices", "gaussians")
        return {k: getattr(self, k) for k in keys}

    def view(self) -> Camera:
        return self.camera if self.camera is not None else default_camera()

    @property
    def is_gltf(self) -> bool:
        """Whether the mesh is a glTF asset with its own materials."""
        return Path(self.mesh).suffix.lower() in GLTF_SUFFIXES


def default_camera(azimuth: float = 0.0) -> Camera:
    """The view of a prepared mesh (centred, bounding-box diagonal 2): from +Z turned by
    ``azimuth`` degrees about +Y (towards +X), raised by 0.3 of the distance, its bounding
    sphere filling a 40-degree field of view across the image's smaller side with a 5 % margin
    (as :func:`lobelight.scene.load` frames a bare mesh at ``azimuth = 0``)."""
    dist = 1.0 / math.sin(math.radians(20)) * 1.05
    a = math.radians(azimuth)
    origin = (dist * math.sin(a), 0.3 * dist, dist * math.cos(a))
    return Camera.look_at(origin, (0.0, 0.0, 0.0), fov=40.0, fov_axis="smaller")


#: Gaussians per view of a material's bakes where they are not ``fit_model``'s default
#: (``"auto"``: chosen from the material's lobe, :func:`lobelight.fit.choose_gaussians`), by
#: the material's key in :data:`MATERIALS`; empty: every bake takes the default.
GAUSSIANS: dict[str, int] = {}


def _bake(bake, mesh, material, maps, **kw) -> tuple[GalleryScene, ...]:
    """One (mesh, material) bake rendered under each of ``maps``."""
    return tuple(
        GalleryScene(
            f"{bake}-{m}",
            bake,
            mesh,
            MAPS[m],
            MATERIALS[material],
            gaussians=GAUSSIANS.get(material),
            **kw,
        )
        for m in maps
    )


_BUNNY = {
    "max_vertices": 14000,
    "description": "Stanford bunny (watertight remesh), decimated from 29,834 to about 14,000 "
    "vertices",
}
_SUZANNE = {
    "subdivisions": 2,
    "description": "Blender's Suzanne (open, low-poly: 505 vertices after welding), two Loop "
    "subdivisions (7,814 vertices) so that per-vertex transport resolves its curvature",
}
_SPOT = {
    "camera": default_camera(150.0),  # its face looks along -Z
    "description": "Spot the cow (Keenan Crane), 11,533 vertices, seen from the front",
}
_TEAPOT = {"description": "Newell's teapot (watertight version), 7,850 vertices"}
_SCORPION = {
    "max_vertices": 12000,
    "camera": default_camera(30.0),  # claws, legs and the raised tail side by side
    "description": "a scorpion (YahooJAPAN, remeshed by Oded Stein; gallery-data/LICENSES.md): "
    "thin legs, claws and tail over deep gaps, decimated from 49,997 to about 12,000 vertices",
}


def _gltf(bake, asset, maps, **kw) -> tuple[GalleryScene, ...]:
    """The glTF asset ``assets/gltf/ASSET/ASSET.glb`` with its own materials under each of
    ``maps``."""
    return tuple(
        GalleryScene(f"{bake}-{m}", bake, f"{asset}/{asset}.glb", MAPS[m], GLTF_MATERIAL, **kw)
        for m in maps
    )


_HELMET = {
    "camera": default_camera(25.0),
    "description": "DamagedHelmet (glTF sample asset): one textured metallic-roughness "
    "material, 14,353 vertices, base colour and metallic-roughness textures of 2048^2",
}
_TRUCK = {
    "camera": default_camera(45.0),
    "description": "CesiumMilkTruck (glTF sample asset): four materials (textured body and "
    "wheels sharing one 2048^2 texture, dark glass, window trim), 3,564 vertices",
}
_BOTTLE = {
    "camera": default_camera(20.0),
    "description": "WaterBottle (glTF sample asset): a metal cap and a painted bottle in one "
    "material with base colour and metallic-roughness textures of 2048^2, 2,508 vertices",
}
_AVOCADO = {
    "camera": default_camera(20.0),
    "description": "Avocado (glTF sample asset): a halved avocado, one material with base "
    "colour and metallic-roughness textures of 2048^2 on 406 vertices",
}

#: The gallery: 10 (mesh, material) bakes, each under 3 maps, and 4 textured glTF assets,
#: each under 2. The first 8 bakes see every (material, map) pair once, so each map four
#: times; the scorpion's two add a rough metal and a plastic on a mesh with thin parts and
#: deep concavities. The glTF assets (module docstring) are each under the park's sharp sun
#: and an interior or overcast map.
SCENES: tuple[GalleryScene, ...] = (
    *_bake(
        "bunny-sharp-metal",
        "bunny_hr.obj",
        "sharp_metal",
        ("park", "grace", "interior"),
        reference_samples=SHARP_REFERENCE_SAMPLES,
        **_BUNNY,
    ),
    *_bake("bunny-plastic", "bunny_hr.obj", "plastic", ("studio", "overcast", "dawn"), **_BUNNY),
    *_bake("spot-rough-metal", "spot.obj", "rough_metal", ("park", "studio", "dawn"), **_SPOT),
    *_bake("spot-diffuse", "spot.obj", "diffuse", ("overcast", "grace", "interior"), **_SPOT),
    *_bake("teapot-diffuse", "teapot.obj", "diffuse", ("park", "studio", "dawn"), **_TEAPOT),
    *_bake(
        "teapot-sharp-metal",
        "teapot.obj",
        "sharp_metal",
        ("studio", "overcast", "dawn"),
        reference_samples=SHARP_REFERENCE_SAMPLES,
        **_TEAPOT,
    ),
    *_bake(
        "suzanne-rough-metal",
        "suzanne.obj",
        "rough_metal",
        ("overcast", "grace", "interior"),
        **_SUZANNE,
    ),
    *_bake("suzanne-plastic", "suzanne.obj", "plastic", ("park", "grace", "interior"), **_SUZANNE),
    *_bake(
        "scorpion-rough-metal",
        "scorpion.obj",
        "rough_metal",
        ("dawn", "interior", "park"),
        **_SCORPION,
    ),
    *_bake(
        "scorpion-plastic",
        "scorpion.obj",
        "plastic",
        ("interior", "studio", "overcast"),
        **_SCORPION,
    ),
    *_gltf("helmet", "DamagedHelmet", ("park", "interior"), **_HELMET),
    *_gltf("truck", "CesiumMilkTruck", ("park", "overcast"), **_TRUCK),
    *_gltf("bottle", "WaterBottle", ("park", "interior"), **_BOTTLE),
    *_gltf("avocado", "Avocado", ("park", "overcast"), **_AVOCADO),
)


def select(names=None, scenes: tuple[GalleryScene, ...] = SCENES) -> list[GalleryScene]:
    """The scenes named (each a scene's or a bake's name), all of them for None or empty."""
    if not names:
        return list(scenes)
    out: list[GalleryScene] = []
    for n in names:
        if isinstance(n, GalleryScene):
            hit = [n]
        else:
            hit = [s for s in scenes if n in (s.name, s.bake)]
        if not hit:
            raise InputError(
                "--scenes", f"no gallery scene or bake {n!r}; known: {[s.name for s in scenes]}"
            )
        out += [s for s in hit if s not in out]
    bakes: dict[str, dict] = {}
    for s in out:
        if bakes.setdefault(s.bake, s.bake_definition()) != s.bake_definition():
            raise InputError(s.name, f"bake {s.bake!r} is declared with two definitions")
    return out


def data_folder(data=None) -> Path | None:
    """The data folder: ``data``, else ``$LOBELIGHT_DATA``, else None (the scenes' files are
    then looked for in :data:`GALLERY_DATA` only); InputError when ``data`` or the variable
    names no folder."""
    given = "--data"
    if data is None:
        data = os.environ.get(DATA_ENV) or None
        given = f"${DATA_ENV}"
        if data is None:
            return None
    p = Path(data).expanduser()
    if not p.is_dir():
        raise InputError(given, f"no such folder: {str(p)!r}")
    return p


def _find(data: Path | None, sub: str, name: str, what: str) -> Path:
    """The file ``name``: in the data folder (``data/sub/name``, else ``data/name``), else in
    the repository's :data:`GALLERY_DATA` (``sub/name``)."""
    places = [] if data is None else [data / sub / name, data / name]
    places += [] if GALLERY_DATA is None else [GALLERY_DATA / sub / name]
    for p in places:
        if p.is_file():
            return p
    if data is None:
        where = f"a data folder (none given: --data DIR or ${DATA_ENV})"
    else:
        where = f"the data folder {str(data / sub)!r}"
    if GALLERY_DATA is None:
        repo = f"the repository's {_REPO_DATA_NAME}/{sub} (not found next to the package)"
    else:
        repo = f"the repository's {str(GALLERY_DATA / sub)!r}"
    raise InputError(what, f"{name!r} is neither in {where} nor in {repo}")


def find_map(scene: GalleryScene, data: Path | None) -> Path:
    """The scene's map file (:func:`_find`)."""
    return _find(data, "envmaps", scene.envmap, f"{scene.name}: envmap")


def find_mesh(scene: GalleryScene, data: Path | None) -> Path:
    """The scene's mesh file (:func:`_find`; a glTF asset: :func:`_find_gltf`)."""
    if scene.is_gltf:
        return _find_gltf(data, scene.mesh, f"{scene.name}: mesh")
    return _find(data, "meshes", scene.mesh, f"{scene.name}: mesh")


def _gltf_folders(data: Path | None) -> list[tuple[str, Path]]:
    """Where glTF assets are looked for, in order, each with how it was named."""
    out = []
    given = os.environ.get(GLTF_ENV) or None
    if given is not None:
        folder = Path(given).expanduser()
        if not folder.is_dir():
            raise InputError(f"${GLTF_ENV}", f"no such folder: {str(folder)!r}")
        out.append((f"${GLTF_ENV}", folder))
    if data is not None:
        out.append(("the data folder's gltf/", data / "gltf"))
    if GLTF_ASSETS is not None:
        out.append(("the repository's assets/gltf/", GLTF_ASSETS))
    return out


def _find_gltf(data: Path | None, name: str, what: str) -> Path:
    """The glTF asset ``name`` (``NAME/NAME.glb``): under ``$LOBELIGHT_GLTF``, else the data
    folder's ``gltf/``, else the repository's :data:`GLTF_ASSETS`."""
    places = _gltf_folders(data)
    for _, folder in places:
        if (folder / name).is_file():
            return folder / name
    looked = "; ".join(f"{label} ({str(folder)!r})" for label, folder in places)
    if GLTF_ASSETS is None:
        looked += "; the repository's assets/gltf/ (not found next to the package)"
    raise InputError(what, f"{name!r} is in none of: {looked} (set ${GLTF_ENV} to its folder)")


def sha256_file(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def scene_hash(scene: GalleryScene, data: Path | None) -> str:
    """sha256 of the scene's definition, :data:`PREPARATION` and its mesh and map files'
    contents: it changes whenever anything that a reference shows changes (not the bake's
    Gaussians per view, nor the reference's samples per pixel)."""
    mesh = find_mesh(scene, data)
    # the samples are the reference's settings, checked with them (reference_status)
    shown = {
        k: v for k, v in scene.to_dict().items() if k not in ("gaussians", "reference_samples")
    }
    d = {
        "definition": shown | {"name": None, "description": None},
        "preparation": PREPARATION,
        "mesh_sha256": sha256_file(mesh),
        "map_sha256": sha256_file(find_map(scene, data)),
    }
    return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()


def prepare_mesh(scene: GalleryScene, data: Path | None) -> Mesh:
    """The scene's mesh as the gallery uses it: loaded (welded, cleaned), Loop-subdivided
    ``subdivisions`` times, decimated to about ``max_vertices``, then centred on its bounding
    box and scaled to a bounding-box diagonal of 2. A glTF asset is loaded as
    :func:`lobelight.scene.load_gltf` welds it (its own normals and UV seams kept) and only
    centred and scaled: it is neither subdivided nor decimated (its UVs would not follow)."""
    path = find_mesh(scene, data)
    if scene.is_gltf:
        if scene.subdivisions or scene.max_vertices is not None:
            raise InputError(
                scene.name, "a glTF asset is neither subdivided nor decimated by the gallery"
            )
        return _normalised(load_gltf(path).mesh)
    m = load_mesh(path)
    v = m.vertices.double().numpy()  # (V, 3)
    f = m.faces.numpy()  # (F, 3)
    if scene.subdivisions:
        v, f = trimesh.remesh.subdivide_loop(v, f, iterations=int(scene.subdivisions))
    if scene.max_vertices is not None and len(v) > scene.max_vertices:
        try:
            import fast_simplification  # optional: the gallery extra
        except ImportError:
            raise InputError(
                f"{scene.name}: max_vertices",
                "decimating needs fast-simplification: pip install 'lobelight[gallery]'",
            ) from None
        keep = scene.max_vertices / len(v)
        v, f = fast_simplification.simplify(
            v.astype(np.float32), f.astype(np.int32), target_reduction=1.0 - keep
        )
        v = v.astype(np.float64)
    lo, hi = v.min(0), v.max(0)
    v = (v - (lo + hi) / 2) * (2.0 / float(np.linalg.norm(hi - lo)))
    return mesh_from_arrays(v.astype(np.float32), f, name=Path(scene.mesh).stem)


def _normalised(mesh: Mesh) -> Mesh:
    """``mesh`` centred on its bounding box and scaled to a bounding-box diagonal of 2, its
    normals, faces and vertex order unchanged."""
    v = mesh.vertices.double()
    lo, hi = v.amin(0), v.amax(0)
    v = (v - (lo + hi) / 2) * (2.0 / float((hi - lo).norm()))
    return Mesh(v.to(mesh.vertices.dtype), mesh.faces, mesh.normals, mesh.name)


def geometry_sha256(mesh: Mesh) -> str:
    """sha256 of a mesh's vertices, faces and normals (what the renders see); a negative zero
    counts as zero (the same geometry, whichever sign a loader's arithmetic left it)."""
    h = hashlib.sha256()
    for t in (mesh.vertices, mesh.faces, mesh.normals):
        h.update(np.ascontiguousarray((t + 0).cpu().numpy()).tobytes())
    return h.hexdigest()


def to_scene(scene: GalleryScene, data: Path | None, mesh: Mesh | None = None) -> Scene:
    """The :class:`lobelight.scene.Scene` of a gallery scene (``mesh``: its prepared mesh, when
    already at hand)."""
    mesh = prepare_mesh(scene, data) if mesh is None else mesh
    env = str(find_map(scene, data))
    if scene.is_gltf:
        return _gltf_scene(scene, data, mesh, env)
    mats = parse_material(scene.material, mesh.n_vertices, what=f"{scene.name}: material")
    return Scene(mesh, mats, env, scene.view(), scene.name)


def _gltf_scene(scene: GalleryScene, data: Path | None, mesh: Mesh, env: str) -> Scene:
    """A glTF scene: the asset as :func:`lobelight.scene.load` reads a bare ``.glb`` (its own
    materials and textures), on the prepared ``mesh`` (the same vertices, centred and
    scaled)."""
    if scene.material != GLTF_MATERIAL:
        raise InputError(
            f"{scene.name}: material", f"a glTF scene takes {GLTF_MATERIAL!r} (its own materials)"
        )
    sc = load(find_mesh(scene, data))
    if sc.gltf is None or sc.mesh.n_vertices != mesh.n_vertices:
        raise InputError(f"{scene.name}: mesh", "the prepared mesh is not the asset's")
    return dataclasses.replace(
        sc,
        mesh=mesh,
        gltf=dataclasses.replace(sc.gltf, mesh=mesh),
        environment=env,
        camera=scene.view(),
        name=scene.name,
    )
