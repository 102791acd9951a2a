"""Ray casting against a mesh: occlusion and first hits, through Embree or NVIDIA Warp.

One class, :class:`RayCaster`, over one of two engines:

- ``"embree"``: trimesh's Embree intersector (embreex), a CPU library: rays are moved to the
  CPU in batches of ``batch`` rays (bounded memory), split over a thread pool, and the results
  moved back to the rays' device;
- ``"warp"``: NVIDIA Warp's BVH (:mod:`lobelight.geometry._warp_rays`, the optional ``gpu``
  extra), built on the mesh's device, CPU or CUDA; on a GPU the rays stay on it, in batches
  too; on the CPU a batch is split over the same thread pool.

``"auto"`` is Warp when the mesh is on a CUDA device and Warp imports, else Embree (on a CPU,
Embree traces faster). A caster made with ``engine=None`` takes the process default
(:func:`set_default_engine`, :func:`default_engine`; "auto" unless changed).

Either way the engine only names the triangle a ray hits: distance and barycentrics are
recomputed from it in float64 on the rays' device, so both engines report the same numbers
whenever they report the same triangle. Both intersect in float32, so a ray passing within
rounding of an edge may be given either triangle (or, at an outline, slip past to what is
behind). Zero-area triangles are left out of both BVHs: they have nothing to hit.

Self-intersection: every ray starts ``offset`` (default ``1e-4`` of the mesh's bounding-box
diagonal) away from its surface point along the *geometric* side the ray leaves from, i.e.
``origin = x + offset * sign(n . d) * n``. Rays that graze a surface could still hit the
triangles around ``x``; callers only cast rays with ``n . d > 0`` (the cosine factor is zero for
the others).
"""

from __future__ import annotations

import contextlib
import functools
import importlib
import itertools
import os
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Protocol

import numpy as np
import torch

from .._tol import DIVISOR_F64
from ..errors import InputError

__all__ = [
    "ENGINES",
    "RayCaster",
    "TriangleMesh",
    "default_engine",
    "get_default_engine",
    "resolve_engine",
    "set_default_engine",
    "warp_available",
]


class TriangleMesh(Protocol):
    """What ray casting reads of a mesh (:class:`lobelight.scene.Mesh` is one)."""

    vertices: torch.Tensor  # (V, 3) float
    faces: torch.Tensor  # (F, 3) long
    scale: float  # the bounding box's diagonal


#: The names ``engine`` takes.
ENGINES = ("auto", "embree", "warp")
#: Rays per call into an engine: 2^20 rays hold ~50 MB of float64 arrays in trimesh, and about
#: as much in the float64 hit geometry.
RAY_BATCH = 1 << 20
#: Fewest rays a thread is given: below this, threads cost more than they save.
MIN_RAYS_PER_THREAD = 1 << 14

_default = "auto"


def _warp_engine():
    """:mod:`._warp_rays`, imported on first use: it imports NVIDIA Warp, whose import time a
    run on Embree alone need not pay."""
    from . import _warp_rays  # optional dependency (NVIDIA Warp): imported when first asked for

    return _warp_rays


def warp_available() -> bool:
    """Whether NVIDIA Warp (``pip install warp-lang``) imports, i.e. ``engine="warp"`` works."""
    return _warp_engine().available()


def _check_engine(name: str) -> str:
    """``name`` if it is an engine this process can run, else :class:`InputError`."""
    if name not in ENGINES:
        raise InputError(
            "engine", f"unknown ray-casting engine {name!r}: use one of {', '.join(ENGINES)}"
        )
    if name == "warp" and not warp_available():
        raise InputError(
            "engine", "'warp' needs NVIDIA Warp, which is not installed: pip install warp-lang"
        )
    return name


def set_default_engine(name: str | None) -> None:
    """Make ``name`` (one of :data:`ENGINES`; None: "auto") the engine of casters made with
    ``engine=None``, for the whole process. :class:`InputError` for an unknown name, or "warp"
    without Warp installed."""
    global _default
    _default = _check_engine("auto" if name is None else name)


def get_default_engine() -> str:
    """The engine casters made with ``engine=None`` take (one of :data:`ENGINES`)."""
    return _default


@contextlib.contextmanager
def default_engine(name: str | None) -> Iterator[str]:
    """:func:`set_default_engine` for a ``with`` block; the previous default comes back after."""
    global _default
    previous = _default
    set_default_engine(name)
    try:
        yield _default
    finally:
        _default = previous  # as it was, checked or not


def resolve_engine(name: str | None, device: torch.device | str) -> str:
    """The engine a caster for a mesh on ``device`` runs: ``"embree"`` or ``"warp"``.

    ``name``: one of :data:`ENGINES`, None for the process default; "auto" is Warp on a CUDA
    device when Warp is installed, else Embree."""
    name = _check_engine(_default if name is None else name)
    kind = torch.device(device).type
    if name == "auto":
        return "warp" if kind == "cuda" and warp_available() else "embree"
    if name == "warp" and kind not in ("cpu", "cuda"):
        raise InputError("engine", f"'warp' builds its BVH on the CPU or a CUDA device, not {kind}")
    return name


@functools.cache
def _trimesh() -> tuple[Any, Any]:
    """trimesh and its Embree intersector class, imported when the first Embree caster is made
    rather than with this module: importing trimesh loads scipy and networkx, a large part of
    the start of a process that casts no ray (a render of a model that holds its tiles)."""
    trimesh = importlib.import_module("trimesh")
    return trimesh, importlib.import_module("trimesh.ray.ray_pyembree").RayMeshIntersector


class _EmbreeRays:
    """trimesh's Embree intersector for one mesh; rays and results on the CPU."""

    device = torch.device("cpu")

    def __init__(self, vertices: torch.Tensor, faces: torch.Tensor):
        trimesh, RayMeshIntersector = _trimesh()
        tm = trimesh.Trimesh(
            vertices=vertices.detach().cpu().numpy().astype(np.float64),
            faces=faces.cpu().numpy(),
            process=False,
        )
        self._rt = RayMeshIntersector(tm, scale_to_box=False)
        # trimesh makes Embree's scene, and Embree its BVH, on the first query: one ray now, so
        # that the build is the caster's and no two threads of a first query race to build it
        self._rt.intersects_first(np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]))

    def occluded(self, o: torch.Tensor, d: torch.Tensor, parts) -> torch.Tensor:
        """(R,) bool on the CPU for (R, 3) rays, split by ``parts`` (:data:`._warp_rays.Parts`)."""
        return self._run(self._rt.intersects_any, o, d, torch.bool, parts)

    def first_face(self, o: torch.Tensor, d: torch.Tensor, parts) -> torch.Tensor:
        """(R,) int64 triangle index (-1 on a miss) on the CPU for (R, 3) rays."""
        return self._run(self._rt.intersects_first, o, d, torch.int64, parts)

    @staticmethod
    def _run(fn, o, d, dtype, parts) -> torch.Tensor:
        # float64 numpy, as trimesh hands them to Embree
        on = o.detach().cpu().numpy().astype(np.float64)
        dn = d.detach().cpu().numpy().astype(np.float64)
        out = torch.empty(on.shape[0], dtype=dtype)

        def run(a: int, b: int) -> None:
            if b > a:
                out[a:b] = torch.from_numpy(fn(on[a:b], dn[a:b]))

        parts(run, on.shape[0])
        return out


class RayCaster:
    """Occlusion and first-hit queries for one mesh.

    Parameters
    ----------
    mesh : a :class:`TriangleMesh`
    offset : ray-origin offset along the normal, as a fraction of the mesh's diagonal
    engine : "embree", "warp", "auto" (see :func:`resolve_engine`) or None (the process
        default, :func:`get_default_engine`); the one chosen is :attr:`engine`
    batch : rays per call into the engine (bounds the memory of a query)
    threads : CPU threads a batch is split over (default: the cores torch may use)

    Raises
    ------
    InputError
        for an unknown engine, or "warp" when Warp is not installed.
    """

    def __init__(
        self,
        mesh: TriangleMesh,
        *,
        offset: float = 1e-4,
        engine: str | None = None,
        batch: int = RAY_BATCH,
        threads: int | None = None,
    ):
        self.mesh = mesh
        self.offset = float(offset) * mesh.scale
        self.batch = int(batch)
        #: the engine this caster runs: "embree" or "warp"
        self.engine = resolve_engine(engine, mesh.vertices.device)
        # embreex and Warp's CPU kernels release the GIL while they trace, so plain threads
        # trace in parallel; by default one per core torch may use
        self.threads = max(1, int(threads or min(os.cpu_count() or 1, torch.get_num_threads())))
        self._pool: ThreadPoolExecutor | None = None
        # (F, 3, 3) float64 first corner and two edges for the hit geometry, per device the
        # rays come on
        self._tri: dict[torch.device, torch.Tensor] = {}
        tri = self._triangles(mesh.vertices.device)
        # zero-area triangles have no surface to hit, nor barycentrics or a normal: left out
        # of the BVH (a float32 engine can still report one by rounding)
        keep = torch.linalg.cross(tri[:, 1], tri[:, 2]).norm(dim=-1) > 0
        faces = mesh.faces if bool(keep.all()) else mesh.faces[keep]
        if self.engine == "warp":
            self._rays = _warp_engine().WarpRays(mesh.vertices, faces)
        else:
            self._rays = _EmbreeRays(mesh.vertices, faces)
        #: index in the mesh of each triangle the engine has, (F',) int64 on its device; None
        #: when it has them all
        self._face_ids = None if faces is mesh.faces else keep.nonzero()[:, 0].to(self._rays.device)

    def spawn(
        self,
        points: torch.Tensor,
        normals: torch.Tensor,
        dirs: torch.Tensor,
        *,
        offset: float | None = None,
    ) -> torch.Tensor:
        """Ray origins offset off the surface on the side ``dirs`` leave toward, ``(..., 3)``.

        ``offset`` overrides the caster's, as a fraction of the mesh's diagonal (a caster made
        for primary rays has none, but its shadow rays need one)."""
        off = self.offset if offset is None else float(offset) * self.mesh.scale
        side = torch.sign((normals * dirs).sum(-1, keepdim=True))
        side = torch.where(side == 0, torch.ones_like(side), side)
        return points + (off * side) * normals

    def occluded(self, origins: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
        """Whether each ray hits the mesh at all, ``(...)`` bool on the inputs' device.

        Parameters
        ----------
        origins, dirs : (..., 3) (broadcast); origins already offset (see :meth:`spawn`)
        """
        shape, o, d = self._flat(origins, dirs)
        out = torch.empty(o.shape[0], dtype=torch.bool, device=o.device)
        for i in range(0, o.shape[0], self.batch):
            j = i + self.batch
            out[i:j] = self._rays.occluded(o[i:j], d[i:j], self._parts)
        return out.reshape(shape)

    def first_hit(
        self, origins: torch.Tensor, dirs: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Nearest hit of each ray.

        Parameters
        ----------
        origins, dirs : (..., 3) (broadcast), dirs unit

        Returns
        -------
        tri : (...) int64 triangle index, -1 on a miss
        t : (...) float distance along the ray (inf on a miss)
        bary : (..., 3) barycentric weights of the triangle's three vertices at the hit

        All on the inputs' device, ``t`` and ``bary`` in the origins' dtype.
        """
        shape, o, d = self._flat(origins, dirs)
        dev, dt = origins.device, origins.dtype
        tri = torch.empty(o.shape[0], dtype=torch.int64, device=dev)
        t = torch.empty(o.shape[0], dtype=dt, device=dev)
        bary = torch.empty(o.shape[0], 3, dtype=dt, device=dev)
        for i in range(0, o.shape[0], self.batch):
            j = i + self.batch
            tri[i:j] = self._mesh_faces(self._rays.first_face(o[i:j], d[i:j], self._parts))
            t[i:j], bary[i:j] = self._hit_geometry(o[i:j], d[i:j], tri[i:j])
        return tri.reshape(shape), t.reshape(shape), bary.reshape(*shape, 3)

    @staticmethod
    def _flat(origins: torch.Tensor, dirs: torch.Tensor):
        """Broadcast batch shape and the rays flattened to (R, 3) each."""
        shape = torch.broadcast_shapes(origins.shape, dirs.shape)[:-1]
        o = origins.expand(*shape, 3).reshape(-1, 3)
        return shape, o, dirs.expand(*shape, 3).reshape(-1, 3)

    def _parts(self, fn: Callable[[int, int], None], n: int) -> None:
        """``fn(a, b)`` on consecutive pieces of ``range(n)``, one per thread when there are
        at least :data:`MIN_RAYS_PER_THREAD` rays a thread; returns when all are done."""
        parts = min(self.threads, max(1, n // MIN_RAYS_PER_THREAD))
        if parts == 1:
            fn(0, n)
            return
        if self._pool is None:
            self._pool = ThreadPoolExecutor(self.threads, thread_name_prefix="lobelight-rays")
        cuts = np.linspace(0, n, parts + 1).astype(np.int64).tolist()
        for f in [self._pool.submit(fn, a, b) for a, b in itertools.pairwise(cuts)]:
            f.result()  # raises what the piece raised

    def _mesh_faces(self, tri: torch.Tensor) -> torch.Tensor:
        """The engine's triangle indices ``(R,)`` as the mesh's (-1 stays -1)."""
        if self._face_ids is None:
            return tri
        return torch.where(tri >= 0, self._face_ids[tri.clamp(min=0)], tri)

    def _triangles(self, device: torch.device) -> torch.Tensor:
        """(F, 3, 3) first corner and the two edges from it, ``v0, v1 - v0, v2 - v0``, of every
        triangle, float64 (float32 on MPS, which has no float64) on ``device``, made once per
        device."""
        if device not in self._tri:
            real = torch.float32 if device.type == "mps" else torch.float64
            v = self.mesh.vertices.detach().to(device, real)[self.mesh.faces.to(device)]
            self._tri[device] = torch.stack([v[:, 0], v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]], 1)
        return self._tri[device]

    def _hit_geometry(
        self, o: torch.Tensor, d: torch.Tensor, tri: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Distance ``(R,)`` (inf on a miss) and barycentrics ``(R, 3)`` (0 on a miss) of rays
        ``(R, 3)`` on the triangles ``tri`` ``(R,)`` the engine reported, by Moller-Trumbore in
        float64 on the rays' device."""
        tables = self._triangles(o.device)
        o, d = o.detach().to(tables.dtype), d.detach().to(tables.dtype)
        hit = tri >= 0
        t = torch.full(tri.shape, float("inf"), dtype=o.dtype, device=o.device)
        bary = torch.zeros(*tri.shape, 3, dtype=o.dtype, device=o.device)
        if o.device.type == "cpu":  # the hits only: picking them costs no device sync here
            idx = hit.nonzero()[:, 0]
            t[idx], bary[idx] = _moller_trumbore(tables[tri[idx]], o[idx], d[idx])
        else:  # every ray, misses on triangle 0 then masked out: no host sync on a GPU
            th, bh = _moller_trumbore(tables[tri.clamp(min=0)], o, d)
            t, bary = torch.where(hit, th, t), torch.where(hit[:, None], bh, bary)
        return t, bary


def _moller_trumbore(tri: torch.Tensor, o: torch.Tensor, d: torch.Tensor):
    """Distance ``(R,)`` and barycentrics ``(R, 3)`` of rays ``o, d`` ``(R, 3)`` that hit
    triangles ``tri`` ``(R, 3, 3)`` (first corner, two edges from it)."""
    v0, e1, e2 = tri.unbind(1)
    p = torch.linalg.cross(d, e2)
    det = (e1 * p).sum(-1)
    # a ray the engine says hits a triangle is not parallel to it, but float32 and float64
    # can disagree on a grazing one: a tiny determinant, not a division by zero
    inv = 1 / torch.where(det.abs() < DIVISOR_F64, torch.full_like(det, DIVISOR_F64), det)
    s = o - v0
    b1 = (s * p).sum(-1) * inv
    b2 = (d * torch.linalg.cross(s, e1)).sum(-1) * inv
    # the engine's float32 test and this float64 one can put a ray passing within rounding of
    # an edge on opposite sides of it, and a sliver's barycentrics are ill-conditioned: the
    # weights are clamped onto the triangle, and t is where the ray passes nearest that point
    # (for a hit inside, Moller-Trumbore's own t, to rounding)
    bary = torch.stack([1 - b1 - b2, b1, b2], -1).clamp(min=0)
    bary = bary / bary.sum(-1, keepdim=True)
    x = v0 + bary[:, 1:2] * e1 + bary[:, 2:3] * e2
    t = (((x - o) * d).sum(-1) / (d * d).sum(-1)).clamp(min=0)
    return t, bary
