"""The Gaussians and hit tiles as a model file holds them, made whole on first use.

Gaussians. A file stores ``gaussians (K, N, 7)`` for the ``K`` rows its ``keep (V, J)`` mask
holds (:mod:`lobelight.model._format`); a :class:`~lobelight.lobes.sg.Gaussians` has ``(V, J,
N)`` of each array, the dropped rows with zero weight. :class:`StoredGaussians` is both: read
as ``w``, ``mu`` and ``lam`` it expands once and keeps the expansion, while
:meth:`StoredGaussians.records` decodes a range of records straight from the stored rows. The
GL renderer packs its records texture a band at a time through ``records``, so a render never
allocates the expansion (28 bytes per vertex, view and Gaussian: the model's largest arrays).

Hit tiles. A file stores the hit tiles ``(V, R, R)`` (:func:`lobelight.model.hit_tiles`) as
the texels whose ray hits the object, a few percent of them: :class:`HitTexels`. The GL
renderer lays those texels straight into its atlases (``lobelight.render._gl.hit_atlases``);
:meth:`HitTexels.tiles` makes the tiles whole for the other readers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..lobes import sg
from ..lobes.sg import Gaussians

__all__ = ["HitTexels", "StoredGaussians", "hit_offsets"]

#: The mean of a dropped record (its weight is zero).
_UP = torch.tensor([0.0, 1.0, 0.0])


class StoredGaussians(Gaussians):
    """``(V, J, N)`` Gaussians held as a file's records (on the CPU).

    Parameters
    ----------
    g7 : (K, N, 7) float32 or float16 checked records of the kept rows, in row-major
        ``(vertex, view)`` order: weight RGB, mean (not necessarily unit), sigma
    keep : (V, J) bool, the rows stored (``K`` of them set)
    integral_weights : whether ``g7``'s weights are the light each Gaussian carries (its peak
        times its integral) rather than its peak
    """

    def __init__(self, g7: np.ndarray, keep: np.ndarray, *, integral_weights: bool):
        # the dataclass's fields are this class's properties: not set here
        self._g7 = torch.from_numpy(g7)  # (K, N, 7), the file's dtype
        self._keep = torch.from_numpy(keep).reshape(-1)  # (V J,)
        self._shape = (int(keep.shape[0]), int(keep.shape[1]), int(g7.shape[1]))
        self._integral = integral_weights
        self._slot: torch.Tensor | None = None  # (V J,) each kept row's index in g7
        self._expanded: Gaussians | None = None

    @property
    def shape(self) -> tuple[int, ...]:
        return self._shape

    @property
    def device(self) -> torch.device:
        return torch.device("cpu")

    @property
    def w(self) -> torch.Tensor:
        return self.expanded().w

    @property
    def mu(self) -> torch.Tensor:
        return self.expanded().mu

    @property
    def lam(self) -> torch.Tensor:
        return self.expanded().lam

    def to(self, device) -> Gaussians:
        """Itself on the CPU (still unexpanded); elsewhere the expansion, moved."""
        if torch.device(device).type == "cpu":
            return self
        return self.expanded().to(device)

    def contiguous(self) -> Gaussians:
        """Itself: the stored records and the expansion are C-ordered."""
        return self

    def expanded(self) -> Gaussians:
        """Every record, the dropped rows with zero weight, unit sharpness and mean +y; made
        on first use and kept."""
        if self._expanded is None:
            v, j, n = self._shape
            w, mu, lam = self._rows(0, v * j)
            self._expanded = Gaussians(w.view(v, j, n, 3), mu.view(v, j, n, 3), lam.view(v, j, n))
        return self._expanded

    def records(self, a: int, b: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Records ``a`` to ``b`` (:meth:`Gaussians.records`), decoded from the rows that hold
        them without the expansion (or read from it once made)."""
        if self._expanded is not None:
            return self._expanded.records(a, b)
        n = self._shape[2]
        r0, r1 = a // n, -(-b // n)
        w, mu, lam = self._rows(r0, r1)
        lo, hi = a - r0 * n, b - r0 * n
        return w.view(-1, 3)[lo:hi], mu.view(-1, 3)[lo:hi], lam.view(-1)[lo:hi]

    def _rows(self, r0: int, r1: int) -> tuple[torch.Tensor, ...]:
        """Rows ``r0`` to ``r1`` of ``V J``: ``w (R, N, 3)``, ``mu (R, N, 3)``, ``lam (R, N)``."""
        n = self._shape[2]
        whole = r0 == 0 and r1 == self._keep.shape[0]
        keep = self._keep[r0:r1]
        kept = keep.nonzero().squeeze(1)  # (K',) rows of the range that are stored
        if whole:  # every stored record, in order: no gather
            rec = self._g7.float()
        else:
            if self._slot is None:
                self._slot = torch.cumsum(self._keep, 0) - 1
            rec = self._g7[self._slot[r0:r1][kept]].float()  # (K', N, 7)
        w_k, mu_k, lam_k = self._decode(rec)
        m = r1 - r0
        w = torch.zeros(m, n, 3)
        w.index_copy_(0, kept, w_k)
        lam = torch.ones(m, n)
        lam.index_copy_(0, kept, lam_k)
        mu = torch.empty(m, n, 3)
        mu.index_copy_(0, kept, mu_k)
        dropped = (~keep).nonzero().squeeze(1)
        if dropped.numel():  # zero weight, any unit mean
            mu.index_copy_(0, dropped, _UP.expand(dropped.shape[0], n, 3))
        return w, mu, lam

    def _decode(self, rec: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """Stored records ``(K, N, 7)`` as ``w (K, N, 3)`` peak weights, unit ``mu (K, N,
        3)`` and ``lam (K, N)``."""
        lam = rec[..., 6].pow(-2)
        w = rec[..., :3]
        if self._integral:
            w = w / sg.integral(lam.double()).float()[..., None]
        mu = torch.nn.functional.normalize(rec[..., 3:6], dim=-1)
        return w, mu, lam


@dataclass(frozen=True, eq=False)
class HitTexels:
    """Hit tiles ``(V, R, R)`` as the texels whose ray hits the object (the file's layout,
    :mod:`lobelight.model._format`).

    Attributes
    ----------
    count : (V,) int32 texels per vertex
    texel : (K,) each texel's index in its vertex's tile (row-major), in vertex order and
        ascending within a vertex
    face : (K,) int32 the triangle its ray hits;  dist : (K,) float16 how far
    res : R, the tiles' resolution
    """

    count: np.ndarray
    texel: np.ndarray
    face: np.ndarray
    dist: np.ndarray
    res: int

    @classmethod
    def of_tiles(cls, face: torch.Tensor, dist: torch.Tensor) -> HitTexels:
        """The texels that hit of whole tiles ``face (V, R, R)`` (-1: none) and ``dist``."""
        v, r = face.shape[0], int(face.shape[-1])
        flat = face.reshape(v, -1).cpu().numpy()
        hit = flat >= 0
        vert, texel = np.nonzero(hit)  # row-major: vertex after vertex, texels ascending
        return cls(
            count=hit.sum(1, dtype=np.int32),
            texel=texel,
            face=flat[vert, texel].astype(np.int32),
            dist=dist.reshape(v, -1).cpu().numpy()[vert, texel].astype(np.float16),
            res=r,
        )

    def arrays(self) -> dict[str, np.ndarray]:
        """The file's members (``hit_count``, ``hit_texel`` uint16, ``hit_face``,
        ``hit_distance``)."""
        return {
            "hit_count": self.count.astype(np.int32),
            "hit_texel": self.texel.astype(np.uint16),
            "hit_face": self.face.astype(np.int32),
            "hit_distance": self.dist.astype(np.float16),
        }

    def found(self) -> bool:
        """Whether any texel's ray hits the object."""
        return bool((self.count > 0).any())

    def offsets(self) -> torch.Tensor:
        """Each texel's place in the tiles laid end to end, ``vertex R² + texel`` (K,) int64,
        ascending."""
        return hit_offsets(self.count, self.texel, self.res * self.res)

    def tiles(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The whole tiles: ``face (V, R, R)`` int32 (-1 where the ray misses) and ``dist (V,
        R, R)`` float16 (0 there)."""
        v, r = self.count.shape[0], self.res
        flat = self.offsets()
        face = torch.full((v * r * r,), -1, dtype=torch.int32)
        dist = torch.zeros(v * r * r, dtype=torch.float16)
        face[flat] = torch.from_numpy(np.ascontiguousarray(self.face, np.int32))
        dist[flat] = torch.from_numpy(np.ascontiguousarray(self.dist, np.float16))
        return face.view(v, r, r), dist.view(v, r, r)


def hit_offsets(count: np.ndarray, texel: np.ndarray, per_tile: int) -> torch.Tensor:
    """Each stored hit's place in the tiles laid end to end, ``vertex R² + texel`` (K,) int64."""
    vert = torch.repeat_interleave(
        torch.arange(count.shape[0], dtype=torch.int64), torch.from_numpy(count.astype(np.int64))
    )
    return vert * per_tile + torch.from_numpy(texel.astype(np.int64))
