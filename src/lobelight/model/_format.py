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
``hit_face``        optional (V, R, R) int32, with ``hit_distance`` (V, R, R) float16: the
                    triangle and distance each tile texel's ray hits, -1 and 0 for none
                    (:func:`lobelight.model.hit_tiles`; computed from the mesh when absent)

Beyond the paper's 92 x 7 x V x N floats: ``float16`` halves it, and records are dropped
where they cannot matter. A view's Gaussians enter rendering only through the spherical
triangles of views it belongs to, whose other corners are its geodesic neighbours; if a view
and all its neighbours have zero weight, every triangle it is in interpolates to zero weight,
so its means and widths are never seen. Those records are dropped (on load they come back with
zero weight). Writes go to a temporary name and are renamed into place, so a file is either
whole or absent.
"""

from __future__ import annotations

import json
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .. import __version__
from .._io import atomic_writer, check_input
from .._tol import SHARPNESS_MIN
from ..errors import InputError
from ..geometry import sphere
from ..lobes import sg
from ..lobes.sg import Gaussians
from ..scene import Materials, Mesh

__all__ = ["FORMAT", "MAX_LIGHT", "VERSION", "read", "write"]

FORMAT = "lobelight-model"
VERSION = 1
_ARRAYS = ("meta", "vertices", "faces", "normals", "views", "keep", "gaussians", "diffuse")
_OPTIONAL = ("bounce", "visibility", "hit_face", "hit_distance")


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
    hits: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> dict[str, Any]:
    """Write a model file atomically (module docstring); returns sizes (bytes, records kept).

    ``g``: the Gaussians, ``(V, J, N)``, of ``views (J, 3)``; ``diffuse (V, n, 3)``; ``float16``
    stores the Gaussians and SH as half floats; ``drop`` leaves out the records no rendering
    can see; the last ``indirect_gaussians`` of the N hold indirect glossy transport.
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
    sigma = g.lam.clamp_min(SHARPNESS_MIN).rsqrt()  # (V, J, N)
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
    arrays = {
        "meta": np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8),
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
        arrays["hit_face"] = hits[0].cpu().numpy().astype(np.int32)
        arrays["hit_distance"] = hits[1].cpu().numpy().astype(np.float16)
    with atomic_writer(p) as f:
        np.savez_compressed(f, **arrays)
    return {
        "bytes": p.stat().st_size,
        "records": int(keep.sum()),
        "records_total": v * j,
        "floats_paper": 92 * 7 * v * n,
    }


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


#: The largest model file read (a 50K-vertex model with three Gaussians is about 100 MB).
MAX_FILE_BYTES = 1 << 36

#: Decompressed bytes a model file may hold beyond ``EXPANSION`` times its own size: a model's
#: arrays are floats, which deflate compresses by a few times at most, while a zip bomb's
#: members expand by a thousand times and more.
EXPANSION_SLACK = 64 << 20
EXPANSION = 100


def _check_sizes(archive: zipfile.ZipFile, file_bytes: int, name: str) -> None:
    """Refuse an archive whose members would decompress to more than ``EXPANSION`` times the
    file's size plus ``EXPANSION_SLACK``: the memory a read takes is bounded by that. The
    sizes are those the zip directory declares, which decompression never exceeds."""
    total = sum(info.file_size for info in archive.infolist())
    limit = EXPANSION_SLACK + EXPANSION * file_bytes
    _need(
        total <= limit,
        name,
        f"its members would decompress to {total:,} bytes, over {limit:,} for a file of "
        f"{file_bytes:,} bytes: not a model file",
    )


def read(path) -> dict[str, Any]:
    """Read and check a model file: the :class:`lobelight.model.Model` fields it holds.

    The checks run in stages, each on what the one before has vouched for: the container
    (:func:`_open`), the metadata (:func:`_header`), the arrays (:func:`_check_arrays`), the
    Gaussians and the light they carry (:func:`_gaussians`, :func:`_check_transfer`), and the
    mesh, materials and bounce transfer built from them (:func:`_build`).

    Returns
    -------
    dict with ``mesh``, ``views (J, 3)``, ``gaussians`` (:class:`Gaussians`, ``(V, J, N)``),
    ``diffuse (V, n, 3)``, ``materials``, ``provenance``, ``bounce`` (or None),
    ``indirect_gaussians``, ``visibility`` (or None) and ``hits`` (``(face, distance)`` or
    None), all on the CPU

    Raises
    ------
    InputError
        naming the file: missing, not a model file, unknown version, missing or malformed
        arrays, non-finite values, inconsistent shapes.
    """
    p = Path(path)
    name = str(p)
    a, extra = _open(p, name)
    bounce_arr = extra.get("bounce")
    h = _header(a["meta"], name)
    _check_arrays(a, h, name)
    g = _gaussians(a, h, name)
    _check_transfer(a["diffuse"], bounce_arr, name)
    out = _build(p, a, bounce_arr, h, g, name)
    out["visibility"] = _visibility(extra.get("visibility"), h.v, name)
    out["hits"] = _hits(extra.get("hit_face"), extra.get("hit_distance"), h.v,
                        out["mesh"].n_faces, name)  # fmt: skip
    vis, hits = out["visibility"], out["hits"]
    _need(vis is None or hits is None or tuple(hits[0].shape) == tuple(vis.shape), name,
          "hit tiles and visibility tiles differ in resolution")  # fmt: skip
    return out


def _hits(face: np.ndarray | None, dist: np.ndarray | None, v: int, n_faces: int, name: str):
    """The optional hit tiles, checked: both or neither; ``(V, R, R)`` int32 triangle ids in
    ``[-1, F)`` and float16 distances, finite and non-negative."""
    if face is None and dist is None:
        return None
    _need(face is not None and dist is not None, name,
          "hit_face and hit_distance come together; the file holds only one")  # fmt: skip
    ok = face.dtype == np.int32 and face.ndim == 3 and face.shape[0] == v
    _need(ok and face.shape[1] == face.shape[2] >= 2, name,
          f"hit_face must be ({v}, R, R) int32 tiles, got {face.dtype} {face.shape}")  # fmt: skip
    _need(dist.dtype == np.float16 and dist.shape == face.shape, name,
          f"hit_distance must be {face.shape} float16, got {dist.dtype} {dist.shape}")  # fmt: skip
    _need(face.size == 0 or (int(face.min()) >= -1 and int(face.max()) < n_faces), name,
          f"hit_face holds triangle ids outside -1..{n_faces - 1}")  # fmt: skip
    _need(bool(np.isfinite(dist).all()) and not bool((dist < 0).any()), name,
          "hit_distance holds negative or non-finite distances")  # fmt: skip
    return torch.from_numpy(face.copy()), torch.from_numpy(dist.copy())


def _visibility(arr: np.ndarray | None, v: int, name: str) -> torch.Tensor | None:
    """The optional visibility tiles, checked: ``(V, R, R)`` uint8 with ``R >= 2``."""
    if arr is None:
        return None
    ok = arr.dtype == np.uint8 and arr.ndim == 3 and arr.shape[0] == v
    _need(ok and arr.shape[1] == arr.shape[2] >= 2, name,
          f"visibility must be ({v}, R, R) uint8 tiles, got {arr.dtype} {arr.shape}")  # fmt: skip
    return torch.from_numpy(arr.copy())


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


def _open(p: Path, name: str) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """The container: a regular zip archive of ``.npy`` arrays holding every array of
    ``_ARRAYS``, of a plausible expanded size. Returns the arrays, and those of ``_OPTIONAL``
    it holds."""
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
            a = {k: z[k] for k in _ARRAYS}
            extra = {k: z[k] for k in _OPTIONAL if k in z.files}
    except InputError:
        raise
    except _UNREADABLE as exc:
        raise InputError(name, f"cannot read model file: {type(exc).__name__}: {exc}") from None
    for k, arr in (*a.items(), *extra.items()):
        # a member without the .npy header comes back as raw bytes
        _need(isinstance(arr, np.ndarray), name, f"{k} is not an array")
    return a, extra


def _header(raw: np.ndarray, name: str) -> _Header:
    """The metadata: UTF-8 JSON of this format and version, with counts in range (checked
    before anything is allocated from them)."""
    _need(raw.dtype == np.uint8 and raw.ndim == 1, name, "meta must be UTF-8 bytes")
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
        f"unknown weights encoding {meta.get('weights')!r}",
    )
    _need(
        meta.get("version") == VERSION,
        name,
        f"model format version {meta.get('version')!r}; this lobelight reads version {VERSION}",
    )
    try:
        v, j, n = int(meta["n_vertices"]), int(meta["n_views"]), int(meta["n_gaussians"])
    except (KeyError, TypeError, ValueError, OverflowError):
        raise InputError(name, "metadata lacks the vertex, view or Gaussian counts") from None
    # bounds before anything is allocated from these counts
    _need(1 <= n <= 8, name, f"n_gaussians must be 1..8, got {n}")
    ni = meta.get("indirect_gaussians", 0)
    _need(
        isinstance(ni, int) and not isinstance(ni, bool) and 0 <= ni < n,
        name,
        f"indirect_gaussians must be a whole number in 0..{n - 1}, got {ni!r}",
    )
    # every renderer and Model.transport blend between the 92 geodesic views
    _need(
        j == sphere.N_VIEWS, name, f"n_views must be {sphere.N_VIEWS} (the geodesic views), got {j}"
    )
    _need(3 <= v <= 1 << 26, name, f"n_vertices must be 3..{1 << 26}, got {v}")
    return _Header(meta, prov, v, j, n, ni)


def _check_arrays(a: dict[str, np.ndarray], h: _Header, name: str) -> None:
    """Each array against the header: shapes, dtypes, finite values, then the geometry, the
    views, the SH order and the stored Gaussians' means and widths."""
    _check_shapes(a, h, name)
    for k in ("vertices", "normals", "views", "gaussians", "diffuse"):
        _need(np.issubdtype(a[k].dtype, np.floating), name, f"{k} must be floating point")
        _need(bool(np.isfinite(a[k]).all()), name, f"{k} has NaN or Inf values")
    _check_geometry(a, h.v, name)
    _check_sh_order(a["diffuse"], h.meta, name)
    _check_records(a["gaussians"], name)


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
    _need(a["keep"].dtype == np.bool_, name, "keep must be boolean")
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


def _check_geometry(a: dict[str, np.ndarray], v: int, name: str) -> None:
    """Faces, vertices, normals and views: indices in range, an extent, no zero vectors, and
    the views the geodesic set."""
    f = a["faces"]
    _need(np.issubdtype(f.dtype, np.integer), name, "faces must be integers")
    _need(f.shape[0] > 0, name, "has no faces")
    _need(f.min() >= 0 and f.max() < v, name, "face index out of range")
    _need(float(np.ptp(a["vertices"], axis=0).max()) > 0, name, "all vertices coincide (no extent)")
    for k in ("normals", "views"):
        _need(bool((np.linalg.norm(a[k], axis=-1) > 1e-6).all()), name, f"{k} has zero vectors")
    geodesic = sphere.geodesic_views(dtype=torch.float64).numpy()
    unit = a["views"] / np.linalg.norm(a["views"], axis=-1, keepdims=True)
    # within float32 rounding of the geodesic set, in its order
    _need(
        float((unit * geodesic).sum(-1).min()) > 1 - 1e-6,
        name,
        "views are not the 92 geodesic views in their order",
    )


def _check_sh_order(diffuse: np.ndarray, meta: dict[str, Any], name: str) -> None:
    order = meta.get("sh_order", 5)
    _need(
        isinstance(order, int) and not isinstance(order, bool) and 1 <= order <= 10,
        name,
        f"sh_order must be a whole number in 1..10, got {order!r}",
    )
    _need(
        diffuse.shape[1] == order**2,
        name,
        f"diffuse has {diffuse.shape[1]} SH coefficients, sh_order {meta.get('sh_order')!r}",
    )


def _check_records(g7: np.ndarray, name: str) -> None:
    """The stored Gaussians (K, N, 7): means not zero, widths a float32 sharpness can hold."""
    if g7.size:
        _need(
            bool((np.linalg.norm(g7[..., 3:6].astype(np.float64), axis=-1) > 1e-6).all()),
            name,
            "a Gaussian mean is a zero vector",
        )
        sig = g7[..., 6].astype(np.float64)
        # sigma >= 1e-6: lam = sigma^-2 must be a finite float32
        _need(bool((sig >= 1e-6).all()), name, "sigma must be at least 1e-6")


def _gaussians(a: dict[str, np.ndarray], h: _Header, name: str) -> Gaussians:
    """The Gaussians (V, J, N) of every record, dropped ones with zero weight; checks their
    weights and the light each carries."""
    rec = torch.zeros(h.v, h.j, h.n, 7)
    rec[..., 3:6] = torch.tensor([0.0, 1.0, 0.0])  # dropped records: zero weight
    rec[..., 6] = 1.0
    rec[torch.from_numpy(a["keep"])] = torch.from_numpy(a["gaussians"].astype(np.float32))
    sigma = rec[..., 6]
    _need(bool((sigma > 0).all()), name, "sigma must be positive")
    _need(bool((rec[..., :3] >= 0).all()), name, "Gaussian weights must be non-negative")
    mu = torch.nn.functional.normalize(rec[..., 3:6], dim=-1)
    lam = sigma.pow(-2)
    w = rec[..., :3].contiguous()
    if h.meta.get("weights", "peak") == "integral":
        w = w / sg.integral(lam.double()).to(w.dtype)[..., None]
    carried = float((w.double() * sg.integral(lam.double())[..., None]).max()) if w.numel() else 0
    _need(
        carried <= MAX_LIGHT,
        name,
        f"a Gaussian carries {carried:.3g} of light, over {MAX_LIGHT:g}: not a fitted model",
    )
    return Gaussians(w, mu, lam)


def _check_transfer(diffuse: np.ndarray, bounce: np.ndarray | None, name: str) -> None:
    """No SH transfer coefficient over :data:`MAX_LIGHT`."""
    for k, arr in (("diffuse", diffuse), ("bounce", bounce)):
        if arr is not None and arr.size and float(np.abs(arr).max()) > MAX_LIGHT:
            raise InputError(name, f"{k} transfer over {MAX_LIGHT:g}: not a fitted model")


def _build(p: Path, a, bounce_arr, h: _Header, g: Gaussians, name: str) -> dict[str, Any]:
    """The fields of the model: the mesh, the materials (checked against the vertex count) and
    the bounce transfer (checked against ``diffuse``), with the rest as read."""
    mesh = Mesh(
        vertices=torch.from_numpy(a["vertices"].astype(np.float32)),
        faces=torch.from_numpy(a["faces"].astype(np.int64)),
        normals=torch.from_numpy(a["normals"].astype(np.float32)),
        name=str(h.provenance.get("scene", p.stem)),
    )
    try:
        mats = Materials.from_dict(h.meta["materials"], h.v)
    except (KeyError, TypeError) as exc:
        raise InputError(name, f"bad materials entry: {exc}") from None
    except InputError as exc:
        raise InputError(name, f"bad materials entry: {exc}") from None
    bounce = None
    if bounce_arr is not None:
        _need(
            bounce_arr.shape == a["diffuse"].shape,
            name,
            f"bounce has shape {bounce_arr.shape}, diffuse {a['diffuse'].shape}",
        )
        _need(bool(np.isfinite(bounce_arr).all()), name, "bounce has non-finite values")
        bounce = torch.from_numpy(bounce_arr.astype(np.float32))
    return {
        "mesh": mesh,
        "views": torch.from_numpy(a["views"].astype(np.float32)),
        "gaussians": g,
        "diffuse": torch.from_numpy(a["diffuse"].astype(np.float32)),
        "materials": mats,
        "provenance": dict(h.provenance),
        "bounce": bounce,
        "indirect_gaussians": h.ni,
    }
