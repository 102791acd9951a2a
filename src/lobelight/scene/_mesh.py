"""Triangle meshes: loading through trimesh, checking, cleaning, normals and adjacency."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import torch
import trimesh

from .._io import check_input
from ..errors import InputError

__all__ = ["MAX_MESH_BYTES", "Mesh", "load_mesh", "mesh_from_arrays"]

#: Largest mesh file we read: beyond this a dense per-vertex transport is not what anyone wants,
#: and trimesh would hold several copies of it in memory while parsing.
MAX_MESH_BYTES = 2 * 1024**3
#: Largest coordinate magnitude accepted: products of two coordinates (cross products for
#: normals and areas, in float32 on the GPU) stay far below float32's 3.4e38.
MAX_COORDINATE = 1e18
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
    normals : (V, 3) float32 unit vertex normals, area-weighted average of face normals
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
        return trimesh.Trimesh(
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


def mesh_from_arrays(
    vertices, faces, *, name: str = "mesh", weld: bool = True, device=None
) -> Mesh:
    """Check, clean and weld raw arrays into a :class:`Mesh`.

    Cleaning: vertices closer than ``1e-6`` of the bounding-box diagonal are merged (so a mesh
    stored with split vertices, e.g. per-face UV seams in an OBJ, gets one smooth normal per
    position), then faces that became degenerate (repeated index or zero area) and duplicate
    faces are dropped, and unreferenced vertices removed. Non-manifold edges are kept: the
    transport only needs triangles and normals, and ray casting treats every face the same.

    Parameters
    ----------
    vertices : (V, 3) float array;  faces : (F, 3) integer array

    Raises
    ------
    InputError
        naming ``name`` when there are no faces, NaN/Inf positions or coordinates beyond
        :data:`MAX_COORDINATE`, out-of-range indices, or nothing with area is left.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise InputError(name, f"vertices must be an (V, 3) array, got shape {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] == 0:
        raise InputError(name, f"needs at least one triangle, got faces of shape {f.shape}")
    if not np.issubdtype(f.dtype, np.integer):
        raise InputError(name, "face indices must be integers")
    if not np.isfinite(v).all():
        raise InputError(name, f"{int((~np.isfinite(v)).any(1).sum())} vertices are NaN or Inf")
    if np.abs(v).max(initial=0.0) > MAX_COORDINATE:
        raise InputError(name, f"vertex coordinates beyond +-{MAX_COORDINATE:g}")
    if f.min() < 0 or f.max() >= len(v):
        raise InputError(name, f"face index out of range [0, {len(v)})")
    f = f.astype(np.int64)
    diag = float(np.linalg.norm(v.max(0) - v.min(0)))
    if not diag > 1 / MAX_COORDINATE:  # also: an extent that float32 vertices would lose
        raise InputError(name, "all vertices coincide: the mesh has no extent")
    if weld:
        # merge on a grid of 1e-6 diag: positions that round to the same cell become one vertex
        key = np.round((v - v.min(0)) / (1e-6 * diag)).astype(np.int64)
        _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
        v, f = v[first], inv.reshape(-1)[f]
    # degenerate faces: repeated vertex, or area below (1e-9 diag)^2 ~ rounding noise
    area2 = np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    keep = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
    keep &= area2 > (1e-9 * diag) ** 2
    f = f[keep]
    if len(f):  # duplicate faces (same vertex set) double-count area and hits
        _, uniq = np.unique(np.sort(f, axis=1), axis=0, return_index=True)
        f = f[np.sort(uniq)]
    if len(f) == 0:
        raise InputError(name, "no triangle with non-zero area")
    used = np.zeros(len(v), dtype=bool)
    used[f.reshape(-1)] = True
    remap = np.cumsum(used) - 1
    v, f = v[used], remap[f]
    n = _area_weighted_normals(v, f)
    return Mesh(
        vertices=torch.as_tensor(v, dtype=torch.float32, device=device),
        faces=torch.as_tensor(f, dtype=torch.int64, device=device),
        normals=torch.as_tensor(n, dtype=torch.float32, device=device),
        name=name,
    )


def load_mesh(path, *, device=None) -> Mesh:
    """Load a mesh file (OBJ, PLY, STL, glTF/GLB, OFF) with trimesh and clean it.

    Scenes with several geometries (glTF, multi-object OBJ) are flattened into one mesh in world
    coordinates. Materials in the file are ignored: lobelight's materials come from the scene
    description.

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
    try:
        loaded = trimesh.load(str(p), force="mesh", process=False, skip_materials=True)
    except Exception as exc:  # trimesh raises many types for corrupt files
        raise InputError(str(p), f"cannot read mesh: {type(exc).__name__}: {exc}") from None
    v = getattr(loaded, "vertices", None)
    f = getattr(loaded, "faces", None)
    if v is None or f is None or len(f) == 0:
        raise InputError(str(p), "file holds no triangles")
    if suffix == ".ply":
        _check_ply_counts(p, len(v), len(f))
    try:
        return mesh_from_arrays(np.asarray(v), np.asarray(f), name=p.name, device=device)
    except InputError as exc:  # name the whole path, as every other error here does
        raise InputError(str(p), exc.problem) from None


def _check_ply_counts(p: Path, n_vertices: int, n_triangles: int) -> None:
    """Refuse a PLY file that holds fewer vertices or faces than its header declares (cut
    short, or a header that lies): trimesh reads what is there and says nothing. Each declared
    face gives one triangle or more (polygons are fanned), so triangles may outnumber faces."""
    with p.open("rb") as fh:
        head = fh.read(1 << 16)
    end = head.find(b"end_header")
    if end < 0:
        return  # trimesh parsed it: nothing declared to check against
    declared = {}
    for line in head[:end].decode("ascii", errors="replace").splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[0] == "element" and parts[2].isdigit():
            declared[parts[1]] = int(parts[2])
    nv, nf = declared.get("vertex"), declared.get("face")
    if nv is not None and n_vertices != nv:
        raise InputError(str(p), f"declares {nv:,} vertices and holds {n_vertices:,} (cut short?)")
    if nf is not None and n_triangles < nf:
        raise InputError(str(p), f"declares {nf:,} faces and holds {n_triangles:,} (cut short?)")


def triangle_areas(mesh: Mesh) -> torch.Tensor:
    """``(F,)`` triangle areas."""
    tri = mesh.vertices[mesh.faces]
    return 0.5 * torch.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], dim=-1).norm(dim=-1)
