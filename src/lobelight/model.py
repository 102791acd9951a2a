"""The model file: a fitted object in one file, checked on load, never unpickled.

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
                    glossy transport (:attr:`Model.indirect_gaussians`)
``diffuse``         (V, n, 3) SH diffuse transfer
``bounce``          optional (V, n, 3): the interreflected part of ``diffuse``, lit by the sun
                    as well (the self-shadowed part sees the sun per pixel)

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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from . import __version__
from ._io import atomic_writer
from ._moved import renamed
from .errors import InputError
from .geometry import sphere
from .lobes import sg
from .lobes.sg import Gaussians
from .scene import Materials, Mesh

__all__ = [
    "FORMAT",
    "LIVE_FLOOR",
    "MAX_LIGHT",
    "VERSION",
    "Model",
    "blend_lobes",
    "horizon_scale",
    "load",
    "save",
]

FORMAT = "lobelight-model"
VERSION = 1
_ARRAYS = ("meta", "vertices", "faces", "normals", "views", "keep", "gaussians", "diffuse")


#: The most light a Gaussian, or a transfer coefficient, of a fitted model carries: they are
#: reflectances (at most about 1 for a physical material), and values near float32's range
#: rendered Inf pixels.
MAX_LIGHT = 1e4
#: Carried light below which a record is dead: it has no say in a blended lobe's shape.
LIVE_FLOOR = 1e-30
#: A blended lobe whose live records have less barycentric weight than this carries no light.
_MIN_SAY = 1e-6


def blend_lobes(e, mu, sigma, b, *, frame=None):
    """Blend corresponding Gaussians of three records (views of a vertex, or vertices of a
    triangle) with barycentric weights ``b``.

    The light a lobe carries, ``e = w * integral(lam)`` (RGB), blends linearly; its width and
    mean blend linearly (the mean then renormalised) over the *live* records, those carrying
    light (mean of ``e`` over colour at least ``LIVE_FLOOR``), with their barycentric weights
    renormalised.

    Why not blend peak weights and widths independently, the paper's literal wording: where a
    slot is a sharp lobe in one record and a broad or dead one in the next, the sharp lobe's
    peak weight (~1e4) is spread over the blended width and the light grows by the ratio of
    the integrals. On the knot with two Gaussians per view that made images ~7x too bright
    (and one Gaussian's 1 % worst blends carried 17x their light). Blending the carried light
    conserves it exactly. Why not weight the shape by the light too: that pins a highlight to
    the brighter record's mean instead of letting it travel across the triangle as the means
    do, the point of the paper's nonlinear interpolation; measured on ``knot:2`` (N = 1) it
    costs 2.4 dB against this rule. Dead records are left out because their means and widths
    are never fitted to anything (the M and V fill may be poor). The shader does the same, per
    vertex explicitly and per pixel with varyings premultiplied by the live flag.

    ``frame = (base, target)`` blends the means as offsets from per-record directions ``base``
    and adds them to ``target`` before normalising. The renderer passes each triangle corner's
    mirror direction (its view reflected about its normal) and the point's own, computed from
    its interpolated normal and view: a mirror-like lobe then follows the reflection per pixel
    as Phong shading does, instead of a blend of corner directions that differ by up to 60
    degrees across the default knot's triangles (+1.2 dB glossy on the knot, relative L2 error
    0.93 -> 0.34). At a corner (``b`` a unit vector) the corner's own mean comes back exactly.

    Parameters
    ----------
    e : (..., 3, N, C) light carried (>= 0);  mu : (..., 3, N, 3) unit;  sigma : (..., 3, N)
    b : (..., 3) barycentric weights;  frame : optional (base (..., 3, 3), target (..., 3))

    Returns
    -------
    e : (..., N, C), zero where the live records' weight is below ``_MIN_SAY`` (then at most
    ``_MIN_SAY`` of the largest record's light is dropped);  mu : (..., N, 3) unit (``+z`` for a
    lobe without light);  sigma : (..., N) (1 for a lobe without light)
    """
    bn = b[..., None]  # (..., 3, 1)
    live = e.mean(-1) >= LIVE_FLOOR  # (..., 3, N)
    a = torch.where(live, bn, torch.zeros_like(bn))
    s = a.sum(-2)  # (..., N)
    ok = s >= _MIN_SAY
    u = a / torch.where(ok, s, torch.ones_like(s))[..., None, :]
    e_out = torch.where(
        ok[..., None], (e * bn[..., None]).sum(-3), torch.zeros_like(e[..., 0, :, :])
    )
    sigma = torch.where(ok, (u * sigma).sum(-2), torch.ones_like(s))
    z = torch.zeros_like(mu[..., 0, :, :])
    z[..., 2] = 1.0
    if frame is None:
        m = (u[..., None] * mu).sum(-3)
    else:  # means as offsets from each record's mirror direction, re-based at the point's
        base, target = frame
        m = target[..., None, :] + (u[..., None] * (mu - base[..., None, :])).sum(-3)
    mu = torch.where(ok[..., None], torch.nn.functional.normalize(m, dim=-1), z)
    return e_out, mu, sigma


def horizon_scale(views, normals, rows, idx, bary, view_dirs) -> torch.Tensor:
    """The factor that makes a view blend ignore records below the vertex's horizon.

    A stored view with ``n.v <= 0`` has no data (the fit gives it zero weight), not zero
    light: a view direction just above the horizon blends such a record with the last views
    above it, and counting the record as dark loses the light in proportion to its
    barycentric weight (a third of it on average at ``n.v < 0.1`` on a sphere). So for
    a view direction above the horizon the carried light is averaged over the records above
    it: each record's light is scaled by ``1 / sum(b over records above)``. Below the horizon
    (seen only through interpolated normals at a silhouette) the records blend as they are,
    fading to the dark records. The shader does the same with the flag stored next to each
    record's mean.

    Parameters
    ----------
    views : (J, 3);  normals : (V, 3);  rows, idx : (..., 3) vertex and view ids of the records
    bary : (..., 3) their barycentric weights;  view_dirs : (..., 3) the blended view

    Returns
    -------
    (...) scale of the blended light (1 below the horizon)
    """
    n = normals[rows[..., 0]]  # (..., 3)
    above = (views[idx] * n[..., None, :]).sum(-1) > 0  # (..., 3)
    say = (bary * above).sum(-1)
    ok = ((view_dirs * n).sum(-1) > 0) & (say >= _MIN_SAY)
    return torch.where(ok, 1.0 / torch.where(ok, say, torch.ones_like(say)), torch.ones_like(say))


@dataclass(eq=False)
class Model:
    """A fitted object: mesh, views, Gaussians per vertex and view, SH diffuse, materials.

    Attributes
    ----------
    mesh : Mesh (V vertices);  views : (J, 3) view directions (the 92 geodesic views)
    gaussians : w (V, J, N, 3), mu (V, J, N, 3), lam (V, J, N)
    diffuse : (V, n, 3) SH diffuse transfer (order-5: n = 25)
    materials : per-vertex materials;  provenance : scene, settings, timings, versions
    bounce : optional (V, n, 3) the interreflected part of ``diffuse``: a renderer that shades
        the map's sun per pixel lights it with the sun's SH too (the sun's light bounced off
        the object; left out, the knot under the built-in sky rendered 5 % dark)
    indirect_gaussians : how many of the last Gaussians per view hold indirect glossy transport
        (light reflected off the object itself before it reaches the vertex's glossy lobe).
        A renderer that shades the sun's glossy light per pixel, with the other lobes seeing
        the map without it, lets the sun light these (render/_sun_glossy.py):
        a mirror shows the sun's reflection in another mirror
    """

    mesh: Mesh
    views: torch.Tensor
    gaussians: Gaussians
    diffuse: torch.Tensor
    materials: Materials
    provenance: dict[str, Any] = field(default_factory=dict)
    bounce: torch.Tensor | None = None
    indirect_gaussians: int = 0

    def __post_init__(self):
        n = int(self.gaussians.lam.shape[-1])
        if not 0 <= self.indirect_gaussians < n:
            raise InputError(
                "indirect_gaussians", f"must be in 0..{n - 1}, got {self.indirect_gaussians}"
            )

    @property
    def n_gaussians(self) -> int:
        """Gaussians per view, direct and indirect."""
        return int(self.gaussians.lam.shape[-1])

    @property
    def direct_gaussians(self) -> int:
        """Gaussians per view fitted to the direct glossy transport."""
        return self.n_gaussians - self.indirect_gaussians

    @property
    def n_lobes(self) -> int:
        # the earlier name of n_gaussians, kept working
        renamed("Model.n_lobes", "Model.n_gaussians")
        return self.n_gaussians

    @property
    def direct_lobes(self) -> int:
        renamed("Model.direct_lobes", "Model.direct_gaussians")
        return self.direct_gaussians

    @property
    def indirect_lobes(self) -> int:
        renamed("Model.indirect_lobes", "Model.indirect_gaussians")
        return self.indirect_gaussians

    @property
    def device(self) -> torch.device:
        return self.gaussians.w.device

    def transport(self, vertex_ids, view_dirs) -> Gaussians:
        """The Gaussians of vertices at arbitrary views, interpolated between stored views.

        The paper's scheme (section 5): the geodesic triangle holding the view
        (:func:`lobelight.geometry.sphere.locate_views`) gives three stored records and barycentric
        weights, and corresponding lobes blend with each other, by :func:`blend_lobes`: the
        light each lobe carries linearly, width and mean over the records that carry light.

        Parameters
        ----------
        vertex_ids : (...) int vertex indices;  view_dirs : (..., 3) world-frame directions
            towards the viewer (need not be unit)

        Returns
        -------
        Gaussians with w (..., N, 3), mu (..., N, 3), lam (..., N)
        """
        if self.views.shape[0] != 92:
            raise InputError("model", "view interpolation needs the 92 geodesic views")
        dev = self.device
        vid = torch.as_tensor(vertex_ids, device=dev).long()
        vd = torch.as_tensor(view_dirs, device=dev, dtype=torch.float32)
        if vd.shape[-1] != 3 or vd.shape[:-1] != vid.shape:
            want = (*vid.shape, 3)
            raise InputError("view_dirs", f"expected shape {want}, got {tuple(vd.shape)}")
        if vid.numel() and (int(vid.min()) < 0 or int(vid.max()) >= self.mesh.n_vertices):
            raise InputError("vertex_ids", f"out of range 0..{self.mesh.n_vertices - 1}")
        idx, bary = sphere.locate_views(vd)  # (..., 3), (..., 3)
        g = self.gaussians
        rows = vid[..., None].expand_as(idx)
        lam = g.lam[rows, idx]  # (..., 3, N)
        e = g.w[rows, idx] * sg.integral(lam)[..., None]  # (..., 3, N, 3)
        scale = horizon_scale(self.views, self.mesh.normals, rows, idx, bary, vd)
        e = e * scale[..., None, None, None]
        e, mu, sigma = blend_lobes(e, g.mu[rows, idx], lam.rsqrt(), bary)
        lam = sigma.pow(-2)
        return Gaussians(e / sg.integral(lam)[..., None], mu, lam)

    def evaluate(self, vertex_ids, view_dirs, dirs) -> torch.Tensor:
        """The interpolated glossy transport function ``sum_k w_k G(d; mu_k, lam_k)``.

        Parameters
        ----------
        vertex_ids : (...);  view_dirs : (..., 3);  dirs : (..., D, 3) unit light directions

        Returns
        -------
        (..., D, 3)
        """
        g = self.transport(vertex_ids, view_dirs)
        d = torch.as_tensor(dirs, device=self.device, dtype=torch.float32)
        cos = d @ g.mu.transpose(-1, -2)  # (..., D, N)
        gk = torch.exp(g.lam[..., None, :] * (cos - 1))  # (..., D, N)
        return gk @ g.w  # (..., D, 3)

    def to(self, device) -> Model:
        """The model with every tensor on ``device`` (in place; returns it)."""
        g = self.gaussians
        self.mesh = self.mesh.to(device)
        self.views = self.views.to(device)
        self.gaussians = Gaussians(g.w.to(device), g.mu.to(device), g.lam.to(device))
        self.diffuse = self.diffuse.to(device)
        self.materials = self.materials.to(device)
        if self.bounce is not None:
            self.bounce = self.bounce.to(device)
        return self

    def save(self, path, *, float16: bool = False, drop: bool = True) -> dict[str, Any]:
        """Write the model to ``path`` (see :func:`save`); returns sizes."""
        return _write(
            path,
            self.mesh,
            self.materials,
            self.gaussians,
            self.views,
            self.diffuse,
            float16=float16,
            drop=drop,
            provenance=self.provenance,
            bounce=self.bounce,
            indirect_gaussians=self.indirect_gaussians,
        )


def _kept(w: torch.Tensor, views: torch.Tensor) -> torch.Tensor:
    """(V, J) records that rendering can see: weight at the view or at a neighbouring view."""
    live = w.amax((-1, -2)) > 0  # (V, J)
    j = views.shape[0]
    if j != 92:  # not the geodesic set: keep everything
        return torch.ones_like(live)
    nbr = sphere.geodesic_neighbor_table(device=w.device)
    near = live[:, nbr.clamp_min(0)] & (nbr >= 0)  # (V, J, 6)
    return live | near.any(-1)


def save(
    path,
    mesh: Mesh,
    materials: Materials,
    fit: Any,
    *,
    float16: bool = False,
    drop: bool = True,
    provenance: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Write a model file atomically; returns sizes (bytes, records kept).

    Parameters
    ----------
    fit : the fitted transport, with ``gaussians``, ``views``, ``diffuse`` and ``bounce`` (None
        for none) as a :class:`lobelight.fit.MeshFit` has them
    float16 : store the Gaussians (and SH) as half floats
    drop : leave out records no rendering can see (module docstring)
    """
    return _write(
        path,
        mesh,
        materials,
        fit.gaussians,
        fit.views,
        fit.diffuse,
        float16=float16,
        drop=drop,
        provenance=provenance,
        bounce=fit.bounce,
        indirect_gaussians=getattr(fit, "indirect_gaussians", 0),
    )


def _write(
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
) -> dict[str, Any]:
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
    rec = torch.cat([w, g.mu, g.lam.clamp_min(1e-12).rsqrt()[..., None]], -1)  # (V, J, N, 7)
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


def load(path, *, device=None) -> Model:
    """Read and check a model file.

    Raises
    ------
    InputError
        naming the file: missing, not a model file, unknown version, missing or malformed
        arrays, non-finite values, inconsistent shapes.
    """
    p = Path(path)
    name = str(p)
    if not p.is_file():
        raise InputError(name, "no such file")
    _need(_is_zip(p), name, _not_a_model(p))
    try:
        z = np.load(p, allow_pickle=False)
        # a bare .npy file loads as an array: not an archive of arrays
        _need(isinstance(z, np.lib.npyio.NpzFile), name, "not a lobelight model file (not npz)")
        with z:
            missing = [k for k in _ARRAYS if k not in z.files]
            _need(not missing, name, f"not a lobelight model file (missing {missing})")
            a = {k: z[k] for k in _ARRAYS}
            bounce_arr = z["bounce"] if "bounce" in z.files else None
    except InputError:
        raise
    except (
        zipfile.BadZipFile,
        zlib.error,
        ValueError,
        OSError,
        EOFError,
        KeyError,
        NotImplementedError,  # an unknown zip compression method
        RuntimeError,  # an encrypted zip member
        MemoryError,
    ) as exc:
        raise InputError(name, f"cannot read model file: {type(exc).__name__}: {exc}") from None
    for k, arr in a.items():
        # a member without the .npy header comes back as raw bytes
        _need(isinstance(arr, np.ndarray), name, f"{k} is not an array")
    _need(a["meta"].dtype == np.uint8 and a["meta"].ndim == 1, name, "meta must be UTF-8 bytes")
    try:
        meta = json.loads(bytes(a["meta"]).decode())
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
    _need(1 <= j <= 4096, name, f"n_views must be 1..4096, got {j}")
    _need(3 <= v <= 1 << 26, name, f"n_vertices must be 3..{1 << 26}, got {v}")
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
    for k in ("vertices", "normals", "views", "gaussians", "diffuse"):
        _need(np.issubdtype(a[k].dtype, np.floating), name, f"{k} must be floating point")
        _need(bool(np.isfinite(a[k]).all()), name, f"{k} has NaN or Inf values")
    f = a["faces"]
    _need(np.issubdtype(f.dtype, np.integer), name, "faces must be integers")
    _need(f.shape[0] > 0, name, "has no faces")
    _need(f.min() >= 0 and f.max() < v, name, "face index out of range")
    _need(float(np.ptp(a["vertices"], axis=0).max()) > 0, name, "all vertices coincide (no extent)")
    for k in ("normals", "views"):
        _need(bool((np.linalg.norm(a[k], axis=-1) > 1e-6).all()), name, f"{k} has zero vectors")
    _need(
        a["diffuse"].shape[1] == int(meta.get("sh_order", 5)) ** 2
        if isinstance(meta.get("sh_order", 5), int)
        else False,
        name,
        f"diffuse has {a['diffuse'].shape[1]} SH coefficients, sh_order {meta.get('sh_order')!r}",
    )
    g7 = a["gaussians"]
    if g7.size:
        _need(
            bool((np.linalg.norm(g7[..., 3:6].astype(np.float64), axis=-1) > 1e-6).all()),
            name,
            "a Gaussian mean is a zero vector",
        )
        sig = g7[..., 6].astype(np.float64)
        # sigma >= 1e-6: lam = sigma^-2 must be a finite float32
        _need(bool((sig >= 1e-6).all()), name, "sigma must be at least 1e-6")
    rec = torch.zeros(v, j, n, 7)
    rec[..., 3:6] = torch.tensor([0.0, 1.0, 0.0])  # dropped records: zero weight
    rec[..., 6] = 1.0
    rec[torch.from_numpy(a["keep"])] = torch.from_numpy(a["gaussians"].astype(np.float32))
    sigma = rec[..., 6]
    _need(bool((sigma > 0).all()), name, "sigma must be positive")
    _need(bool((rec[..., :3] >= 0).all()), name, "Gaussian weights must be non-negative")
    mu = torch.nn.functional.normalize(rec[..., 3:6], dim=-1)
    lam = sigma.pow(-2)
    w = rec[..., :3].contiguous()
    if meta.get("weights", "peak") == "integral":
        w = w / sg.integral(lam.double()).to(w.dtype)[..., None]
    g = Gaussians(w, mu, lam)
    carried = float((w.double() * sg.integral(lam.double())[..., None]).max()) if w.numel() else 0
    _need(
        carried <= MAX_LIGHT,
        name,
        f"a Gaussian carries {carried:.3g} of light, over {MAX_LIGHT:g}: not a fitted model",
    )
    for k, arr in (("diffuse", a["diffuse"]), ("bounce", bounce_arr)):
        if arr is not None and arr.size and float(np.abs(arr).max()) > MAX_LIGHT:
            raise InputError(name, f"{k} transfer over {MAX_LIGHT:g}: not a fitted model")
    mesh = Mesh(
        vertices=torch.from_numpy(a["vertices"].astype(np.float32)),
        faces=torch.from_numpy(f.astype(np.int64)),
        normals=torch.from_numpy(a["normals"].astype(np.float32)),
        name=str(prov.get("scene", p.stem)),
    )
    try:
        mats = Materials.from_dict(meta["materials"], v)
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
    model = Model(
        mesh,
        torch.from_numpy(a["views"].astype(np.float32)),
        g,
        torch.from_numpy(a["diffuse"].astype(np.float32)),
        mats,
        dict(prov),
        bounce=bounce,
        indirect_gaussians=ni,
    )
    return model.to(device) if device is not None else model
