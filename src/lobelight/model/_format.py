"""The model file format: a fitted object in one file, checked on read, never unpickled.

Layout: a NumPy ``.npz`` archive (a zip of ``.npy`` arrays, read with ``allow_pickle=False``)
holding

``meta``            UTF-8 JSON (as uint8): ``format`` ("lobelight-model"), ``version``, counts,
                    storage options, materials (:meth:`lobelight.scene.Materials.to_dict`) and
                    provenance (scene name, fit settings, timings, software versions)
``vertices``        (V, 3) float32;  ``faces`` (F, 3) int32;  ``normals`` (V, 3) float32
``views``           (J, 3) float32, the view directions the Gaussians belong to
``keep``            (V, J) bool, which (vertex, view) records are stored
``gaussians``       (K, N, 7) float32 or float16: the paper's 7 floats per Gaussian, RGB weight,
                    mean, sigma, for the K kept records in row-major (vertex, view) order
                    (half-float files store the weight times the Gaussian's integral instead
                    of its peak: ``meta["weights"] == "integral"``); the last
                    ``meta["indirect_gaussians"]`` (0 when absent) of the N hold indirect
                    glossy transport (:attr:`lobelight.model.Model.indirect_gaussians`)
``diffuse``         (V, n, 3) SH diffuse transfer
``bounce``          optional (V, n, 3): the interreflected part of ``diffuse``, lit by the sun
                    as well (the self-shadowed part sees the sun per pixel)
``visibility``      optional (V, R, R) uint8: each vertex's octahedral visibility tile
                    (:func:`lobelight.model.visibility_tiles`; computed from the mesh when absent)
``hit_*``           optional, with ``visibility``: the hit tiles (:func:`lobelight.model.hit_tiles`;
                    computed from the mesh when absent), the triangle and distance each tile
                    texel's ray hits, stored as the texels that hit (a few percent of them):
                    ``hit_count`` (V,) int32 texels per vertex, then for each of them in vertex
                    order ``hit_texel`` (K,) uint16 its index in the vertex's tile (row-major,
                    ascending), ``hit_face`` (K,) int32 and ``hit_distance`` (K,) float16. The
                    reader also takes the tiles whole, ``hit_face`` (V, R, R) int32 with -1 for
                    none and ``hit_distance`` (V, R, R) float16.
``albedo_*``        optional: the albedo textures read per pixel (``lobelight.model._albedo_file``);
                    with them ``diffuse`` and ``bounce`` are per unit albedo

Beyond the paper's 92 x 7 x V x N floats: ``float16`` halves it, and records are dropped
where they cannot matter. A view's Gaussians enter rendering only through the spherical
triangles of views it belongs to, whose other corners are its geodesic neighbours; if a view
and all its neighbours have zero weight, every triangle it is in interpolates to zero weight,
so its means and widths are never seen. Those records are dropped (on load they come back with
zero weight). Writes go to a temporary name and are renamed into place, so a file is either
whole or absent, and only after the arrays pass the reader's checks (:func:`check`), so a file
written is one the reader accepts. A read holds at most :data:`MAX_READ_BYTES` of arrays and
expanded Gaussians: a file whose declared sizes and counts add up to more is refused before
they are allocated.
"""

from __future__ import annotations

import io
import json
import math
import zipfile
import zlib
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .. import __version__, _container
from .._container import MAX_FILE_BYTES, MAX_READ_BYTES, declared_limit
from .._io import atomic_writer, check_input
from .._tol import SHARPNESS_MIN
from ..errors import InputError
from ..geometry import sphere
from ..lobes import sg
from ..lobes.sg import Gaussians
from ..scene import AlbedoTexture, Materials, Mesh, check_precision
from ._albedo_file import ALBEDO_ARRAYS, ALBEDO_DTYPES, albedo_arrays, check_albedo, read_albedo
from ._stored import HitTexels, StoredGaussians, hit_offsets

__all__ = [
    "FORMAT",
    "MAX_LIGHT",
    "MAX_READ_BYTES",
    "SIGMA_MAX",
    "SIGMA_MIN",
    "VERSION",
    "check",
    "read",
    "write",
]

FORMAT = "lobelight-model"
VERSION = 1
_ARRAYS = ("meta", "vertices", "faces", "normals", "views", "keep", "gaussians", "diffuse")
_HITS = ("hit_count", "hit_texel", "hit_face", "hit_distance")
_OPTIONAL = ("bounce", "visibility", *_HITS, *ALBEDO_ARRAYS)


#: The most light a Gaussian, or a transfer coefficient, of a fitted model carries: they are
#: reflectances (at most about 1 for a physical material), and values near float32's range
#: rendered Inf pixels.
MAX_LIGHT = 1e4


def _kept(w: torch.Tensor, views: torch.Tensor) -> torch.Tensor:
    """(V, J) records that rendering can see: weight at the view or at a neighbouring view."""
    live = w.amax((-1, -2)) > 0  # (V, J)
    j = views.shape[0]
    if j != 92:  # not the geodesic set: keep everything
        return torch.ones_like(live)
    nbr = sphere.geodesic_neighbor_table(device=w.device)
    near = live[:, nbr.clamp_min(0)] & (nbr >= 0)  # (V, J, 6)
    return live | near.any(-1)


def write(
    path,
    mesh: Mesh,
    materials: Materials,
    g: Gaussians,
    views: torch.Tensor,
    diffuse: torch.Tensor,
    *,
    float16: bool,
    drop: bool,
    provenance: dict[str, Any] | None,
    bounce: torch.Tensor | None = None,
    indirect_gaussians: int = 0,
    visibility: torch.Tensor | None = None,
    hits: tuple[torch.Tensor, torch.Tensor] | HitTexels | None = None,
    albedo: AlbedoTexture | None = None,
) -> dict[str, Any]:
    """Write a model file atomically (module docstring); returns sizes (bytes, records kept).

    ``g``: the Gaussians, ``(V, J, N)``, of ``views (J, 3)``; ``diffuse (V, n, 3)``; ``float16``
    stores the Gaussians and SH as half floats; ``drop`` leaves out the records no rendering
    can see; the last ``indirect_gaussians`` of the N hold indirect glossy transport.

    The arrays pass the reader's checks (:func:`check`) before anything is written, so a file
    this writes is one :func:`read` accepts.

    Raises
    ------
    InputError
        naming ``path``: its folder is missing, or the model fails a check of the reader
        (non-finite Gaussians, say), with the check's problem.
    """
    p = Path(path)
    if not p.parent.is_dir():
        raise InputError(str(p), f"the directory {str(p.parent)!r} does not exist")
    v, j, n = g.lam.shape
    keep = _kept(g.w, views) if drop else torch.ones(v, j, dtype=torch.bool)
    w = g.w
    if float16:
        # peak weights of sharp lobes reach 1e5 and more; their integrals w 2 pi / lam (the
        # light the lobe carries, at most the albedo) fit half floats with full relative
        # precision, so half-float files store those
        w = w * sg.integral(g.lam.double()).to(w.dtype)[..., None]
    # widths up to SHARPNESS_MIN^-1/2; half floats hold up to 65504, a lobe as flat over the
    # sphere as a wider one (they differ by under 2 lam = 5e-10 anywhere)
    sigma = g.lam.clamp_min(SHARPNESS_MIN).rsqrt().clamp_max(_SIGMA_F16 if float16 else SIGMA_MAX)
    rec = torch.cat([w, g.mu, sigma[..., None]], -1)  # (V, J, N, 7)
    kept = rec[keep.to(rec.device)]  # (K, N, 7)
    dt = np.float16 if float16 else np.float32
    if float16 and float(rec[..., :3].abs().max()) > 65504:
        raise InputError("float16", "Gaussian integrals exceed the half-float range")
    meta = {
        "format": FORMAT,
        "version": VERSION,
        "n_vertices": v,
        "n_views": j,
        "n_gaussians": n,
        "indirect_gaussians": int(indirect_gaussians),
        "sh_order": round(diffuse.shape[1] ** 0.5),
        "float16": bool(float16),
        "weights": "integral" if float16 else "peak",
        "materials": materials.to_dict(),
        "provenance": {"lobelight": __version__, **(provenance or {})},
    }
    try:
        text = json.dumps(meta)
    except (TypeError, ValueError) as exc:  # a provenance value JSON cannot hold
        raise InputError(str(p), f"cannot write the model's metadata: {exc}") from None
    arrays = {
        "meta": np.frombuffer(text.encode(), dtype=np.uint8),
        "vertices": mesh.vertices.detach().cpu().numpy().astype(np.float32),
        "faces": mesh.faces.cpu().numpy().astype(np.int32),
        "normals": mesh.normals.detach().cpu().numpy().astype(np.float32),
        "views": views.detach().cpu().numpy().astype(np.float32),
        "keep": keep.cpu().numpy(),
        "gaussians": kept.detach().cpu().numpy().astype(dt),
        "diffuse": diffuse.detach().cpu().numpy().astype(dt),
    }
    if bounce is not None:
        arrays["bounce"] = bounce.detach().cpu().numpy().astype(dt)
    if visibility is not None:
        arrays["visibility"] = visibility.cpu().numpy().astype(np.uint8)
    if hits is not None:
        texels = hits if isinstance(hits, HitTexels) else HitTexels.of_tiles(*hits)
        arrays.update(texels.arrays())
    arrays.update(albedo_arrays(albedo))
    try:
        check(arrays, str(p))
    except InputError as exc:
        raise InputError(str(p), f"not written, a reader would refuse it: {exc.problem}") from None
    with atomic_writer(p) as f:
        np.savez_compressed(f, **arrays)
    return {
        "bytes": p.stat().st_size,
        "records": int(keep.sum()),
        "records_total": v * j,
        "floats_paper": 92 * 7 * v * n,
    }


def _hits(a: dict[str, np.ndarray]) -> tuple[torch.Tensor, torch.Tensor] | HitTexels:
    """The hit tiles of checked arrays as the file holds them: whole tiles ``(face, distance)``
    ``(V, R, R)``, or their texels that hit."""
    if "hit_texel" not in a:
        return _tensor(a["hit_face"]), _tensor(a["hit_distance"])
    return HitTexels(*(a[k] for k in _HITS), res=int(a["visibility"].shape[-1]))


def _need(cond: bool, name: str, problem: str) -> None:
    if not cond:
        raise InputError(name, problem)


def _is_zip(path: Path) -> bool:
    """Whether the file starts as a zip archive (a model file is an ``.npz``)."""
    try:
        with path.open("rb") as f:
            return f.read(4) in (b"PK\x03\x04", b"PK\x05\x06")
    except OSError:
        return False


def _not_a_model(path: Path) -> str:
    """The problem with a file that is not a model, with what to do when it is a mesh/scene."""
    ext = path.suffix.lower()
    if ext in (".ply", ".obj", ".stl", ".glb", ".gltf", ".off", ".toml", ".json"):
        return f"not a lobelight model ({ext} is a mesh or scene: bake it first, lobelight bake)"
    return "not a lobelight model file (not an .npz archive)"


#: Bytes of the metadata beyond ``_META_PER_VERTEX_BYTE`` times the vertex array's bytes: the
#: settings, provenance and material records (a per-vertex albedo in the materials takes at
#: most 76 bytes of JSON per vertex, under 7 times the vertex's 12 bytes of position).
_META_SLACK = 16 << 20
_META_PER_VERTEX_BYTE = 7

#: The widths ``sigma`` a model file holds, in radians: at least 1e-6 (the sharpness
#: ``sigma**-2`` stays a finite float32), at most :data:`lobelight._tol.SHARPNESS_MIN`
#: ``**-0.5`` (the writer's floor of the sharpness; a lobe that wide is flat over the sphere).
SIGMA_MIN = 1e-6
SIGMA_MAX = SHARPNESS_MIN**-0.5
# the widest half-float width (65504): half-float files hold widths up to it
_SIGMA_F16 = 65504.0
# float32's rsqrt rounds by a few ulps (1e-7 relative): a width written at SIGMA_MAX reads
# back within this fraction above it
_SIGMA_ROUNDING = 1e-5

# bytes per expanded Gaussian: 7 float32 (RGB weight, mean, sharpness)
_GAUSSIAN_BYTES = 28


def _check_sizes(archive: zipfile.ZipFile, file_bytes: int, name: str) -> None:
    """Refuse an archive whose members would decompress to more than
    :func:`lobelight._container.declared_limit` of the file's size, or whose
    metadata is larger than its vertices could need: the memory a read takes is bounded by
    that. The sizes are those the zip directory declares, which decompression never exceeds."""
    total = sum(info.file_size for info in archive.infolist())
    limit = declared_limit(file_bytes)
    _need(
        total <= limit,
        name,
        f"its members would decompress to {total:,} bytes, over {limit:,} for a file of "
        f"{file_bytes:,} bytes: not a model file",
    )
    sizes = {i.filename.removesuffix(".npy"): i.file_size for i in archive.infolist()}
    _check_meta_size(sizes.get("meta", 0), sizes.get("vertices", 0), name)


def _check_meta_size(meta_bytes: int, vertex_bytes: int, name: str) -> None:
    limit = _META_SLACK + _META_PER_VERTEX_BYTE * vertex_bytes
    _need(
        meta_bytes <= limit,
        name,
        f"its metadata takes {meta_bytes:,} bytes, over {limit:,} for its vertices",
    )


def read(path) -> dict[str, Any]:
    """Read and check a model file: the :class:`lobelight.model.Model` fields it holds.

    The container is checked first (:func:`_open`: a zip of arrays whose declared sizes fit
    :data:`MAX_READ_BYTES`), then everything :func:`check` checks, before the model is built.

    Returns
    -------
    dict with ``mesh``, ``views (J, 3)``, ``gaussians`` (``(V, J, N)``, a
    :class:`~lobelight.model._stored.StoredGaussians`: expanded to every record on first use),
    ``diffuse (V, n, 3)``, ``materials``, ``provenance``, ``bounce`` (or None),
    ``indirect_gaussians``, ``visibility`` (or None), ``hits`` (whole tiles ``(face,
    distance)``, the texels that hit as :class:`~lobelight.model.HitTexels`, or None) and
    ``albedo`` (:class:`lobelight.scene.AlbedoTexture` or None), all on the CPU

    Raises
    ------
    InputError
        naming the file: missing, not a model file, unknown version, missing or malformed
        arrays, non-finite values, inconsistent shapes, sizes over the limits.
    """
    p = Path(path)
    name = str(p)
    a = _open(p, name)
    h, mats = check(a, name)
    # expanded to every (vertex, view) record on first use (:mod:`._stored`)
    integral = h.meta.get("weights", "peak") == "integral"
    g = StoredGaussians(a["gaussians"], a["keep"], integral_weights=integral)
    out = _build(p, a, h, mats, g)
    vis = a.get("visibility")
    # the arrays read are this read's own and writable: copied only where not C-ordered
    out["visibility"] = None if vis is None else _tensor(vis)
    out["hits"] = _hits(a) if "hit_face" in a else None
    out["albedo"] = read_albedo(a)
    return out


def _tensor(arr: np.ndarray) -> torch.Tensor:
    """A C-ordered tensor of an array read from the file (sharing its memory where it is)."""
    return torch.from_numpy(np.ascontiguousarray(arr))


def check(a: dict[str, np.ndarray], name: str) -> tuple[_Header, Materials]:
    """Every check of a model's arrays (those of a file, or those about to be written): the
    dtypes (:func:`_check_dtypes`), the metadata (:func:`_header`), the memory the model takes
    (:func:`_check_memory`), the arrays against the metadata (:func:`_check_arrays`), the light
    they carry (:func:`_check_transfer`), the optional tiles, the provenance
    (:func:`_check_provenance`) and the materials. Nothing is allocated beyond the arrays'
    size. Returns the checked metadata and the materials.

    Raises
    ------
    InputError
        naming ``name`` and the part of the model at fault.
    """
    missing = [k for k in _ARRAYS if k not in a]
    _need(not missing, name, f"not a lobelight model file (missing {missing})")
    for k, arr in a.items():
        # a member without the .npy header comes back as raw bytes
        _need(isinstance(arr, np.ndarray), name, f"{k} is not an array")
    _check_dtypes(a, name)
    _need(a["meta"].ndim == 1 and a["vertices"].ndim >= 1, name, "meta must be UTF-8 bytes")
    _check_meta_size(a["meta"].nbytes, a["vertices"].nbytes, name)
    h = _header(a["meta"], name)
    _check_memory(a, h, name)
    _check_arrays(a, h, name)
    _check_transfer(a["diffuse"], a.get("bounce"), name)
    n_faces = int(a["faces"].shape[0])
    _check_tiles(a, h.v, n_faces, name)
    check_albedo(a, h.v, name)
    _check_provenance(h.provenance, name)
    return h, _materials(h, name)


#: The dtypes each array may have: floating arrays any of float16, float32 and float64 (read
#: as float32, so their values must be finite in float32), faces any integer type.
_FLOATS = (np.dtype(np.float16), np.dtype(np.float32), np.dtype(np.float64))
_DTYPES = {
    "meta": ((np.dtype(np.uint8),), "UTF-8 bytes (uint8)"),
    "vertices": (_FLOATS, "floating point"),
    "normals": (_FLOATS, "floating point"),
    "views": (_FLOATS, "floating point"),
    "gaussians": (_FLOATS, "floating point"),
    "diffuse": (_FLOATS, "floating point"),
    "bounce": (_FLOATS, "floating point"),
    "keep": ((np.dtype(np.bool_),), "boolean"),
    "visibility": ((np.dtype(np.uint8),), "uint8"),
    "hit_count": ((np.dtype(np.int32),), "int32"),
    "hit_texel": ((np.dtype(np.uint16),), "uint16"),
    "hit_face": ((np.dtype(np.int32),), "int32"),
    "hit_distance": ((np.dtype(np.float16),), "float16"),
    **ALBEDO_DTYPES,
}


def _check_dtypes(a: dict[str, np.ndarray], name: str) -> None:
    """Each array of a dtype it may have (strings, objects, structures and the like are not)."""
    for k, arr in a.items():
        if k == "faces":
            ok, what = arr.dtype.kind in "iu", "integers"
        elif k in _DTYPES:
            allowed, what = _DTYPES[k]
            ok = arr.dtype in allowed
        else:
            continue
        _need(ok, name, f"{k} must be {what}, got dtype {str(arr.dtype)!r}")


def _check_memory(a: dict[str, np.ndarray], h: _Header, name: str) -> None:
    """The arrays and the Gaussians expanded to every (vertex, view) record within
    :data:`MAX_READ_BYTES`, before the expansion is allocated."""
    arrays = sum(arr.nbytes for arr in a.values())
    expanded = _GAUSSIAN_BYTES * h.v * h.j * h.n
    vis = a.get("visibility")
    if "hit_texel" in a and vis is not None and vis.ndim == 3:  # the tiles made whole: 6 B each
        expanded += 6 * h.v * vis.shape[-1] * vis.shape[-1]
    total = arrays + expanded
    _need(
        total <= MAX_READ_BYTES,
        name,
        f"{h.v:,} vertices with {h.n} Gaussian(s) per view take {total / 2**30:.1f} GiB "
        f"in memory, over the reader's limit of {MAX_READ_BYTES / 2**30:g} GiB",
    )


def _check_tiles(a: dict[str, np.ndarray], v: int, n_faces: int, name: str) -> None:
    """The optional tiles: visibility ``(V, R, R)`` uint8 with ``R >= 2``; hit tiles stored
    whole or as their texels that hit (module docstring), every array of them or none."""
    vis = a.get("visibility")
    if vis is not None:
        ok = vis.ndim == 3 and vis.shape[0] == v and vis.shape[1] == vis.shape[2] >= 2
        _need(ok, name, f"visibility must be ({v}, R, R) uint8 tiles, got {vis.shape}")
    held = [k for k in _HITS if k in a]
    if not held:
        return
    face, dist = a.get("hit_face"), a.get("hit_distance")
    if "hit_texel" in a or "hit_count" in a:
        _need(len(held) == len(_HITS), name,
              f"the hit tiles are {', '.join(_HITS)} together; the file holds {held}")  # fmt: skip
        _check_sparse_hits(a, vis, v, name)
        lo_face = 0
    else:
        _need(face is not None and dist is not None, name,
              "hit_face and hit_distance come together; the file holds only one")  # fmt: skip
        ok = face.ndim == 3 and face.shape[0] == v and face.shape[1] == face.shape[2] >= 2
        _need(ok, name, f"hit_face must be ({v}, R, R) int32 tiles, got {face.shape}")
        _need(vis is None or face.shape == vis.shape, name,
              "hit tiles and visibility tiles differ in resolution")  # fmt: skip
        lo_face = -1
    _need(dist.shape == face.shape, name,
          f"hit_distance must be {face.shape} float16, got {dist.shape}")  # fmt: skip
    if face.size:
        lo, hi = torch.aminmax(torch.from_numpy(face))
        _need(int(lo) >= lo_face and int(hi) < n_faces, name,
              f"hit_face holds triangle ids outside {lo_face}..{n_faces - 1}")  # fmt: skip
    _need(_distances_fine(dist), name, "hit_distance holds negative or non-finite distances")


def _check_sparse_hits(a: dict[str, np.ndarray], vis, v: int, name: str) -> None:
    """Hit tiles stored as their texels that hit: the visibility tiles held (their
    resolution is the tiles'), a count per vertex adding up to the texels stored, and each
    vertex's texels inside its tile and ascending (no texel twice)."""
    count, texel, face = a["hit_count"], a["hit_texel"], a["hit_face"]
    _need(vis is not None, name, "hit tiles stored by texel need the visibility tiles")
    rr = vis.shape[-1] ** 2
    _need(rr <= 65536, name, f"hit tiles of {vis.shape[-1]}² texels: at most 256² by texel")
    _need(count.shape == (v,), name, f"hit_count must be ({v},) int32, got {count.shape}")
    _need(texel.ndim == 1 and face.shape == texel.shape, name,
          f"hit_texel and hit_face must be (K,), got {texel.shape} and {face.shape}")  # fmt: skip
    total = int(count.sum(dtype=np.int64))
    k = texel.shape[0]
    _need(bool((count >= 0).all()) and total == k, name,
          f"hit_count must be counts adding up to the {k:,} texels stored")  # fmt: skip
    if texel.size:
        _need(int(texel.max()) < rr, name, f"hit_texel holds texels outside 0..{rr - 1}")
        flat = hit_offsets(count, texel, rr)
        _need(
            bool((flat[1:] > flat[:-1]).all()),
            name,
            "hit_texel must ascend within each vertex's tile (no texel twice)",
        )


def _distances_fine(dist: np.ndarray) -> bool:
    """Whether float16 distances are all finite and not negative (-0 is not): read from their
    bits where every one is a finite value >= +0 (sign bit clear, exponent not all ones: as
    int16, 0..0x7BFF), else from their values."""
    if not dist.size:
        return True
    lo, hi = torch.aminmax(torch.from_numpy(dist.view(np.int16)))
    if int(lo) >= 0 and int(hi) <= 0x7BFF:
        return True
    return bool(np.isfinite(dist).all()) and not bool((dist < 0).any())


@dataclass(frozen=True)
class _Header:
    """What a model file's metadata says, checked: the metadata itself, its provenance, and
    the counts of vertices ``v``, views ``j``, Gaussians per view ``n`` and indirect ones
    ``ni``."""

    meta: dict[str, Any]
    provenance: dict[str, Any]
    v: int
    j: int
    n: int
    ni: int


#: What reading a damaged archive raises, besides InputError: each becomes one InputError.
_UNREADABLE = (
    zipfile.BadZipFile,
    zlib.error,
    ValueError,
    OSError,
    EOFError,
    KeyError,
    NotImplementedError,  # an unknown zip compression method
    RuntimeError,  # an encrypted zip member
    MemoryError,
)


def _open(p: Path, name: str) -> dict[str, np.ndarray]:
    """The container: a regular zip archive of ``.npy`` arrays holding every array of
    ``_ARRAYS``, of a plausible expanded size. Returns the arrays, with those of ``_OPTIONAL``
    it holds (:func:`_read_members`)."""
    check_input(p, limit=MAX_FILE_BYTES)  # a regular file (not a device or pipe)
    _need(_is_zip(p), name, _not_a_model(p))
    try:
        z = np.load(p, allow_pickle=False)
        # a bare .npy file loads as an array: not an archive of arrays
        _need(isinstance(z, np.lib.npyio.NpzFile), name, "not a lobelight model file (not npz)")
        with z:
            missing = [k for k in _ARRAYS if k not in z.files]
            _need(not missing, name, f"not a lobelight model file (missing {missing})")
            _check_sizes(z.zip, p.stat().st_size, name)  # before anything is decompressed
            keys = [k for k in (*_ARRAYS, *_OPTIONAL) if k in z.files]
            return _read_members(z, p, keys, name)
    except InputError:
        raise
    except _UNREADABLE as exc:
        raise InputError(name, f"cannot read model file: {type(exc).__name__}: {exc}") from None


#: Threads that decompress a model file's members at once (zlib lets go of Python's lock while
#: it inflates), and the decompressed bytes below which a file is read on one thread.
READ_THREADS = 2
_PARALLEL_BYTES = 8 << 20


def _read_members(z, p: Path, keys: list[str], name: str) -> dict[str, np.ndarray]:
    """The members ``keys`` of the open archive ``z`` (as ``z[key]`` reads them): those the
    command line's child inflated ahead where it read this very file (:func:`_read_ahead`),
    else read here, the largest first on :data:`READ_THREADS` threads, each through its own
    handle on ``p`` whose directory must be the one :func:`_check_sizes` checked (a file
    replaced meanwhile is refused, so the declared sizes still bound what is read). A failure
    is the one the first failing member in ``keys``' order raises, as in a read of one member
    after another."""
    directory = _container.directory(z.zip)
    ahead = _read_ahead(p, directory, keys)
    if ahead is not None:
        return ahead
    sizes = {i.filename.removesuffix(".npy"): i.file_size for i in z.zip.infolist()}
    if READ_THREADS < 2 or sum(sizes.get(k, 0) for k in keys) < _PARALLEL_BYTES:
        return {k: z[k] for k in keys}

    def member(key: str) -> np.ndarray:
        with np.load(p, allow_pickle=False) as own:
            same = isinstance(own, np.lib.npyio.NpzFile)
            same = same and _container.directory(own.zip) == directory
            _need(same, name, "the file changed while it was read")
            return own[key]

    with ThreadPoolExecutor(READ_THREADS) as pool:
        futures = {k: pool.submit(member, k) for k in sorted(keys, key=lambda k: -sizes.get(k, 0))}
        try:
            return {k: futures[k].result() for k in keys}
        finally:
            pool.shutdown(cancel_futures=True)


def _read_ahead(p: Path, directory: list[tuple], keys: list[str]) -> dict[str, np.ndarray] | None:
    """The members ``keys`` as the command line's child process inflated them ahead
    (:func:`lobelight._container.take`), parsed as ``np.load`` parses them, sharing the child's
    memory; None where there is no such read ahead of this file, or a member is not a plain
    ``.npy`` array (the file is then read as usual, with its errors)."""
    members = _container.take(p, directory)
    if members is None:
        return None
    out = {}
    for k in keys:
        arr = _npy(members.get(k + ".npy"))
        if arr is None:
            return None
        out[k] = arr
    return out


def _npy(buf: memoryview | None) -> np.ndarray | None:
    """The array of an ``.npy`` file's bytes ``buf``, sharing them (None where ``buf`` is not a
    version 1 or 2 ``.npy`` file of plain data whose size is its header's)."""
    if buf is None:
        return None
    fmt = np.lib.format
    try:
        head = io.BytesIO(bytes(buf[: _NPY_HEADER_MAX + 12]))
        version = fmt.read_magic(head)
        read_header = {(1, 0): fmt.read_array_header_1_0, (2, 0): fmt.read_array_header_2_0}
        shape, fortran, dtype = read_header[version](head, max_header_size=_NPY_HEADER_MAX)
    except (ValueError, KeyError, EOFError):
        return None
    count = math.prod(shape)
    offset = head.tell()
    if dtype.hasobject or len(buf) != offset + count * dtype.itemsize:
        return None
    arr = np.frombuffer(buf, dtype, count, offset)
    return arr.reshape(shape, order="F" if fortran else "C")


# the largest .npy header parsed (NumPy's own default limit)
_NPY_HEADER_MAX = 10_000


def _header(raw: np.ndarray, name: str) -> _Header:
    """The metadata: UTF-8 JSON of this format and version, with counts in range (checked
    before anything is allocated from them)."""
    try:
        meta = json.loads(bytes(raw).decode())
    except (ValueError, UnicodeDecodeError) as exc:
        raise InputError(name, f"corrupt metadata: {exc}") from None
    except RecursionError:
        raise InputError(name, "corrupt metadata: nested too deep to read") from None
    _need(isinstance(meta, dict) and meta.get("format") == FORMAT, name, "not a lobelight model")
    prov = meta.get("provenance", {})
    _need(isinstance(prov, dict), name, "provenance must be a mapping")
    _need(
        meta.get("weights", "peak") in ("peak", "integral"),
        name,
        f"unknown weights encoding {meta.get('weights')!r:.40}",
    )
    _need(
        meta.get("version") == VERSION,
        name,
        f"model format version {meta.get('version')!r:.40}; this lobelight reads version {VERSION}",
    )
    v, j, n = (_count(meta.get(k), k, name) for k in ("n_vertices", "n_views", "n_gaussians"))
    # bounds before anything is allocated from these counts
    _need(1 <= n <= 8, name, f"n_gaussians must be 1..8, got {n}")
    ni = meta.get("indirect_gaussians", 0)
    _need(
        _is_int(ni) and 0 <= ni < n,
        name,
        f"indirect_gaussians must be a whole number in 0..{n - 1}, got {ni!r:.40}",
    )
    # every renderer and Model.transport blend between the 92 geodesic views
    _need(
        j == sphere.N_VIEWS, name, f"n_views must be {sphere.N_VIEWS} (the geodesic views), got {j}"
    )
    _need(3 <= v <= 1 << 26, name, f"n_vertices must be 3..{1 << 26}, got {v}")
    return _Header(meta, prov, v, j, n, ni)


def _is_int(x: Any) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def _count(x: Any, key: str, name: str) -> int:
    _need(x is not None, name, "metadata lacks the vertex, view or Gaussian counts")
    _need(_is_int(x), name, f"{key} must be a whole number, got {x!r:.40}")
    return x


def _check_arrays(a: dict[str, np.ndarray], h: _Header, name: str) -> None:
    """Each array against the header: shapes, finite values in float32, then the geometry, the
    views, the SH order and the stored Gaussians' means, widths and weights."""
    _check_shapes(a, h, name)
    for k in ("vertices", "normals", "views", "gaussians", "diffuse", "bounce"):
        if k in a:
            _need(_finite32(a[k]), name, f"{k} has NaN or Inf values, or values beyond float32")
    _check_geometry(a, h.v, name)
    _check_sh_order(a["diffuse"], h.meta, name)
    _check_records(a["gaussians"], h.meta.get("weights", "peak") == "integral", name)


def _finite32(arr: np.ndarray) -> bool:
    """Whether every value of ``arr`` is finite once read as float32."""
    with np.errstate(over="ignore", invalid="ignore"):  # float64 beyond float32 becomes Inf
        return bool(np.isfinite(arr.astype(np.float32, copy=False)).all())


def _check_shapes(a: dict[str, np.ndarray], h: _Header, name: str) -> None:
    v, j, n = h.v, h.j, h.n
    shapes = {
        "vertices": (v, 3),
        "normals": (v, 3),
        "views": (j, 3),
        "keep": (v, j),
    }
    for k, shape in shapes.items():
        _need(a[k].shape == shape, name, f"{k} has shape {a[k].shape}, expected {shape}")
    kept = int(a["keep"].sum())
    _need(
        a["gaussians"].shape == (kept, n, 7),
        name,
        f"gaussians has shape {a['gaussians'].shape}, expected {(kept, n, 7)}",
    )
    _need(a["faces"].ndim == 2 and a["faces"].shape[1] == 3, name, "faces must be (F, 3)")
    _need(
        a["diffuse"].ndim == 3 and a["diffuse"].shape[0] == v and a["diffuse"].shape[2] == 3,
        name,
        f"diffuse has shape {a['diffuse'].shape}",
    )
    b = a.get("bounce")
    if b is not None:
        _need(b.shape == a["diffuse"].shape, name,
              f"bounce has shape {b.shape}, diffuse {a['diffuse'].shape}")  # fmt: skip


def _check_geometry(a: dict[str, np.ndarray], v: int, name: str) -> None:
    """Faces, vertices, normals and views: indices in range, an extent, no zero vectors, and
    the views the geodesic set."""
    f = a["faces"]
    _need(f.shape[0] > 0, name, "has no faces")
    _need(f.min() >= 0 and f.max() < v, name, "face index out of range")
    # the vertices the faces use, held to a loaded mesh's own checks (size, distance)
    check_precision(a["vertices"][np.unique(f)], name)
    for k in ("normals", "views"):
        norm = np.linalg.norm(a[k].astype(np.float64), axis=-1)
        _need(bool((norm > 1e-6).all()), name, f"{k} has zero vectors")
    geodesic = sphere.geodesic_views(dtype=torch.float64).numpy()
    views = a["views"].astype(np.float64)
    unit = views / np.linalg.norm(views, axis=-1, keepdims=True)
    # within float32 rounding of the geodesic set, in its order
    _need(
        float((unit * geodesic).sum(-1).min()) > 1 - 1e-6,
        name,
        "views are not the 92 geodesic views in their order",
    )


def _check_sh_order(diffuse: np.ndarray, meta: dict[str, Any], name: str) -> None:
    order = meta.get("sh_order", 5)
    _need(
        _is_int(order) and 1 <= order <= 10,
        name,
        f"sh_order must be a whole number in 1..10, got {order!r:.40}",
    )
    _need(
        diffuse.shape[1] == order**2,
        name,
        f"diffuse has {diffuse.shape[1]} SH coefficients, sh_order {order}",
    )


def _check_records(g7: np.ndarray, integral: bool, name: str) -> None:
    """The stored Gaussians (K, N, 7): means not zero, widths in ``SIGMA_MIN..SIGMA_MAX``,
    weights non-negative, none carrying more than :data:`MAX_LIGHT` (the weight times the
    Gaussian's integral; ``integral``: the weights stored are that product).

    Decided in float32 where that is plain (:func:`_records_plainly_fine`), else in float64
    (:func:`_check_records_f64`), whose verdict and message are the check's."""
    if not g7.size:
        return
    if g7.dtype == np.float64 or not _records_plainly_fine(g7, integral):
        _check_records_f64(g7, integral, name)


#: Relative rounding float32's arithmetic stays far within (a few ulps of 6e-8): a float32
#: value this far on the right side of a bound is on it in float64 as well.
_F32_MARGIN = 1e-4


def _records_plainly_fine(g7: np.ndarray, integral: bool) -> bool:
    """Whether float32 arithmetic shows every record of ``g7`` (K, N, 7), float32 or float16,
    within :func:`_check_records`' bounds by more than :data:`_F32_MARGIN` (False: decide
    in float64). The widths' range and the weights' signs are exact in any dtype; the light a
    record carries is bounded above by its largest weight times ``min(2 pi sigma^2, 4 pi)``
    (the Gaussian's integral ``2 pi (1 - exp(-2 / sigma^2)) sigma^2`` is below both)."""
    t = torch.from_numpy(g7).reshape(-1, 7)  # (K N, 7), no copy
    lo, hi = (float(x) for x in torch.aminmax(t[:, 6]))
    if not (SIGMA_MIN <= lo and hi <= SIGMA_MAX * (1 + _SIGMA_ROUNDING)):
        return False
    if float(t[:, :3].amin(-1).min()) < 0:
        return False
    m = t[:, 3:6].float()  # (K N, 3) the means
    norm2 = m[:, 0].square().addcmul_(m[:, 1], m[:, 1]).addcmul_(m[:, 2], m[:, 2])  # (K N,)
    if not float(norm2.min()) > 1e-12 * (1 + _F32_MARGIN):
        return False
    w = t[:, :3].amax(-1).float()  # (K N,) the largest channel: the one that carries most
    if not integral:
        w = w * t[:, 6].float().square().mul_(2 * math.pi).clamp_max_(4 * math.pi)
    return float(w.max()) <= MAX_LIGHT * (1 - _F32_MARGIN)


def _check_records_f64(g7: np.ndarray, integral: bool, name: str) -> None:
    """:func:`_check_records` in float64."""
    _need(
        bool((np.linalg.norm(g7[..., 3:6].astype(np.float64), axis=-1) > 1e-6).all()),
        name,
        "a Gaussian mean is a zero vector",
    )
    sig = g7[..., 6].astype(np.float64)  # (K, N)
    lo, hi = float(sig.min()), float(sig.max())
    _need(
        SIGMA_MIN <= lo and hi <= SIGMA_MAX * (1 + _SIGMA_ROUNDING),
        name,
        f"Gaussian widths (sigma) must be in {SIGMA_MIN:g}..{SIGMA_MAX:g} radians, "
        f"got {lo:.3g}..{hi:.3g}",
    )
    w = g7[..., :3].astype(np.float64)  # (K, N, 3)
    _need(bool((w >= 0).all()), name, "Gaussian weights must be non-negative")
    if not integral:
        w = w * sg.integral(torch.from_numpy(sig**-2)).numpy()[..., None]
    carried = float(w.max())
    _need(
        carried <= MAX_LIGHT,
        name,
        f"a Gaussian carries {carried:.3g} of light, over {MAX_LIGHT:g}: not a fitted model",
    )


def _check_transfer(diffuse: np.ndarray, bounce: np.ndarray | None, name: str) -> None:
    """No SH transfer coefficient over :data:`MAX_LIGHT`."""
    for k, arr in (("diffuse", diffuse), ("bounce", bounce)):
        if arr is not None and arr.size and float(np.abs(arr).max()) > MAX_LIGHT:
            raise InputError(name, f"{k} transfer over {MAX_LIGHT:g}: not a fitted model")


#: Provenance entries the commands read, and the JSON types each must have (other entries are
#: kept as they are).
_PROVENANCE = {
    "scene": (str,),
    "environment": (str,),
    "camera": (dict,),
    "n_gaussians_choice": (dict, str),
    "materials": (list,),
    "seconds": (dict,),
    "memory": (dict,),
    "weights": (dict,),
    "lobelight": (str,),
}
#: Provenance entries that are counts (whole numbers, at least 0).
_PROVENANCE_COUNTS = (
    "bounces",
    "indirect_paths",
    "n_gaussians",
    "flips_before",
    "flips_after",
    "separated_flips_before",
    "separated_flips_after",
)


def _check_provenance(prov: dict[str, Any], name: str) -> None:
    """The provenance entries the commands read, of the types the writer gives them: strings,
    mappings and lists, counts, stage times and the fit's error (finite numbers, at least 0)."""
    for k, types in _PROVENANCE.items():
        x = prov.get(k)
        _need(x is None or isinstance(x, types), name,
              f"provenance {k} must be {' or '.join(_JSON_NAMES[t] for t in types)}, "
              f"got {type(x).__name__}")  # fmt: skip
    for k in _PROVENANCE_COUNTS:
        x = prov.get(k)
        _need(x is None or (_is_int(x) and x >= 0), name,
              f"provenance {k} must be a whole number >= 0, got {x!r:.40}")  # fmt: skip
    numbers = {f"seconds.{k}": x for k, x in (prov.get("seconds") or {}).items()}
    numbers["relative_l2_error_mean"] = prov.get("relative_l2_error_mean")
    for k, x in numbers.items():
        ok = x is None or (isinstance(x, int | float) and not isinstance(x, bool))
        _need(ok and (x is None or (math.isfinite(x) and x >= 0)), name,
              f"provenance {k} must be a finite number >= 0, got {x!r:.40}")  # fmt: skip


_JSON_NAMES = {str: "a string", dict: "a mapping", list: "a list"}


def _materials(h: _Header, name: str) -> Materials:
    """The materials of the metadata, for the model's vertices."""
    try:
        return Materials.from_dict(h.meta.get("materials"), h.v)
    except (KeyError, TypeError) as exc:
        raise InputError(name, f"bad materials entry: {exc}") from None
    except InputError as exc:
        raise InputError(name, f"bad materials entry: {exc}") from None


def _build(p: Path, a, h: _Header, mats: Materials, g: Gaussians) -> dict[str, Any]:
    """The fields of the model from the checked arrays: the mesh (named by the provenance's
    scene), the transfer, and the rest as read."""
    mesh = Mesh(
        vertices=torch.from_numpy(a["vertices"].astype(np.float32)),
        faces=torch.from_numpy(a["faces"].astype(np.int64)),
        normals=torch.from_numpy(a["normals"].astype(np.float32)),
        name=str(h.provenance.get("scene", p.stem)),
    )
    b = a.get("bounce")
    return {
        "mesh": mesh,
        "views": torch.from_numpy(a["views"].astype(np.float32)),
        "gaussians": g,
        "diffuse": torch.from_numpy(a["diffuse"].astype(np.float32)),
        "materials": mats,
        "provenance": dict(h.provenance),
        "bounce": None if b is None else torch.from_numpy(b.astype(np.float32)),
        "indirect_gaussians": h.ni,
    }
