"""glTF 2.0 files: the default scene's triangles in world space, and their materials.

:func:`read_gltf` reads a ``.gltf`` (external buffers and images, data URIs) or ``.glb`` into
:class:`GltfGeometry` (unwelded triangles with their attributes) and a list of
:class:`GltfMaterial` (metallic-roughness factors, textures as linear float tensors with their
:class:`Sampler`); :func:`sample_texture` reads a texture at UVs the way the sampler says.
:func:`lobelight.scene.load_gltf` welds the result into an asset.

Library: pygltflib reads the JSON document into typed records that carry the specification's
defaults (a material's factors, a sampler's wrap modes, a primitive's mode). trimesh's glTF
loader is not used: it drops the samplers (wrap modes and filters) and the material extensions
without a word, keeps textures and vertex colours as 8-bit visuals, and a broken file makes it
raise whatever numpy raises. The container (GLB chunks), the buffers (the GLB binary chunk,
data URIs, files beside the document), accessors and images are read here, every offset and
count checked against what holds it before anything is allocated, so that a bad file gives one
:class:`~lobelight.errors.InputError` naming the file and the part (``meshes[0].primitives[1]:
POSITION accessor 3 ...``).

Read: every triangle primitive (modes TRIANGLES, TRIANGLE_STRIP, TRIANGLE_FAN) of the default
scene with its node transforms (a mirroring transform's winding is flipped); POSITION, NORMAL,
TEXCOORD_0, COLOR_0 (any component type the specification allows, normalized integers
included); materials' ``baseColorFactor``/``baseColorTexture`` (sRGB decoded to linear),
``metallicFactor``, ``roughnessFactor``, ``metallicRoughnessTexture`` (B = metal, G = rough),
``normalTexture`` (read, linear), ``doubleSided``, and ``KHR_texture_transform`` on textures.
Named in one warning, not used: emissive light, alpha modes other than OPAQUE, occlusion
textures, textures on a second UV set, morph targets (the rest pose is read), and every other
extension the file uses (``KHR_materials_*``, ``KHR_lights_punctual``, ...). Refused with an
error: points and lines, sparse accessors, and extensions the file declares required
(``KHR_draco_mesh_compression``: the geometry is not in the accessors).
"""

from __future__ import annotations

import base64
import binascii
import importlib
import io
import json
import math
import struct
import urllib.parse
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from .._io import check_input, read_input
from ..errors import InputError

__all__ = [
    "GLTF_SUFFIXES",
    "MAX_CORNERS",
    "MAX_GLTF_BYTES",
    "MAX_TEXTURE_PIXELS",
    "GltfGeometry",
    "GltfMaterial",
    "Sampler",
    "Texture",
    "read_gltf",
    "sample_texture",
    "wrap_texels",
    "wrap_uv",
]

GLTF_SUFFIXES = (".gltf", ".glb")
#: Largest glTF document, buffer or image file read (bytes).
MAX_GLTF_BYTES = 2 * 1024**3
#: Largest texture (pixels): a 16K x 16K texture, as float32 RGBA, is already 4 GiB.
MAX_TEXTURE_PIXELS = 16384 * 16384
#: Most triangle corners the default scene may expand to (instancing multiplies a mesh's):
#: 11 million triangles, far beyond a per-vertex transport's reach, and a few GB while welding.
MAX_CORNERS = 1 << 25

_COMPONENTS = {
    5120: np.dtype("i1"),
    5121: np.dtype("u1"),
    5122: np.dtype("<i2"),
    5123: np.dtype("<u2"),
    5125: np.dtype("<u4"),
    5126: np.dtype("<f4"),
}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
_WRAP = {33071: "clamp", 33648: "mirror", 10497: "repeat"}
_MAG = {9728: "nearest", 9729: "linear"}
# the base level's filter of a minification filter (mipmaps are not built)
_MIN = {9728: "nearest", 9729: "linear", 9984: "nearest", 9985: "linear", 9986: "nearest",
        9987: "linear"}  # fmt: skip
_TRIANGLES, _STRIP, _FAN = 4, 5, 6
_MODE_NAMES = {0: "POINTS", 1: "LINES", 2: "LINE_LOOP", 3: "LINE_STRIP"}
_GLB_MAGIC, _GLB_JSON, _GLB_BIN = b"glTF", 0x4E4F534A, 0x004E4942
# extensions read here (quantized attributes need nothing more than the accessors' types)
_READ_EXTENSIONS = {"KHR_mesh_quantization", "KHR_texture_transform"}


@dataclass(frozen=True)
class Sampler:
    """How a texture is read between and beyond its texels.

    ``wrap_s``/``wrap_t`` (along U and V): ``"repeat"``, ``"clamp"`` or ``"mirror"``;
    ``mag_filter``/``min_filter``: ``"linear"`` or ``"nearest"`` (a mipmapped minification
    filter is read as its base level's filter; an unset filter is linear).
    """

    wrap_s: str = "repeat"
    wrap_t: str = "repeat"
    mag_filter: str = "linear"
    min_filter: str = "linear"


@dataclass(frozen=True, eq=False)
class Texture:
    """A decoded texture: ``image`` (H, W, C) float32 in [0, 1], linear (colour textures are
    sRGB-decoded), row 0 at V = 0; ``source`` names the image (``images[2] 'wood.png'``);
    ``tex_coord`` the UV set it reads; ``uv_transform`` the (2, 3) row-major affine map
    applied to UVs before reading (``KHR_texture_transform``), None for none."""

    image: torch.Tensor
    sampler: Sampler
    source: str
    tex_coord: int = 0
    uv_transform: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None


@dataclass(frozen=True, eq=False)
class GltfMaterial:
    """One glTF metallic-roughness material.

    Attributes
    ----------
    name : the material's name (``materials[i]`` when it has none; ``default`` for the
        specification's default material of primitives without one)
    base_color : (4,) linear RGBA ``baseColorFactor``
    metallic, roughness : ``metallicFactor``, ``roughnessFactor``
    base_color_texture : RGBA (H, W, 4), sRGB-decoded, or None
    metallic_roughness_texture : (H, W, 3) linear (B = metal, G = rough), or None
    normal_texture : (H, W, 3) linear tangent-space normals in [0, 1], or None;
        ``normal_scale`` its scale
    double_sided : ``doubleSided``
    unsupported : what the material asks for that is not used (emissive, alpha mode,
        occlusion, extensions), each named
    """

    name: str
    base_color: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
    metallic: float = 1.0
    roughness: float = 1.0
    base_color_texture: Texture | None = None
    metallic_roughness_texture: Texture | None = None
    normal_texture: Texture | None = None
    normal_scale: float = 1.0
    double_sided: bool = False
    unsupported: tuple[str, ...] = ()


@dataclass(frozen=True, eq=False)
class GltfGeometry:
    """The default scene's triangles in world space, one vertex per primitive vertex and node
    (unwelded).

    Attributes
    ----------
    positions : (N, 3) float64
    normals : (N, 3) float64 unit normals from the file; NaN rows where a primitive has none
    uvs : (N, 2) float64 TEXCOORD_0 (zeros where a primitive has none)
    colors : (N, 4) float64 linear COLOR_0 RGBA (ones where a primitive has none)
    material : (N,) int64 index into the materials read with it
    faces : (F, 3) int64, counter-clockwise seen from the front
    """

    positions: np.ndarray
    normals: np.ndarray
    uvs: np.ndarray
    colors: np.ndarray
    material: np.ndarray
    faces: np.ndarray


# --------------------------------------------------------------------------------------------
# small checked readers of JSON values


def _int(value, where: str, lo: int = 0, hi: int = 1 << 62) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise InputError(where, f"must be an integer in [{lo}, {hi}], got {value!r:.40}")
    return value


def _index(value, items, where: str) -> int:
    n = len(items) if isinstance(items, list) else 0
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < n:
        raise InputError(where, f"index {value!r:.40} out of range (there are {n})")
    return value


def _floats(value, n: int, where: str) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        a = np.zeros(0)
    if a.shape != (n,) or not np.isfinite(a).all():
        raise InputError(where, f"must be {n} finite numbers, got {value!r:.60}")
    return a


def _float(value, where: str) -> float:
    return float(_floats([value] if not isinstance(value, list) else value, 1, where)[0])


def _list(value, where: str) -> list:
    if value is None:
        return []
    if not isinstance(value, list):
        raise InputError(where, f"must be a list, got {type(value).__name__}")
    return value


def _extension_names(obj) -> list[str]:
    ext = getattr(obj, "extensions", None)
    return sorted(str(k) for k in ext) if isinstance(ext, dict) else []


# --------------------------------------------------------------------------------------------
# the container and its buffers


class _Document:
    """The parsed document with its buffers, read lazily and each once."""

    def __init__(self, path: Path):
        self.path = path
        self.name = str(path)
        data = read_input(path, limit=MAX_GLTF_BYTES)
        if not data:
            raise InputError(self.name, "file is empty")
        self.blob: bytes | None = None
        text = self._split_glb(data) if data[:4] == _GLB_MAGIC else data
        # imported here, not with the module: its import would be part of every command's start
        pygltflib = importlib.import_module("pygltflib")

        try:
            doc = json.loads(text.decode("utf-8"))
            if not isinstance(doc, dict):
                raise ValueError("the document is not a JSON object")
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # pygltflib warns about what it coerces
                self.gltf = pygltflib.GLTF2.gltf_from_json(json.dumps(doc))
        except RecursionError:
            raise InputError(self.name, "not a glTF document: JSON nested too deeply") from None
        except Exception as exc:  # json, dataclasses-json and pygltflib raise many types
            msg = f"{type(exc).__name__}: {exc}"[:200]
            raise InputError(self.name, f"not a glTF document ({msg})") from None
        asset = doc.get("asset")  # pygltflib fills in a default asset record: read the JSON
        version = asset.get("version") if isinstance(asset, dict) else None
        if not isinstance(version, str) or not version.startswith("2"):
            raise InputError(f"{self.name}: asset.version", f"needs glTF 2.x, got {version!r:.40}")
        self._buffers: dict[int, memoryview] = {}

    def _split_glb(self, data: bytes) -> bytes:
        """The JSON chunk of a GLB container (its BIN chunk kept as :attr:`blob`)."""
        if len(data) < 20:
            raise InputError(self.name, "GLB file cut short in its header")
        version, length = struct.unpack_from("<II", data, 4)
        if version != 2:
            raise InputError(self.name, f"GLB container version {version}, expected 2")
        if length > len(data):
            raise InputError(self.name, f"GLB declares {length:,} bytes and holds {len(data):,}")
        n_json, kind = struct.unpack_from("<II", data, 12)
        if kind != _GLB_JSON or 20 + n_json > length:
            raise InputError(self.name, "GLB's first chunk is not a whole JSON chunk")
        start = 20 + n_json
        if start + 8 <= length:
            n_bin, kind = struct.unpack_from("<II", data, start)
            if kind == _GLB_BIN:
                if start + 8 + n_bin > length:
                    raise InputError(self.name, "GLB's BIN chunk runs past the file's end")
                self.blob = data[start + 8 : start + 8 + n_bin]
        return data[20:start]

    def external(self, uri: str, where: str) -> bytes:
        """The bytes a URI names: a data URI, or a file beside the document."""
        if uri.startswith("data:"):
            head, sep, payload = uri.partition(",")
            if not sep or not head.endswith(";base64"):
                raise InputError(where, "data URI is not base64")
            try:
                return base64.b64decode(payload, validate=True)
            except (binascii.Error, ValueError):
                raise InputError(where, "data URI holds bad base64") from None
        if "://" in uri:
            raise InputError(where, f"names a remote file {uri!r:.80}: only local files are read")
        target = self.path.parent / urllib.parse.unquote(uri)
        try:
            return read_input(target, limit=MAX_GLTF_BYTES)
        except InputError as exc:
            raise InputError(f"{where} {str(target)!r}", exc.problem) from None

    def buffer(self, i: int, where: str) -> memoryview:
        if i in self._buffers:
            return self._buffers[i]
        buffers = _list(self.gltf.buffers, f"{self.name}: buffers")
        b = buffers[_index(i, buffers, f"{where}: buffer")]
        here = f"{self.name}: buffers[{i}]"
        length = _int(getattr(b, "byteLength", None), f"{here}: byteLength", 1, MAX_GLTF_BYTES)
        uri = getattr(b, "uri", None)
        if uri is None:
            if i != 0 or self.blob is None:
                raise InputError(here, "has no uri and there is no GLB binary chunk for it")
            data = self.blob
        elif isinstance(uri, str):
            data = self.external(uri, here)
        else:
            raise InputError(f"{here}: uri", f"must be a string, got {uri!r:.40}")
        if len(data) < length:
            raise InputError(here, f"declares {length:,} bytes and holds {len(data):,}")
        self._buffers[i] = memoryview(data)[:length]
        return self._buffers[i]

    def view(self, i, where: str) -> tuple[memoryview, int | None]:
        """Buffer view ``i``'s bytes and its byte stride (None when unset)."""
        views = _list(self.gltf.bufferViews, f"{self.name}: bufferViews")
        i = _index(i, views, f"{where}: bufferView")
        v = views[i]
        here = f"{self.name}: bufferViews[{i}]"
        buf = self.buffer(getattr(v, "buffer", None), here)
        off = _int(getattr(v, "byteOffset", 0) or 0, f"{here}: byteOffset")
        length = _int(getattr(v, "byteLength", None), f"{here}: byteLength", 1)
        if off + length > len(buf):
            raise InputError(here, f"bytes [{off:,}, {off + length:,}) exceed its buffer's "
                             f"{len(buf):,}")  # fmt: skip
        stride = getattr(v, "byteStride", None)
        if stride is not None:
            stride = _int(stride, f"{here}: byteStride", 4, 252)
        return buf[off : off + length], stride

    def accessor(self, i, where: str, types: tuple[str, ...]) -> np.ndarray:
        """Accessor ``i`` as a (count, width) array of its component type (normalized integers
        read as floats in [0, 1] or [-1, 1])."""
        accessors = _list(self.gltf.accessors, f"{self.name}: accessors")
        i = _index(i, accessors, where)
        a = accessors[i]
        here = f"{where} accessor {i}"
        kind = getattr(a, "type", None)
        if kind not in types:
            raise InputError(here, f"type {kind!r:.20} where {' or '.join(types)} is needed")
        ctype = getattr(a, "componentType", None)
        if ctype not in _COMPONENTS:
            raise InputError(here, f"unknown componentType {ctype!r:.20}")
        if getattr(a, "sparse", None) is not None:
            raise InputError(here, "sparse accessors are not read")
        count = _int(getattr(a, "count", None), f"{here}: count", 1)
        dtype, width = _COMPONENTS[ctype], _WIDTH[kind]
        if count * width > MAX_CORNERS * 4:
            raise InputError(here, f"count {count:,} is more than is read ({MAX_CORNERS:,})")
        if getattr(a, "bufferView", None) is None:  # all zeros, for sparse accessors to fill
            raise InputError(here, "has no bufferView (sparse accessors are not read)")
        data, stride = self.view(a.bufferView, here)
        off = _int(getattr(a, "byteOffset", 0) or 0, f"{here}: byteOffset")
        elem = dtype.itemsize * width
        stride = stride or elem
        if stride < elem or off % dtype.itemsize:
            raise InputError(here, f"byteStride {stride} / byteOffset {off} do not fit its type")
        end = off + stride * (count - 1) + elem
        if end > len(data):
            raise InputError(here, f"count {count:,} exceeds its buffer view ({end:,} bytes "
                             f"needed, {len(data):,} there)")  # fmt: skip
        out = np.ndarray((count, width), dtype, buffer=data, offset=off,
                         strides=(stride, dtype.itemsize)).copy()  # fmt: skip
        if getattr(a, "normalized", False) and dtype.kind in "iu":
            top = float(np.iinfo(dtype).max)
            return np.maximum(out / top, -1.0)
        return out


# --------------------------------------------------------------------------------------------
# the scene graph


def _local_matrix(node, where: str) -> np.ndarray:
    """A node's (4, 4) local transform: its matrix (column-major), or T * R * S."""
    if getattr(node, "matrix", None) is not None:
        return _floats(node.matrix, 16, f"{where}: matrix").reshape(4, 4).T
    t = np.eye(4)
    if getattr(node, "translation", None) is not None:
        t[:3, 3] = _floats(node.translation, 3, f"{where}: translation")
    if getattr(node, "rotation", None) is not None:
        x, y, z, w = _floats(node.rotation, 4, f"{where}: rotation")
        n = x * x + y * y + z * z + w * w
        if not n > 0:
            raise InputError(f"{where}: rotation", "is a zero quaternion")
        s = 2.0 / n
        t[:3, :3] = [
            [1 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w)],
            [s * (x * y + z * w), 1 - s * (x * x + z * z), s * (y * z - x * w)],
            [s * (x * z - y * w), s * (y * z + x * w), 1 - s * (x * x + y * y)],
        ]
    if getattr(node, "scale", None) is not None:
        t[:3, :3] = t[:3, :3] * _floats(node.scale, 3, f"{where}: scale")[None, :]
    return t


def _scene_roots(gltf, name: str) -> list[int]:
    nodes = _list(gltf.nodes, f"{name}: nodes")
    scenes = _list(gltf.scenes, f"{name}: scenes")
    if scenes:
        s = gltf.scene if gltf.scene is not None else 0
        s = _index(s, scenes, f"{name}: scene")
        roots = _list(getattr(scenes[s], "nodes", None), f"{name}: scenes[{s}].nodes")
        return [_index(r, nodes, f"{name}: scenes[{s}].nodes") for r in roots]
    # no scene: every node that is nobody's child
    children = {
        c for n in nodes for c in (getattr(n, "children", None) or []) if isinstance(c, int)
    }
    return [i for i in range(len(nodes)) if i not in children]


def _mesh_instances(gltf, name: str) -> list[tuple[int, np.ndarray, str]]:
    """(mesh index, (4, 4) world transform, node name) for each node of the default scene that
    holds a mesh, walking the node tree from the scene's roots."""
    nodes = _list(gltf.nodes, f"{name}: nodes")
    meshes = _list(gltf.meshes, f"{name}: meshes")
    out = []
    seen: set[int] = set()
    stack = [(r, np.eye(4)) for r in reversed(_scene_roots(gltf, name))]
    while stack:
        i, parent = stack.pop()
        where = f"{name}: nodes[{i}]"
        if i in seen:
            raise InputError(where, "is reached twice: the node graph is not a tree")
        seen.add(i)
        node = nodes[i]
        world = parent @ _local_matrix(node, where)
        if getattr(node, "mesh", None) is not None:
            out.append((_index(node.mesh, meshes, f"{where}: mesh"), world, where))
        kids = _list(getattr(node, "children", None), f"{where}: children")
        stack.extend((_index(c, nodes, f"{where}: children"), world) for c in reversed(kids))
    return out


# --------------------------------------------------------------------------------------------
# primitives


def _triangles(doc: _Document, prim, where: str, n_vertices: int) -> np.ndarray:
    """A primitive's (F, 3) triangles from its indices (or its vertex order) and mode."""
    mode = getattr(prim, "mode", _TRIANGLES)
    mode = _TRIANGLES if mode is None else mode
    if mode in _MODE_NAMES:
        raise InputError(where, f"mode {_MODE_NAMES[mode]}: only triangles are read")
    if mode not in (_TRIANGLES, _STRIP, _FAN):
        raise InputError(where, f"unknown primitive mode {mode!r:.20}")
    if getattr(prim, "indices", None) is None:
        idx = np.arange(n_vertices, dtype=np.int64)
    else:
        raw = doc.accessor(prim.indices, f"{where}: indices", ("SCALAR",))
        if raw.dtype.kind != "u":
            raise InputError(f"{where}: indices", "must be unsigned integers")
        idx = raw[:, 0].astype(np.int64)
        if idx.size and int(idx.max()) >= n_vertices:
            raise InputError(f"{where}: indices", f"index {int(idx.max())} out of range "
                             f"(POSITION has {n_vertices})")  # fmt: skip
    if mode == _TRIANGLES:
        if len(idx) % 3:
            raise InputError(where, f"{len(idx)} indices is not a whole number of triangles")
        return idx.reshape(-1, 3)
    if len(idx) < 3:
        raise InputError(where, f"a triangle strip or fan needs 3 indices, has {len(idx)}")
    k = np.arange(len(idx) - 2)
    if mode == _FAN:
        return np.stack([np.full_like(k, idx[0]), idx[k + 1], idx[k + 2]], axis=1)
    odd = k % 2 == 1  # every other strip triangle is wound the other way
    a, b = np.where(odd, idx[k + 1], idx[k]), np.where(odd, idx[k], idx[k + 1])
    return np.stack([a, b, idx[k + 2]], axis=1)


def _attribute(doc, attrs, key, where, types, n):
    i = getattr(attrs, key, None)
    if i is None:
        return None
    a = doc.accessor(i, f"{where}: {key}", types)
    if len(a) != n:
        raise InputError(f"{where}: {key}", f"has {len(a):,} items and POSITION {n:,}")
    a = a.astype(np.float64)
    if not np.isfinite(a).all():
        raise InputError(f"{where}: {key}", "holds NaN or Inf")
    return a


def _primitive(doc: _Document, prim, where: str, world: np.ndarray, material: int) -> dict:
    """One primitive's vertices and triangles in world space."""
    attrs = getattr(prim, "attributes", None)
    if getattr(attrs, "POSITION", None) is None:
        raise InputError(where, "has no POSITION attribute")
    pos = doc.accessor(attrs.POSITION, f"{where}: POSITION", ("VEC3",)).astype(np.float64)
    n = len(pos)
    faces = _triangles(doc, prim, where, n)
    nrm = _attribute(doc, attrs, "NORMAL", where, ("VEC3",), n)
    uv = _attribute(doc, attrs, "TEXCOORD_0", where, ("VEC2",), n)
    col = _attribute(doc, attrs, "COLOR_0", where, ("VEC3", "VEC4"), n)
    m3 = world[:3, :3]
    pos = pos @ m3.T + world[:3, 3]
    if nrm is None:
        nrm = np.full((n, 3), np.nan)
    else:  # normals transform by the inverse transpose
        try:
            nrm = nrm @ np.linalg.inv(m3)
        except np.linalg.LinAlgError:
            raise InputError(where, "its node transform is singular") from None
        length = np.linalg.norm(nrm, axis=1, keepdims=True)
        nrm = np.where(length > 0, nrm / np.where(length > 0, length, 1.0), np.nan)
    if np.linalg.det(m3) < 0:  # a mirroring transform turns counter-clockwise into clockwise
        faces = faces[:, ::-1]
    if col is not None and col.shape[1] == 3:
        col = np.concatenate([col, np.ones((n, 1))], axis=1)
    return {
        "positions": pos,
        "normals": nrm,
        "uvs": np.zeros((n, 2)) if uv is None else uv,
        "colors": np.ones((n, 4)) if col is None else col,
        "material": np.full(n, material, dtype=np.int64),
        "faces": faces,
    }


def _geometry(doc: _Document, n_materials: int) -> tuple[GltfGeometry, list[str]]:
    """Every triangle primitive of the default scene, and what was named and not used."""
    gltf, name = doc.gltf, doc.name
    meshes = _list(gltf.meshes, f"{name}: meshes")
    materials = _list(gltf.materials, f"{name}: materials")
    parts, notes, corners = [], [], 0
    for m, world, node in _mesh_instances(gltf, name):
        if not np.isfinite(world).all():
            raise InputError(node, "its world transform is not finite")
        prims = _list(getattr(meshes[m], "primitives", None), f"{name}: meshes[{m}].primitives")
        for k, prim in enumerate(prims):
            where = f"{name}: meshes[{m}].primitives[{k}]"
            mat = getattr(prim, "material", None)
            mat = n_materials if mat is None else _index(mat, materials, f"{where}: material")
            if getattr(prim, "targets", None):
                notes.append("morph targets")
            notes.extend(_extension_names(prim))
            part = _primitive(doc, prim, where, world, mat)
            corners += 3 * len(part["faces"])
            if corners > MAX_CORNERS:
                raise InputError(name, f"the scene expands to more than {MAX_CORNERS:,} corners")
            parts.append(part)
    if not parts:
        raise InputError(name, "its default scene holds no triangles")
    offsets = np.cumsum([0] + [len(p["positions"]) for p in parts[:-1]])
    geom = GltfGeometry(
        **{k: np.concatenate([p[k] for p in parts]) for k in
           ("positions", "normals", "uvs", "colors", "material")},
        faces=np.concatenate([p["faces"] + o for p, o in zip(parts, offsets, strict=True)]),
    )  # fmt: skip
    return geom, notes


# --------------------------------------------------------------------------------------------
# images, textures, materials


def _srgb_to_linear(c: np.ndarray) -> np.ndarray:
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _decode_image(data: bytes, where: str) -> np.ndarray:
    """Image bytes as (H, W, 4) float32 RGBA in [0, 1] (no colour decoding)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            img = Image.open(io.BytesIO(data))
            w, h = img.size
            if w * h > MAX_TEXTURE_PIXELS:
                raise InputError(where, f"{w} x {h} pixels is more than is read")
            img.load()
            if img.mode in ("I", "I;16", "I;16B", "I;16L", "I;16N"):
                a = np.asarray(img, dtype=np.float64) / 65535.0
                rgba = np.concatenate([np.repeat(a[..., None], 3, 2), np.ones((h, w, 1))], 2)
            else:
                rgba = np.asarray(img.convert("RGBA"), dtype=np.float64) / 255.0
    except InputError:
        raise
    except Exception as exc:  # PIL raises many types for files that are not images
        raise InputError(where, f"not an image ({type(exc).__name__}: {exc})"[:200]) from None
    return rgba.astype(np.float32)


def _uv_transform(ext, coord: int, where: str):
    """``KHR_texture_transform`` as a (2, 3) affine map of UVs (or None), and the UV set it
    names. The map is offset * rotation * scale, the rotation turning UVs counter-clockwise
    as seen with V pointing down (the sense the sample models and viewers agree on)."""
    if ext is None:
        return None, coord
    where = f"{where}: KHR_texture_transform"
    if not isinstance(ext, dict):
        raise InputError(where, f"must be an object, got {ext!r:.40}")
    off = _floats(ext.get("offset", [0.0, 0.0]), 2, f"{where}.offset")
    rot = _float(ext.get("rotation", 0.0), f"{where}.rotation")
    scale = _floats(ext.get("scale", [1.0, 1.0]), 2, f"{where}.scale")
    if "texCoord" in ext:
        coord = _int(ext["texCoord"], f"{where}.texCoord", 0, 64)
    c, s = math.cos(rot), math.sin(rot)
    m = np.array([[c, s], [-s, c]]) * scale[None, :]  # rotation after scale
    rows = np.concatenate([m, off[:, None]], axis=1)  # (2, 3)
    return tuple(tuple(float(x) for x in r) for r in rows), coord


class _Textures:
    """Textures of one document, each image decoded once."""

    def __init__(self, doc: _Document, device):
        self.doc, self.device = doc, device
        self._images: dict[int, np.ndarray] = {}

    def image(self, i: int, where: str) -> tuple[np.ndarray, str]:
        images = _list(self.doc.gltf.images, f"{self.doc.name}: images")
        i = _index(i, images, f"{where}: source")
        img = images[i]
        here = f"{self.doc.name}: images[{i}]"
        label = f"images[{i}] {getattr(img, 'name', None) or getattr(img, 'uri', None) or ''!r:.60}"
        if i not in self._images:
            uri = getattr(img, "uri", None)
            if isinstance(uri, str):
                data = self.doc.external(uri, here)
            elif getattr(img, "bufferView", None) is not None:
                data = bytes(self.doc.view(img.bufferView, here)[0])
            else:
                raise InputError(here, "has neither a uri nor a bufferView")
            self._images[i] = _decode_image(data, here)
        return self._images[i], label

    def texture(self, info, where: str, srgb: bool, channels: int, notes: list) -> Texture | None:
        if info is None:
            return None
        textures = _list(self.doc.gltf.textures, f"{self.doc.name}: textures")
        t = _index(getattr(info, "index", None), textures, f"{where}: index")
        tex = textures[t]
        here = f"{self.doc.name}: textures[{t}]"
        coord = _int(getattr(info, "texCoord", 0) or 0, f"{where}: texCoord", 0, 64)
        ext = getattr(info, "extensions", None)
        ext = ext.get("KHR_texture_transform") if isinstance(ext, dict) else None
        transform, coord = _uv_transform(ext, coord, where)
        if coord:
            notes.append(f"{where.rsplit(': ', 1)[-1]} on TEXCOORD_{coord}")
        notes.extend(e for e in _extension_names(info) + _extension_names(tex)
                     if e not in _READ_EXTENSIONS)  # fmt: skip
        if getattr(tex, "source", None) is None:
            raise InputError(here, "has no image source (an image extension only?)")
        rgba, label = self.image(tex.source, here)
        px = rgba[..., :channels]
        if srgb:
            px = np.concatenate([_srgb_to_linear(px[..., :3]), px[..., 3:]], -1)
        image = torch.as_tensor(np.ascontiguousarray(px), dtype=torch.float32, device=self.device)
        sampler = self._sampler(getattr(tex, "sampler", None), here)
        return Texture(image, sampler, label, coord, transform)

    def _sampler(self, i, where: str) -> Sampler:
        if i is None:
            return Sampler()
        samplers = _list(self.doc.gltf.samplers, f"{self.doc.name}: samplers")
        s = samplers[_index(i, samplers, f"{where}: sampler")]
        here = f"{self.doc.name}: samplers[{i}]"

        def pick(key, table, default):
            v = getattr(s, key, None)
            if v is None:
                return default
            if v not in table:
                raise InputError(f"{here}: {key}", f"unknown value {v!r:.20}")
            return table[v]

        return Sampler(
            pick("wrapS", _WRAP, "repeat"),
            pick("wrapT", _WRAP, "repeat"),
            pick("magFilter", _MAG, "linear"),
            pick("minFilter", _MIN, "linear"),
        )


def _unsupported(mat, where: str) -> list[str]:
    """What a material asks for that is not used, named."""
    notes = []
    emissive = getattr(mat, "emissiveFactor", None)
    if getattr(mat, "emissiveTexture", None) is not None or (
        emissive is not None and np.any(_floats(emissive, 3, f"{where}: emissiveFactor") != 0)
    ):
        notes.append("emissive")
    alpha = getattr(mat, "alphaMode", None) or "OPAQUE"
    if alpha != "OPAQUE":
        notes.append(f"alphaMode {alpha!s:.10}")
    if getattr(mat, "occlusionTexture", None) is not None:
        notes.append("occlusionTexture")
    return notes + _extension_names(mat)


def _material(textures: _Textures, mat, i: int) -> GltfMaterial:
    doc = textures.doc
    where = f"{doc.name}: materials[{i}]"
    name = getattr(mat, "name", None)
    name = name if isinstance(name, str) and name else f"materials[{i}]"
    pbr = getattr(mat, "pbrMetallicRoughness", None)
    notes = _unsupported(mat, where)
    pw = f"{where}.pbrMetallicRoughness"
    base = _floats(getattr(pbr, "baseColorFactor", None) or [1.0] * 4, 4, f"{pw}.baseColorFactor")
    metal = getattr(pbr, "metallicFactor", None)
    rough = getattr(pbr, "roughnessFactor", None)
    metal = 1.0 if metal is None else _float(metal, f"{pw}.metallicFactor")
    rough = 1.0 if rough is None else _float(rough, f"{pw}.roughnessFactor")
    notes.extend(_extension_names(pbr))
    normal = getattr(mat, "normalTexture", None)
    scale = getattr(normal, "scale", None)
    return GltfMaterial(
        name=name,
        base_color=tuple(float(x) for x in np.clip(base, 0.0, 1.0)),
        metallic=float(np.clip(metal, 0.0, 1.0)),
        roughness=float(np.clip(rough, 0.0, 1.0)),
        base_color_texture=textures.texture(
            getattr(pbr, "baseColorTexture", None), f"{pw}.baseColorTexture", True, 4, notes
        ),
        metallic_roughness_texture=textures.texture(
            getattr(pbr, "metallicRoughnessTexture", None),
            f"{pw}.metallicRoughnessTexture",
            False,
            3,
            notes,
        ),
        normal_texture=textures.texture(normal, f"{where}.normalTexture", False, 3, notes),
        normal_scale=1.0 if scale is None else _float(scale, f"{where}.normalTexture.scale"),
        double_sided=bool(getattr(mat, "doubleSided", False)),
        unsupported=tuple(dict.fromkeys(notes)),
    )


def _materials(doc: _Document, device, *, decode: bool) -> list[GltfMaterial]:
    """Every material of the document, then the default material (for primitives without)."""
    mats = _list(doc.gltf.materials, f"{doc.name}: materials")
    if not decode:
        return [GltfMaterial(f"materials[{i}]") for i in range(len(mats))] + [
            GltfMaterial("default")
        ]
    textures = _Textures(doc, device)
    return [_material(textures, m, i) for i, m in enumerate(mats)] + [GltfMaterial("default")]


def _warn_unsupported(name: str, file_notes: list[str], materials: list[GltfMaterial]) -> None:
    """One warning line naming everything read and not used (nothing when there is none)."""
    found = dict.fromkeys(file_notes)
    for m in materials:
        for note in m.unsupported:
            found.setdefault(note, None)
    if found:
        warnings.warn(
            f"lobelight: {name}: not supported, ignored: {', '.join(found)}",
            UserWarning,
            stacklevel=4,  # the caller of read_gltf
        )


def read_gltf(
    path, *, textures: bool = True, device=None, warn: bool = True
) -> tuple[GltfGeometry, list[GltfMaterial]]:
    """Read a glTF 2.0 file (``.gltf`` or ``.glb``): its default scene's triangles and its
    materials (module docstring for what is read).

    Parameters
    ----------
    textures : decode the materials' textures (False: geometry only, every material a default
        record, nothing warned about materials)
    device : where the texture tensors go
    warn : issue one ``UserWarning`` naming every feature found and not used

    Returns
    -------
    (geometry, materials): ``geometry.material`` indexes ``materials``, whose last entry is the
    specification's default material.

    Raises
    ------
    InputError
        naming the file and the part: a missing buffer or image file, an accessor whose count
        exceeds its buffer view, counts that disagree, points or lines, an index out of range,
        an image that is not one, a required extension, more than :data:`MAX_CORNERS` corners.
    """
    p = Path(path)
    check_input(p, limit=MAX_GLTF_BYTES)
    doc = _Document(p)
    # overflow in a file's transforms gives Inf or NaN, which the checks below name
    with np.errstate(all="ignore"):
        return _read(doc, textures=textures, device=device, warn=warn)


def _read(doc: _Document, *, textures: bool, device, warn: bool):
    name = doc.name
    required = [str(e) for e in _list(doc.gltf.extensionsRequired, f"{name}: extensionsRequired")]
    missing = [e for e in required if e not in _READ_EXTENSIONS]
    if missing:
        raise InputError(name, f"requires extensions lobelight does not read: {missing}")
    materials = _materials(doc, device, decode=textures)
    geometry, notes = _geometry(doc, len(materials) - 1)
    if warn and textures:
        used = _list(doc.gltf.extensionsUsed, f"{name}: extensionsUsed")
        notes += [str(e) for e in used if str(e) not in _READ_EXTENSIONS]
        _warn_unsupported(name, notes + _extension_names(doc.gltf), materials)
    return geometry, materials


# --------------------------------------------------------------------------------------------
# texture sampling


def wrap_texels(i: torch.Tensor, n: int, mode: str) -> torch.Tensor:
    """Integer texel indices ``i`` wrapped into [0, n) by a glTF sampler's wrap ``mode``
    (``"repeat"``, ``"clamp"`` or ``"mirror"``)."""
    if mode == "clamp":
        return i.clamp(0, n - 1)
    if mode == "mirror":
        j = torch.remainder(i, 2 * n)
        return torch.where(j >= n, 2 * n - 1 - j, j)
    return torch.remainder(i, n)


def wrap_uv(u: torch.Tensor, mode: str) -> torch.Tensor:
    """Texture coordinates ``u`` moved by whole periods of the wrap ``mode`` into [0, 1)
    (repeat), [0, 2) (mirror) or clamped to [-1, 2] (clamp): the same texels and weights,
    in float64 while moving (exact for the UVs a texture is read at)."""
    d = u.double()
    if mode == "clamp":
        d = d.clamp(-1.0, 2.0)
    elif mode == "mirror":
        d = d - 2.0 * torch.floor(d / 2.0)
    else:
        d = d - torch.floor(d)
    return d.to(u.dtype)


def sample_texture(
    texture: Texture, uv: torch.Tensor, *, filter: str | None = None
) -> torch.Tensor:
    """The texture at ``uv`` (..., 2): (..., C), bilinear between texel centres (or nearest
    texel, as the sampler's ``mag_filter`` says unless ``filter`` is given), indices beyond the
    edge wrapped by the sampler's wrap modes; the texture's ``uv_transform`` is applied
    first. UV (0, 0) is the image's top-left corner."""
    img = texture.image  # (H, W, C)
    h, w = img.shape[:2]
    uv = uv.to(img)
    if texture.uv_transform is not None:
        a = torch.tensor(texture.uv_transform, dtype=uv.dtype, device=uv.device)  # (2, 3)
        uv = uv @ a[:, :2].T + a[:, 2]
    s = texture.sampler
    # into one period of the wrap first: a UV of 1e38 (a file may hold one) times the width
    # overflows float32, and its texel index int64
    x = wrap_uv(uv[..., 0], s.wrap_s) * w - 0.5  # texel centres at integer + 0.5
    y = wrap_uv(uv[..., 1], s.wrap_t) * h - 0.5
    if (filter or s.mag_filter) == "nearest":
        ix = wrap_texels(torch.floor(x + 0.5).long(), w, s.wrap_s)
        iy = wrap_texels(torch.floor(y + 0.5).long(), h, s.wrap_t)
        return img[iy, ix]
    x0, y0 = torch.floor(x), torch.floor(y)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    x0, y0 = x0.long(), y0.long()
    xa, xb = wrap_texels(x0, w, s.wrap_s), wrap_texels(x0 + 1, w, s.wrap_s)
    ya, yb = wrap_texels(y0, h, s.wrap_t), wrap_texels(y0 + 1, h, s.wrap_t)
    top = img[ya, xa] * (1 - fx) + img[ya, xb] * fx
    bottom = img[yb, xa] * (1 - fx) + img[yb, xb] * fx
    return top * (1 - fy) + bottom * fy
