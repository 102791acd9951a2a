"""Triangle meshes: loading (trimesh; glTF through :mod:`._gltf`), checking, welding, normals
and adjacency; glTF assets welded with their UVs, vertex colours and materials, and their
per-vertex material parameters."""

from __future__ import annotations

import functools
import importlib
import warnings
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import torch

from .._io import check_input
from .._tol import DIVISOR_F64
from ..errors import InputError
from ..geometry.adjacency import encloses_outward, face_neighbours
from ._gltf import GLTF_SUFFIXES, GltfMaterial, read_gltf, sample_texture


@functools.cache
def _trimesh():
    """trimesh, imported when first used rather than with this module: it loads scipy and
    networkx, a large part of the start of a process that reads no mesh file (a render)."""
    trimesh = importlib.import_module("trimesh")
    importlib.import_module("trimesh.creation")
    return trimesh


__all__ = [
    "MAX_EXTENT",
    "MAX_FACES",
    "MAX_MESH_BYTES",
    "MAX_OFFSET",
    "MAX_WELD_LOSS",
    "MIN_EXTENT",
    "GltfAsset",
    "Mesh",
    "VertexFactors",
    "check_mesh_size",
    "check_precision",
    "load_gltf",
    "load_mesh",
    "mesh_from_arrays",
    "vertex_factors",
    "weld_arrays",
]

#: Largest mesh file we read: beyond this a dense per-vertex transport is not what anyone wants,
#: and trimesh would hold several copies of it in memory while parsing.
MAX_MESH_BYTES = 2 * 1024**3
#: Largest coordinate magnitude accepted: products of two coordinates (cross products for
#: normals and areas, in float32 on the GPU) stay far below float32's 3.4e38.
MAX_COORDINATE = 1e18
#: The most triangles a mesh may have (2,097,152: a closed mesh of about a million vertices),
#: and three vertices per triangle before welding (a triangle soup): what loading one holds
#: grows with these counts, and a bake's state by tens of kilobytes per vertex
#: (lobelight.fit._memory.state_bytes), so that a mesh at the limit is already more than a
#: bake's largest budget holds.
MAX_FACES = 1 << 21
#: The sizes (bounding-box diagonal of the vertices the faces use) a mesh may have: a bake and
#: the renderers give the same light at every size in this range (a bake's tolerances are
#: relative to the size; the renderers' camera planes and depths are float32).
MIN_EXTENT = 1e-6
MAX_EXTENT = 1e9
#: How far from the origin a mesh may lie, in multiples of its size. Rays leave a surface 1e-4
#: of the size along its normal (:class:`lobelight.geometry.raycast.RayCaster`), in float32:
#: 100 sizes away float32 positions are 2^-23 x 100 = 1.2e-5 sizes apart, so that step spans 8
#: of them. Where it spans less than one (1,200 sizes away) rays hit the surface they leave.
MAX_OFFSET = 100.0
#: The share of the surface area a weld may collapse (faces that become points or lines): a
#: weld at 1e-6 of the mesh's size takes only slivers' area, far under this.
MAX_WELD_LOSS = 0.01
#: Formats trimesh reads for us (by suffix).
MESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf", ".off")
#: Floor of an area-weighted normal's length (float64) before it is normalised: a vertex whose
#: faces' area vectors cancel (two faces back to back) keeps a zero normal instead of NaN.
_NORMAL_LENGTH_FLOOR = 1e-30


@dataclass(frozen=True, eq=False)
class Mesh:
    """A welded, cleaned triangle mesh with smooth vertex normals.

    Attributes
    ----------
    vertices : (V, 3) float32 positions (world frame, +Y up)
    faces : (F, 3) int64 vertex indices, counter-clockwise seen from outside
    normals : (V, 3) float32 unit vertex normals: the file's own where it has them, else the
        area-weighted average of the faces' normals
    name : where the mesh came from (file name or built-in name)
    """

    vertices: torch.Tensor
    faces: torch.Tensor
    normals: torch.Tensor
    name: str = "mesh"

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def n_faces(self) -> int:
        return int(self.faces.shape[0])

    @property
    def device(self) -> torch.device:
        return self.vertices.device

    @cached_property
    def bounds(self) -> torch.Tensor:
        """``(2, 3)`` min and max corner."""
        return torch.stack([self.vertices.amin(0), self.vertices.amax(0)])

    @cached_property
    def scale(self) -> float:
        """Length of the bounding-box diagonal: the mesh's natural length unit."""
        return float((self.bounds[1] - self.bounds[0]).norm())

    @cached_property
    def face_normals(self) -> torch.Tensor:
        """``(F, 3)`` unit geometric normals."""
        tri = self.vertices[self.faces]  # (F, 3, 3)
        n = torch.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], dim=-1)
        return torch.nn.functional.normalize(n, dim=-1)

    @cached_property
    def adjacency(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Vertex adjacency as CSR: ``(offsets (V + 1,), neighbours (2E,))`` int64.

        The neighbours of vertex ``i`` are ``neighbours[offsets[i]:offsets[i + 1]]``, sorted.
        """
        f = self.faces.cpu()
        e = torch.cat([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])  # (3F, 2) directed edges
        e = torch.cat([e, e.flip(1)])  # both directions
        e = torch.unique(e, dim=0)  # sorted by source then target
        counts = torch.bincount(e[:, 0], minlength=self.n_vertices)
        offsets = torch.zeros(self.n_vertices + 1, dtype=torch.int64)
        offsets[1:] = torch.cumsum(counts, 0)
        return offsets.to(self.device), e[:, 1].contiguous().to(self.device)

    @cached_property
    def face_neighbours(self) -> torch.Tensor:
        """``(F, 3)`` int64: the triangle across each triangle's edge opposite each corner, -1
        at a boundary or non-manifold edge (:func:`lobelight.geometry.adjacency.face_neighbours`:
        edges matched by their corners' positions)."""
        nb = face_neighbours(self.vertices.detach().cpu().numpy(), self.faces.cpu().numpy())
        return torch.from_numpy(nb).long().to(self.device)

    @cached_property
    def encloses_outward(self) -> bool:
        """Whether the mesh is a closed surface wound outward, so that from outside it its
        triangles seen from behind are hidden and the renderers leave them out
        (:func:`lobelight.geometry.adjacency.encloses_outward`)."""
        return encloses_outward(self.vertices.detach().cpu().numpy(), self.faces.cpu().numpy())

    def neighbors(self, i: int) -> torch.Tensor:
        """Sorted neighbour indices of vertex ``i``."""
        off, nb = self.adjacency
        return nb[int(off[i]) : int(off[i + 1])]

    def to(self, device) -> Mesh:
        return Mesh(
            self.vertices.to(device), self.faces.to(device), self.normals.to(device), self.name
        )

    def to_trimesh(self):
        """The mesh as a ``trimesh.Trimesh`` (no processing, our normals attached)."""
        return _trimesh().Trimesh(
            vertices=self.vertices.detach().cpu().numpy().astype(np.float64),
            faces=self.faces.cpu().numpy(),
            vertex_normals=self.normals.detach().cpu().numpy(),
            process=False,
        )


def _area_weighted_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    # the cross product's length is twice the face area: summing it weights by area
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])  # (F, 3)
    n = np.zeros_like(v)
    for k in range(3):
        np.add.at(n, f[:, k], cross)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return n / np.maximum(length, _NORMAL_LENGTH_FLOOR)


def _quantized(a: np.ndarray, step: float) -> np.ndarray:
    """``a`` (N, k) on a grid of ``step`` as int64 keys (NaN rows get one key of their own;
    values beyond +-1e15 steps are clipped, never cast out of int64's range)."""
    q = np.clip(np.nan_to_num(a / step, nan=2e15), -1e15, 2e15)
    return np.round(q).astype(np.int64)


def _weld_keys(v, diag, normals, attrs, keyed) -> np.ndarray:
    """(N, k) int64 keys: vertices with equal keys are merged. Positions on a grid of 1e-6 of
    the bounding-box diagonal; normals (when given) and the ``keyed`` attributes on grids of
    1e-4 and 1e-6: values written twice by an exporter are equal, different ones differ by
    far more."""
    cols = [_quantized(v - v.min(0), 1e-6 * diag)]
    if normals is not None:
        cols.append(_quantized(normals, 1e-4))
    cols.extend(_quantized(attrs[k].reshape(len(v), -1).astype(np.float64), 1e-6) for k in keyed)
    return np.concatenate(cols, axis=1)


def _check_arrays(v: np.ndarray, f: np.ndarray, name: str) -> None:
    if v.ndim != 2 or v.shape[1] != 3:
        raise InputError(name, f"vertices must be an (V, 3) array, got shape {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] == 0:
        raise InputError(name, f"needs at least one triangle, got faces of shape {f.shape}")
    if not np.issubdtype(f.dtype, np.integer):
        raise InputError(name, "face indices must be integers")
    check_mesh_size(len(v), len(f), name)
    if not np.isfinite(v).all():
        raise InputError(name, f"{int((~np.isfinite(v)).any(1).sum())} vertices are NaN or Inf")
    if np.abs(v).max(initial=0.0) > MAX_COORDINATE:
        raise InputError(name, f"vertex coordinates beyond +-{MAX_COORDINATE:g}")
    if f.min() < 0 or f.max() >= len(v):
        raise InputError(name, f"face index out of range [0, {len(v)})")


def check_mesh_size(n_vertices: int, n_faces: int, name: str) -> None:
    """Refuse a mesh of more than :data:`MAX_FACES` triangles or more than three vertices per
    triangle allowed (a triangle soup): loading one takes memory in proportion.

    Raises
    ------
    InputError
        naming ``name``, its counts and the limit.
    """
    if n_faces > MAX_FACES or n_vertices > 3 * MAX_FACES:
        raise InputError(
            name,
            f"{n_vertices:,} vertices and {n_faces:,} triangles: over lobelight's limit of "
            f"{MAX_FACES:,} triangles ({3 * MAX_FACES:,} vertices before welding); decimate it",
        )


def _compact(v, f, nrm, attrs):
    """The vertices ``f`` references, and ``f`` renumbered to them."""
    used = np.zeros(len(v), dtype=bool)
    used[f.reshape(-1)] = True
    if used.all():
        return v, f, nrm, attrs
    remap = np.cumsum(used) - 1
    nrm = None if nrm is None else nrm[used]
    return v[used], remap[f], nrm, {k: a[used] for k, a in attrs.items()}


def _double_areas(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """(F,) twice each triangle's area (float64)."""
    return np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)


def check_precision(v: np.ndarray, name: str) -> None:
    """Refuse vertices ``(V, 3)`` (those the faces use) that lobelight's float32 geometry cannot
    keep: all at one point, a size outside ``MIN_EXTENT..MAX_EXTENT``, or too far from the
    origin (:func:`_check_precision`); a mesh's load runs it, and a model file's read."""
    v = np.asarray(v, dtype=np.float64)
    diag = float(np.linalg.norm(v.max(0) - v.min(0)))
    if not diag > 0:
        raise InputError(name, "all vertices coincide: the mesh has no extent")
    _check_precision(v, diag, name)


def _check_precision(v: np.ndarray, diag: float, name: str) -> None:
    """Refuse a mesh whose float32 positions cannot keep its shape: one far from the origin
    against its size (beyond :data:`MAX_OFFSET` sizes away), or of a size outside
    ``MIN_EXTENT..MAX_EXTENT``; the message says the translation or scale that fixes it."""
    lo, hi = v.min(0), v.max(0)
    if not MIN_EXTENT <= diag <= MAX_EXTENT:
        scale = 1.0 / diag
        raise InputError(
            name,
            f"its size (bounding-box diagonal) is {diag:.3g}, outside {MIN_EXTENT:g}.."
            f"{MAX_EXTENT:g}, where lobelight's float32 geometry keeps its shape; scale it by "
            f"{scale:.3g} (to a size of 1) and light and render it at that scale",
        )
    far = float(np.abs(np.stack([lo, hi])).max())
    if far > MAX_OFFSET * diag:
        c = (lo + hi) / 2
        raise InputError(
            name,
            f"it lies {far:.3g} from the origin, {far / diag:.3g} times its size ({diag:.3g}): "
            f"float32 positions there are {far * 2**-24:.2g} apart, too coarse for its shape "
            f"(the most is {MAX_OFFSET:g} times its size); translate it by "
            f"({-c[0]:.9g}, {-c[1]:.9g}, {-c[2]:.9g}) to the origin",
        )


def _weld_loss(area_before: float, v: np.ndarray, f: np.ndarray, diag: float, name: str):
    """Refuse a weld that took more than :data:`MAX_WELD_LOSS` of the surface area (faces
    collapsed to points or lines): the mesh holds parts far smaller than its bounding box."""
    after = float(_double_areas(v, f).sum()) if len(f) else 0.0
    lost = 1.0 - after / area_before if area_before > 0 else 0.0
    if lost > MAX_WELD_LOSS:
        raise InputError(
            name,
            f"welding its vertices to {1e-6 * diag:.3g} (1e-6 of its size, {diag:.3g}) would "
            f"collapse {lost:.0%} of its surface area (at most {MAX_WELD_LOSS:.0%}): it holds "
            f"parts far smaller than its extent or far from each other; remove the stray parts",
        )


def _float32_loss(v: np.ndarray, f: np.ndarray, name: str) -> None:
    """Refuse a mesh whose surface area changes by more than :data:`MAX_WELD_LOSS` when its
    positions are stored as float32 (as every mesh is): parts far smaller than their distance
    from the origin, whose shape float32 cannot hold (the whole mesh's offset and size are
    checked apart, :data:`MAX_OFFSET`)."""
    before = float(_double_areas(v, f).sum())
    after = float(_double_areas(v.astype(np.float32).astype(np.float64), f).sum())
    change = abs(after / before - 1.0) if before > 0 else 0.0
    if change > MAX_WELD_LOSS:
        raise InputError(
            name,
            f"stored as float32 its positions change its surface area by {change:.1%} (at most "
            f"{MAX_WELD_LOSS:.0%}): it holds parts far smaller than their distance from the "
            f"origin; remove them, or move and scale the mesh so that they are not",
        )


def _orient_outward(v, f, nrm, name: str):
    """A closed, consistently wound mesh (each edge in two faces, once each way) of negative
    signed volume is inside out: its faces are turned (and the file's normals too where they
    point inward with them), with a warning. Open meshes are left as they are."""
    if not _closed(f, len(v)):
        return f, nrm
    c = v.mean(0)
    a, b, d = v[f[:, 0]] - c, v[f[:, 1]] - c, v[f[:, 2]] - c
    volume = float(np.einsum("ij,ij->i", a, np.cross(b, d)).sum()) / 6.0
    if volume >= 0:
        return f, nrm
    f = f[:, ::-1].copy()
    if nrm is not None:
        outward = _area_weighted_normals(v, f)
        ok = np.isfinite(nrm).all(1)
        if ok.any() and float(np.einsum("ij,ij->i", nrm[ok], outward[ok]).sum()) < 0:
            nrm = -nrm
    warnings.warn(
        f"lobelight: {name}: the mesh is closed and inside out (signed volume {volume:.3g}): "
        f"its faces are turned to face outward",
        UserWarning,
        stacklevel=4,
    )
    return f, nrm


def _closed(f: np.ndarray, n: int) -> bool:
    """Whether every directed edge of ``f`` (F, 3) appears once and its reverse once: a closed
    mesh wound consistently."""
    a = f.reshape(-1)
    b = f[:, [1, 2, 0]].reshape(-1)
    fwd = np.sort(a * n + b)  # (3F,) directed edge keys
    if len(fwd) > 1 and bool((fwd[1:] == fwd[:-1]).any()):
        return False  # an edge twice the same way
    rev = b * n + a
    return bool(np.isin(rev, fwd, assume_unique=True).all())


def weld_arrays(
    vertices, faces, *, normals=None, attributes=None, keyed=(), name="mesh", weld=True
) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Check, weld and clean raw arrays (the work of :func:`mesh_from_arrays`), carrying
    per-vertex attributes along.

    Checks: at most :data:`MAX_FACES` triangles; finite positions; of the vertices the faces
    use (a vertex no face uses is dropped first, so a stray one changes nothing), a size
    within ``MIN_EXTENT..MAX_EXTENT`` and at most ``MAX_OFFSET`` sizes from the origin, where
    float32 positions keep the shape.

    Weld policy: vertices merge where their positions agree (to 1e-6 of the used vertices'
    bounding-box diagonal), their ``normals`` agree when normals are given (so a hard edge
    stored as split vertices with different normals stays hard), and every attribute named in
    ``keyed`` agrees (a UV seam, a material boundary); a weld that would collapse more than
    :data:`MAX_WELD_LOSS` of the surface area is refused. Then faces that became degenerate
    (repeated index or zero area) and duplicate faces are dropped, and unreferenced vertices
    removed. Last, a closed mesh that is inside out (negative signed volume) is turned
    outward, with a warning. ``weld=False`` takes the arrays as given: no weld, no turning.

    Parameters
    ----------
    vertices : (N, 3) float;  faces : (F, 3) integer
    normals : (N, 3) float or None: the file's vertex normals; a NaN or zero row means none
        for that vertex (it gets the area-weighted normal of its faces)
    attributes : name -> (N, ...) arrays that follow the vertices (the first of a merged
        group is kept)
    keyed : names in ``attributes`` that must agree for vertices to merge

    Returns
    -------
    (V, 3) float64 positions, (F', 3) int64 faces, (V, 3) float64 unit normals, attributes
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    _check_arrays(v, f, name)
    attrs = {k: np.asarray(a) for k, a in (attributes or {}).items()}
    nrm = None
    if normals is not None:
        nrm = np.asarray(normals, dtype=np.float64).reshape(v.shape)
        length = np.linalg.norm(np.nan_to_num(nrm, nan=0.0), axis=1, keepdims=True)
        ok = np.isfinite(nrm).all(1, keepdims=True) & (length > 0)
        nrm = np.where(ok, nrm / np.where(ok, length, 1.0), np.nan)
    # a vertex no face uses neither sets the weld's tolerance nor the extent
    v, f, nrm, attrs = _compact(v, f.astype(np.int64), nrm, attrs)
    check_precision(v, name)
    diag = float(np.linalg.norm(v.max(0) - v.min(0)))  # the weld's and the areas' unit
    area_before = 0.0
    if weld:
        area_before = float(_double_areas(v, f).sum())
        key = _weld_keys(v, diag, nrm, attrs, keyed)  # (N, k)
        _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
        v, f = v[first], inv.reshape(-1)[f]
        nrm = None if nrm is None else nrm[first]
        attrs = {k: a[first] for k, a in attrs.items()}
    # degenerate faces: repeated vertex, or area below (1e-9 diag)^2 ~ rounding noise
    keep = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
    keep &= _double_areas(v, f) > (1e-9 * diag) ** 2
    f = f[keep]
    if weld:
        _weld_loss(area_before, v, f, diag, name)
    if len(f):  # duplicate faces (same vertex set) double-count area and hits
        _, uniq = np.unique(np.sort(f, axis=1), axis=0, return_index=True)
        f = f[np.sort(uniq)]
    if len(f) == 0:
        raise InputError(name, "no triangle with non-zero area")
    v, f, nrm, attrs = _compact(v, f, nrm, attrs)
    if weld:
        _float32_loss(v, f, name)
        f, nrm = _orient_outward(v, f, nrm, name)
    n = _area_weighted_normals(v, f)
    if nrm is not None:
        n = np.where(np.isfinite(nrm).all(1, keepdims=True), nrm, n)
    return v, f, n, attrs


def mesh_from_arrays(
    vertices, faces, *, normals=None, name: str = "mesh", weld: bool = True, device=None
) -> Mesh:
    """Check, clean and weld raw arrays into a :class:`Mesh`.

    Cleaning (:func:`weld_arrays`): vertices whose positions agree to ``1e-6`` of the
    bounding-box diagonal are merged - and, when ``normals`` are given, only where their
    normals agree too, so that hard edges stay hard; without normals, a mesh stored with split
    vertices (per-face UV seams in an OBJ) gets one smooth area-weighted normal per position.
    Then faces that became degenerate (repeated index or zero area) and duplicate faces are
    dropped, and unreferenced vertices removed. Non-manifold edges are kept: the transport
    only needs triangles and normals, and ray casting treats every face the same.

    Parameters
    ----------
    vertices : (V, 3) float array;  faces : (F, 3) integer array
    normals : (V, 3) float array or None: the vertices' own normals (NaN or zero rows: none)

    Raises
    ------
    InputError
        naming ``name`` when there are no faces, NaN/Inf positions or coordinates beyond
        :data:`MAX_COORDINATE`, out-of-range indices, or nothing with area is left.
    """
    v, f, n, _ = weld_arrays(vertices, faces, normals=normals, name=name, weld=weld)
    return Mesh(
        vertices=torch.as_tensor(v, dtype=torch.float32, device=device),
        faces=torch.as_tensor(f, dtype=torch.int64, device=device),
        normals=torch.as_tensor(n, dtype=torch.float32, device=device),
        name=name,
    )


def _trimesh_arrays(p: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """A mesh file's triangles through trimesh, every geometry of its scene in world
    coordinates: (N, 3) vertices, (F, 3) faces, and (N, 3) normals where the file has vertex
    normals for every geometry (else None). trimesh keeps the normals a file holds in the
    geometry's cache and computes them on access otherwise: the cache tells them apart."""
    try:
        loaded = _trimesh().load_scene(str(p), process=False, skip_materials=True)
        parts = []
        for node in loaded.graph.nodes_geometry:
            transform, geom_name = loaded.graph[node]
            g = loaded.geometry[geom_name]
            if not isinstance(g, _trimesh().Trimesh) or len(g.faces) == 0:
                continue
            has_normals = "vertex_normals" in g._cache  # read from the file, not computed
            parts.append((transform, g, g.vertex_normals if has_normals else None))
    except Exception as exc:  # trimesh raises many types for corrupt files
        raise InputError(str(p), f"cannot read mesh: {type(exc).__name__}: {exc}") from None
    if not parts:
        raise InputError(str(p), "file holds no triangles")
    vs, fs, ns, offset = [], [], [], 0
    for t, g, n in parts:
        t = np.asarray(t, dtype=np.float64)
        v, f = _checked_part(p, g)
        vs.append(v @ t[:3, :3].T + t[:3, 3])
        fs.append((f[:, ::-1] if np.linalg.det(t[:3, :3]) < 0 else f) + offset)
        n = None if n is None else np.asarray(n, dtype=np.float64)
        ns.append(None if n is None or n.shape != v.shape else n @ _inverse(t[:3, :3]))
        offset += len(v)
    normals = None if any(n is None for n in ns) else np.concatenate(ns)
    return np.concatenate(vs), np.concatenate(fs), normals


def _checked_part(p: Path, g) -> tuple[np.ndarray, np.ndarray]:
    """One trimesh geometry's (V, 3) vertices and (F, 3) faces, shapes and indices checked (a
    corrupt file can give trimesh other shapes)."""
    v = np.asarray(g.vertices, dtype=np.float64)
    f = np.asarray(g.faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise InputError(str(p), f"vertices must be (V, 3), the file gives {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise InputError(str(p), f"faces must be (F, 3) integers, the file gives {f.shape}")
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise InputError(str(p), f"face index out of range [0, {len(v)})")
    return v, f.astype(np.int64)


def _inverse(m: np.ndarray) -> np.ndarray:
    try:
        return np.linalg.inv(m)
    except np.linalg.LinAlgError:
        return np.full_like(m, np.nan)  # a singular transform: its normals count as none


def load_mesh(path, *, device=None) -> Mesh:
    """Load a mesh file (OBJ, PLY, STL, OFF through trimesh; glTF/GLB through
    :func:`lobelight.scene.read_gltf`) and clean it.

    Scenes with several geometries (glTF, multi-object OBJ) are flattened into one mesh in world
    coordinates. Welding (:func:`mesh_from_arrays`): where the file has vertex normals (OBJ
    ``vn``, PLY ``nx ny nz``, glTF NORMAL), vertices merge only where position and normal
    agree, so hard edges stay hard; where it has none (STL's are per face), by position, with
    area-weighted normals. UV seams are welded: this result carries no UVs
    (:func:`lobelight.scene.load_gltf` keeps them). Materials in the file are ignored:
    lobelight's materials come from the scene description.

    Raises
    ------
    InputError
        naming the file: missing, too large, unknown format, unreadable, or bad geometry.
    """
    p = Path(path)
    size = check_input(p, limit=MAX_MESH_BYTES)  # a regular file, of a size trimesh can read
    if size == 0:
        raise InputError(str(p), "file is empty")
    suffix = p.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise InputError(str(p), f"unknown mesh format {suffix!r} (use one of {MESH_SUFFIXES})")
    _check_declared_size(p, suffix)  # before the file is parsed
    if suffix in GLTF_SUFFIXES:
        geom, _ = read_gltf(p, textures=False, warn=False)
        v, f, n = geom.positions, geom.faces, geom.normals
    else:
        with np.errstate(all="ignore"):  # NaN or Inf from the file: named by the checks below
            v, f, n = _trimesh_arrays(p)
        if suffix == ".ply":
            _check_ply_counts(p, len(v), len(f))
    try:
        return mesh_from_arrays(v, f, normals=n, name=p.name, device=device)
    except InputError as exc:  # name the whole path, as every other error here does
        raise InputError(str(p), exc.problem) from None


@dataclass(frozen=True, eq=False)
class GltfAsset:
    """A glTF asset welded for lobelight: geometry, per-vertex attributes and materials.

    Welding: vertices merge where position, normal, UV, vertex colour and material all agree
    (:func:`weld_arrays`), so hard edges, UV seams and material boundaries keep split vertices
    and every vertex has one material.

    Attributes
    ----------
    mesh : the :class:`Mesh` (the file's normals where it has them)
    uvs : (V, 2) float32 TEXCOORD_0 (zeros where a primitive has none)
    colors : (V, 4) float32 linear COLOR_0 RGBA (ones where a primitive has none)
    material : (V,) int64 index into ``materials``
    materials : :class:`~lobelight.scene.GltfMaterial` records; the last is the
        specification's default material (for primitives without one)
    """

    mesh: Mesh
    uvs: torch.Tensor
    colors: torch.Tensor
    material: torch.Tensor
    materials: tuple[GltfMaterial, ...]

    def to(self, device) -> GltfAsset:
        """The asset with its mesh and per-vertex arrays on ``device`` (the textures stay
        where they are: they are read where a renderer or a reference needs them)."""
        return GltfAsset(
            self.mesh.to(device),
            self.uvs.to(device),
            self.colors.to(device),
            self.material.to(device),
            self.materials,
        )

    @property
    def face_material(self) -> torch.Tensor:
        """``(F,)`` int64 material of each face (its vertices all have the same)."""
        return self.material[self.mesh.faces[:, 0]]


def load_gltf(path, *, device=None) -> GltfAsset:
    """Load a glTF 2.0 asset (``.gltf`` with its buffers and images, or ``.glb``): the default
    scene's triangles in world space with their materials and textures
    (:func:`lobelight.scene.read_gltf`), welded (:class:`GltfAsset`).

    What the file asks for and lobelight does not use (emissive light, alpha modes, occlusion,
    extensions) is named in one ``UserWarning``.

    Raises
    ------
    InputError
        naming the file and the part (``meshes[0].primitives[1]: POSITION accessor 3 ...``).
    """
    p = Path(path)
    geom, materials = read_gltf(p, device=device)
    attrs = {"uvs": geom.uvs, "colors": geom.colors, "material": geom.material}
    try:
        v, f, n, attrs = weld_arrays(
            geom.positions, geom.faces, normals=geom.normals, attributes=attrs,
            keyed=("uvs", "colors", "material"), name=p.name,
        )  # fmt: skip
    except InputError as exc:
        raise InputError(str(p), exc.problem) from None
    mesh = Mesh(
        vertices=torch.as_tensor(v, dtype=torch.float32, device=device),
        faces=torch.as_tensor(f, dtype=torch.int64, device=device),
        normals=torch.as_tensor(n, dtype=torch.float32, device=device),
        name=p.name,
    )
    return GltfAsset(
        mesh=mesh,
        uvs=torch.as_tensor(attrs["uvs"], dtype=torch.float32, device=device),
        colors=torch.as_tensor(attrs["colors"], dtype=torch.float32, device=device),
        material=torch.as_tensor(attrs["material"], dtype=torch.int64, device=device),
        materials=tuple(materials),
    )


@dataclass(frozen=True, eq=False)
class VertexFactors:
    """Per-vertex metallic-roughness parameters of a :class:`GltfAsset`.

    base_color : (V, 3) linear RGB (``baseColorFactor`` x texture x COLOR_0)
    metallic, roughness : (V,) (factor x the metallic-roughness texture's B, G)
    """

    base_color: torch.Tensor
    metallic: torch.Tensor
    roughness: torch.Tensor


def _factors_at(mat: GltfMaterial, uv: torch.Tensor, color: torch.Tensor) -> torch.Tensor:
    """(..., 5) base colour RGB, metallic, roughness of ``mat`` at ``uv`` (..., 2) with vertex
    colour ``color`` (..., 4)."""
    base = torch.tensor(mat.base_color[:3], dtype=uv.dtype, device=uv.device) * color[..., :3]
    metal = torch.full_like(uv[..., 0], mat.metallic)
    rough = torch.full_like(uv[..., 0], mat.roughness)
    if mat.base_color_texture is not None:
        base = base * sample_texture(mat.base_color_texture, uv)[..., :3]
    if mat.metallic_roughness_texture is not None:
        mr = sample_texture(mat.metallic_roughness_texture, uv)
        metal, rough = metal * mr[..., 2], rough * mr[..., 1]
    return torch.cat([base, metal[..., None], rough[..., None]], dim=-1)


def _subtriangle_centroids(n: int) -> torch.Tensor:
    """(n^2, 3) barycentric centroids of the n^2 equal triangles a triangle splits into."""
    i, j = torch.meshgrid(torch.arange(n), torch.arange(n), indexing="ij")
    up = (i + j < n).flatten()
    i, j = i.flatten().double(), j.flatten().double()
    a = torch.stack([(i + 1 / 3) / n, (j + 1 / 3) / n], -1)[up]  # upright triangles
    b = torch.stack([(i + 2 / 3) / n, (j + 2 / 3) / n], -1)[(i + j < n - 1)]  # inverted ones
    ab = torch.cat([a, b])  # (n^2, 2) weights of corners 1 and 2
    return torch.cat([1 - ab.sum(-1, keepdim=True), ab], -1)


def vertex_factors(
    asset: GltfAsset, *, average: str = "vertex", quadrature: int = 4, batch: int = 1 << 16
) -> VertexFactors:
    """The asset's metallic-roughness parameters per vertex, from its materials' factors,
    textures (:func:`lobelight.scene.sample_texture`) and vertex colours.

    ``average="vertex"``: the textures read at the vertex's UV. ``"one_ring"``: the textures
    averaged over the vertex's one-ring with its hat function as weight (the linear
    interpolation weight of the vertex across its faces), by a midpoint rule on each face split
    into ``quadrature``^2 equal triangles: what a per-vertex value that is interpolated across
    faces should hold for the texture's average over the surface to be kept.
    """
    if average not in ("vertex", "one_ring"):
        raise InputError("average", f"must be 'vertex' or 'one_ring', got {average!r}")
    dev = asset.uvs.device
    out = torch.empty(asset.mesh.n_vertices, 5, dtype=torch.float32, device=dev)
    if average == "vertex":
        for m, mat in enumerate(asset.materials):
            sel = torch.nonzero(asset.material == m).squeeze(1)
            if len(sel):
                out[sel] = _factors_at(mat, asset.uvs[sel], asset.colors[sel])
        return VertexFactors(out[:, :3], out[:, 3], out[:, 4])
    bary = _subtriangle_centroids(quadrature).to(device=dev, dtype=torch.float32)  # (K, 3)
    num = torch.zeros(asset.mesh.n_vertices, 5, dtype=torch.float64, device=dev)
    den = torch.zeros(asset.mesh.n_vertices, dtype=torch.float64, device=dev)
    faces, area = asset.mesh.faces, triangle_areas(asset.mesh)
    fmat = asset.face_material
    for m, mat in enumerate(asset.materials):
        sel = torch.nonzero(fmat == m).squeeze(1)
        for start in range(0, len(sel), batch):
            fb = faces[sel[start : start + batch]]  # (B, 3)
            uv = torch.einsum("kc,bcd->bkd", bary, asset.uvs[fb])  # (B, K, 2)
            col = torch.einsum("kc,bcd->bkd", bary, asset.colors[fb])  # (B, K, 4)
            val = _factors_at(mat, uv, col)  # (B, K, 5)
            w = area[sel[start : start + batch], None, None] * bary[None]  # (B, K, 3) hat x dA
            contrib = torch.einsum("bkc,bkd->bcd", w, val).double()  # (B, 3, 5)
            num.index_add_(0, fb.reshape(-1), contrib.reshape(-1, 5))
            den.index_add_(0, fb.reshape(-1), w.sum(1).reshape(-1).double())
    out = (num / den.clamp_min(DIVISOR_F64)[:, None]).float()
    return VertexFactors(out[:, :3], out[:, 3], out[:, 4])


def _ply_declared(p: Path) -> dict[str, int]:
    """The element counts a PLY header declares (``vertex``, ``face``, ...; none where the
    file has no header)."""
    with p.open("rb") as fh:
        head = fh.read(1 << 16)
    end = head.find(b"end_header")
    declared: dict[str, int] = {}
    for line in head[: max(end, 0)].decode("ascii", errors="replace").splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[0] == "element" and parts[2].isdigit():
            declared[parts[1]] = int(parts[2])
    return declared


def _count(p: Path, patterns: tuple[bytes, ...]) -> list[int]:
    """How often each of ``patterns`` occurs in the file, as if it began with a line break
    (so that ``b"\\nv "`` counts the lines starting ``v ``), read in blocks: bounded memory."""
    counts = [0] * len(patterns)
    keep = max(map(len, patterns)) - 1  # a match across two blocks starts in the last bytes
    with p.open("rb") as fh:
        tail = b"\n"
        while block := fh.read(1 << 24):
            text = tail + block
            for i, pattern in enumerate(patterns):
                counts[i] += text.count(pattern)  # tail is shorter than any pattern
            tail = text[-keep:] if keep else b""
    return counts


def _off_declared(p: Path) -> tuple[int, int]:
    """The vertex and face counts an OFF header declares (0, 0 where it has none)."""
    with p.open("rb") as fh:
        head = fh.read(1 << 12).decode("ascii", errors="replace")
    words = [w for line in head.splitlines() for w in line.split("#")[0].split()]
    if words and words[0].upper().endswith("OFF"):
        words[0] = words[0][: -len("OFF")]
        words = [w for w in words if w]
    nums = [int(w) for w in words[:2] if w.isdigit()]
    return (nums[0], nums[1]) if len(nums) == 2 else (0, 0)


def _check_declared_size(p: Path, suffix: str) -> None:
    """Refuse a mesh file whose vertex or triangle counts, as it declares them (PLY and OFF
    headers, STL's binary count) or as its lines give them (OBJ ``v`` and ``f`` lines, ASCII
    STL facets), are over :func:`check_mesh_size`'s limit, before it is parsed: the parser
    allocates in proportion. A polygon of OBJ, PLY or OFF is several triangles: what the
    parsed file holds is checked again."""
    name = str(p)
    if suffix == ".ply":
        d = _ply_declared(p)
        check_mesh_size(d.get("vertex", 0), d.get("face", 0), name)
    elif suffix == ".off":
        check_mesh_size(*_off_declared(p), name)
    elif suffix == ".obj":
        nv, nf = _count(p, (b"\nv ", b"\nf "))
        check_mesh_size(nv, nf, name)
    elif suffix == ".stl":
        size = p.stat().st_size
        with p.open("rb") as fh:
            head = fh.read(84)
        n = int.from_bytes(head[80:84], "little") if len(head) == 84 else 0
        if size != 84 + 50 * n:  # not binary STL: ASCII facets
            n = _count(p, (b"endfacet",))[0]
        check_mesh_size(3 * n, n, name)


def _check_ply_counts(p: Path, n_vertices: int, n_triangles: int) -> None:
    """Refuse a PLY file that holds fewer vertices or faces than its header declares (cut
    short, or a header that lies): trimesh reads what is there and says nothing. Each declared
    face gives one triangle or more (polygons are fanned), so triangles may outnumber faces."""
    declared = _ply_declared(p)
    nv, nf = declared.get("vertex"), declared.get("face")
    if nv is not None and n_vertices != nv:
        raise InputError(str(p), f"declares {nv:,} vertices and holds {n_vertices:,} (cut short?)")
    if nf is not None and n_triangles < nf:
        raise InputError(str(p), f"declares {nf:,} faces and holds {n_triangles:,} (cut short?)")


def triangle_areas(mesh: Mesh) -> torch.Tensor:
    """``(F,)`` triangle areas."""
    tri = mesh.vertices[mesh.faces]
    return 0.5 * torch.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], dim=-1).norm(dim=-1)
