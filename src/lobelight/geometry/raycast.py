"""Ray casting against a mesh through Embree (trimesh + embreex): occlusion and first hits.

One class, :class:`RayCaster`, over trimesh's Embree intersector. Inputs and outputs are torch
tensors on any device; the BVH itself lives on the CPU (Embree is a CPU library), so rays are
moved there in batches of ``batch`` rays (bounded memory) and results moved back.

Self-intersection: every ray starts ``offset`` (default ``1e-4`` of the mesh's bounding-box
diagonal) away from its surface point along the *geometric* side the ray leaves from, i.e.
``origin = x + offset * sign(n . d) * n``. Rays that graze a surface could still hit the
triangles around ``x``; callers only cast rays with ``n . d > 0`` (the cosine factor is zero for
the others).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import Protocol

import numpy as np
import torch
import trimesh
from trimesh.ray.ray_pyembree import RayMeshIntersector

__all__ = ["RayCaster", "TriangleMesh"]


class TriangleMesh(Protocol):
    """What ray casting reads of a mesh (:class:`lobelight.scene.Mesh` is one)."""

    vertices: torch.Tensor  # (V, 3) float
    faces: torch.Tensor  # (F, 3) long
    scale: float  # the bounding box's diagonal


#: Rays per call into Embree: 2^20 rays hold ~50 MB of float64 arrays in trimesh.
RAY_BATCH = 1 << 20
#: Fewest rays a thread is given: below this, threads cost more than they save.
MIN_RAYS_PER_THREAD = 1 << 14


class RayCaster:
    """Occlusion and first-hit queries for one mesh.

    Parameters
    ----------
    mesh : a :class:`TriangleMesh`
    offset : ray-origin offset along the normal, as a fraction of the mesh's diagonal
    """

    def __init__(
        self,
        mesh: TriangleMesh,
        *,
        offset: float = 1e-4,
        batch: int = RAY_BATCH,
        threads: int | None = None,
    ):
        self.mesh = mesh
        self.offset = float(offset) * mesh.scale
        self.batch = int(batch)
        # embreex releases the GIL while it traces, so plain threads trace in parallel; by
        # default one per core torch may use
        self.threads = max(1, int(threads or min(os.cpu_count() or 1, torch.get_num_threads())))
        self._pool: ThreadPoolExecutor | None = None
        tm = trimesh.Trimesh(
            vertices=mesh.vertices.detach().cpu().numpy().astype(np.float64),
            faces=mesh.faces.cpu().numpy(),
            process=False,
        )
        self._tri = mesh.vertices.detach().cpu().to(torch.float64)[mesh.faces.cpu()]  # (F, 3, 3)
        self._rt = RayMeshIntersector(tm, scale_to_box=False)

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
        out = self._query(self._rt.intersects_any, o, d, torch.bool)
        return out.reshape(shape).to(origins.device)

    @staticmethod
    def _flat(origins: torch.Tensor, dirs: torch.Tensor):
        """Broadcast batch shape and the rays flattened to (R, 3) each."""
        shape = torch.broadcast_shapes(origins.shape, dirs.shape)[:-1]
        o = origins.expand(*shape, 3).reshape(-1, 3)
        return shape, o, dirs.expand(*shape, 3).reshape(-1, 3)

    def _query(self, fn, o: torch.Tensor, d: torch.Tensor, dtype: torch.dtype) -> torch.Tensor:
        """``fn(origins, dirs)`` of trimesh's Embree intersector in batches of ``self.batch``
        rays (float64 numpy on the CPU, as Embree takes them), (R,) on the CPU."""
        out = torch.empty(o.shape[0], dtype=dtype)
        for i in range(0, o.shape[0], self.batch):
            on = o[i : i + self.batch].detach().cpu().numpy().astype(np.float64)
            dn = d[i : i + self.batch].detach().cpu().numpy().astype(np.float64)
            parts = min(self.threads, max(1, on.shape[0] // MIN_RAYS_PER_THREAD))
            if parts == 1:
                out[i : i + self.batch] = torch.from_numpy(fn(on, dn))
                continue
            if self._pool is None:
                self._pool = ThreadPoolExecutor(self.threads, thread_name_prefix="lobelight-rays")
            cuts = np.linspace(0, on.shape[0], parts + 1).astype(np.int64)
            res = self._pool.map(
                lambda a, b, on=on, dn=dn: fn(on[a:b], dn[a:b]), cuts[:-1], cuts[1:]
            )
            out[i : i + self.batch] = torch.from_numpy(np.concatenate(list(res)))
        return out

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
        """
        shape, o, d = self._flat(origins, dirs)
        tri = self._query(self._rt.intersects_first, o, d, torch.int64)
        t, bary = self._hit_geometry(o.detach().cpu().to(torch.float64), d.cpu().double(), tri)
        dev, dt = origins.device, origins.dtype
        return (
            tri.reshape(shape).to(dev),
            t.reshape(shape).to(dev, dt),
            bary.reshape(*shape, 3).to(dev, dt),
        )

    def _hit_geometry(
        self, o: torch.Tensor, d: torch.Tensor, tri: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        # Moller-Trumbore on the triangles Embree reported: exact distance and barycentrics
        hit = tri >= 0
        t = torch.full((o.shape[0],), float("inf"), dtype=torch.float64)
        bary = torch.zeros(o.shape[0], 3, dtype=torch.float64)
        if bool(hit.any()):
            v = self._tri[tri[hit]]  # (h, 3, 3)
            oh, dh = o[hit], d[hit]
            e1, e2 = v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]
            p = torch.linalg.cross(dh, e2)
            det = (e1 * p).sum(-1)
            inv = 1 / torch.where(det.abs() < 1e-300, torch.full_like(det, 1e-300), det)
            s = oh - v[:, 0]
            b1 = (s * p).sum(-1) * inv
            q = torch.linalg.cross(s, e1)
            b2 = (dh * q).sum(-1) * inv
            t[hit] = (e2 * q).sum(-1) * inv
            bary[hit] = torch.stack([1 - b1 - b2, b1, b2], -1)
        return t, bary
