"""Light-transport sampling per vertex and view (Green et al. 2006, section 4.1).

For a vertex ``x`` with normal ``n`` and a view direction ``v`` (towards the viewer, global
frame) the transport function splits into three parts (paper eq. 5):

direct glossy
    ``T_G(w) = f_s(w, v) V_x(w) max(n.w, 0)`` (RGB), with ``f_s`` the material's specular lobe and
    ``V_x`` binary visibility of the environment, by ray casting. :meth:`Transport.direct`
    evaluates it at any directions (a global cube map, or a dense local grid around a sharp
    lobe: the BRDF part is analytic, only visibility needs rays).
indirect glossy
    Paths that leave ``x`` toward the object by importance sampling ``f_s`` for the view ``v``,
    bounce off the object (full material: Lambert + specular, sampled as a mixture) and are
    recorded at the direction in which they escape, until Russian roulette ends them. The
    recorded throughputs, binned on a cube map and divided by the bin's solid angle, estimate
    the transport density (:meth:`Transport.indirect`); integrated against the lighting they
    give the radiance these paths carry to the viewer. A bake keeps them as one Gaussian per
    vertex and view instead (:meth:`Transport.indirect_lobes`), each vertex's paths shared
    across its views and no sharper than the lobe that gathers them
    (:func:`gathering_sharpness`).
diffuse
    ``T_D`` as order-5 spherical-harmonic transfer vectors: ``(albedo / pi) int Y_lm(w) V_x(w)
    max(n.w, 0) dw`` (self-shadowed), and optionally diffuse interreflection
    (:func:`~lobelight.transport.diffuse_interreflection`), iterating the transfer of the
    points rays hit.

Every ray a vertex casts leaves its ray origin (:attr:`Transport.origins`,
:func:`lobelight.transport.vertex_origins`): off the other side of a hard edge, and for a
vertex covered by a surface just over it, at an exposed point of its own faces.
Views with ``n.v <= 0`` are below the horizon: their transport is 0 and they are flagged.
Work runs over batches of vertices so that memory stays bounded for any mesh.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import torch

from .._tol import DIVISOR_F32
from ..errors import InputError
from ..geometry import cubemap, sphere
from ..geometry.raycast import RayCaster
from ..lobes import sg, sh
from ..lobes.sg import Gaussians
from ..scene import Scene
from ._origins import VertexOrigins, vertex_origins

__all__ = [
    "BOUNCES",
    "INDIRECT_LAM_RANGE",
    "INDIRECT_PATHS",
    "Transport",
    "TransportBatch",
    "gathering_sharpness",
    "sample",
]

#: Order of the diffuse spherical-harmonic transfer (25 coefficients).
DIFFUSE_ORDER = 5
#: Bounces of diffuse interreflection a bake adds to the SH transfer: in a hemispherical bowl
#: of albedo 0.7 the fifth and later add a negligible part of the total (docs/method.md).
BOUNCES = 4
#: Paths per vertex and view of a bake's indirect glossy (docs/method.md).
INDIRECT_PATHS = 16
#: Sharpness range of the indirect glossy Gaussians (:meth:`Transport.indirect_lobes`), the
#: fit's (:data:`lobelight.lobes.sg.LAM_RANGE`): paths that all escape one way (a mirror seen in a
#: mirror) would give an infinite one, whose width (0) blends to NaN.
INDIRECT_LAM_RANGE = sg.LAM_RANGE
#: Sharpness of the indirect Gaussian of a (vertex, view) whose paths escape as one (by the
#: throughputs' effective count), which tells no width: a lobe holding half its light within
#: 8.4 degrees of the path, narrower than the views' spacing, across which the renderers blend
#: the lobes anyway. Spread over the sphere instead, such a lone path (most of a rough metal's
#: at 16 paths) puts its light where the object blocks it, and on a sun there (docs/method.md
#: has the measurement).
LONE_PATH_LAM = 64.0
#: The sharpest gathering lobe (:func:`gathering_sharpness`) whose (vertex, view)s draw on
#: the paths of the vertex's other views (:meth:`Transport.indirect_lobes`): a lobe holding
#: half its light within 8.4 degrees, while the 92 views' neighbours lie about 20 degrees
#: apart and their lobes twice that in light directions. A sharper lobe's neighbours would
#: add only their lobes' tails; it keeps its own paths.
SHARED_LAM_MAX = 64.0
#: (path, view) pairs :meth:`Transport.indirect_lobes` weighs at once, the vertices grouped to
#: stay near it: bounds its memory (a few (pairs, 3) float tensors) on any mesh and device.
_SHARE_PAIRS = 1 << 19
#: Samples per axis of the stratified grid that measures a lobe's sharpness
#: (:func:`gathering_sharpness`): 16 keeps GGX's within 15 % of a quadrature's from roughness
#: 0.02 to 0.5 (8 misses the lobe's centre at normal incidence by up to 60 %).
_GATHER_GRID = 16
#: Elevations of :meth:`Transport._gathering`'s table, uniform in the view's cosine.
_GATHER_ELEVATIONS = 64


@dataclass(eq=False)
class TransportBatch:
    """Tabulated transport of a batch of vertices for every view.

    Attributes
    ----------
    vertices : (B,) int64 mesh vertex ids
    views : (J, 3) view directions (global frame, towards the viewer)
    below : (B, J) bool, view below the vertex's horizon (transport 0 there)
    dirs : (D, 3) lighting directions of the tabulation (cube-map texel centres, GL layout)
    solid_angle : (D,) their exact texel solid angles
    visibility : (B, D) bool, environment visible from the vertex along ``dirs``
    glossy : (B, J, D, 3) direct glossy transport ``f_s V cos`` at ``dirs``
    indirect : (B, J, D_i, 3) or None, indirect glossy density on a cube map of ``indirect_res``
    indirect_res : face resolution of ``indirect``
    diffuse : (B, 25, 3) self-shadowed diffuse SH transfer (albedo included)
    """

    vertices: torch.Tensor
    views: torch.Tensor
    below: torch.Tensor
    dirs: torch.Tensor
    solid_angle: torch.Tensor
    visibility: torch.Tensor
    glossy: torch.Tensor
    indirect: torch.Tensor | None
    indirect_res: int
    diffuse: torch.Tensor

    def total(self) -> torch.Tensor:
        """Glossy transport at ``dirs`` with the indirect part resampled onto them, (B, J, D, 3)."""
        if self.indirect is None:
            return self.glossy
        res = round(math.sqrt(self.dirs.shape[0] / 6))
        ind = self.indirect
        if self.indirect_res != res:
            # nearest bin: the density is piecewise constant over the coarser bins
            ind = ind[:, :, _bin(self.dirs, self.indirect_res)]
        return self.glossy + ind


@dataclass(eq=False)
class _Escaped:
    """The escaped paths of :meth:`Transport._trace`, each with its first bounce kept apart.

    Attributes
    ----------
    slot : (E,) int64 ``vertex * J + view``;  dirs : (E, 3) escape directions
    first : (E, 3) the direction each left the vertex in;  first_weight : (E, 3) the first
    bounce's ``f cos / pdf`` for its own view;  rest : (E, 3) its throughput after the first
    bounce (which does not depend on the view)
    """

    slot: torch.Tensor
    dirs: torch.Tensor
    first: torch.Tensor
    first_weight: torch.Tensor
    rest: torch.Tensor

    @classmethod
    def none(cls, device) -> _Escaped:
        z = torch.zeros(0, 3, device=device)
        return cls(torch.zeros(0, dtype=torch.int64, device=device), z, z, z, z)


class Transport:
    """Transport sampling for one scene: visibility, direct and indirect glossy, SH diffuse.

    Parameters
    ----------
    scene : Scene
    device : torch device of the transport's tensors. Rays run through
        :class:`lobelight.geometry.raycast.RayCaster`'s process-default engine: Embree (on
        the CPU, the rays moved there and back) or NVIDIA Warp (on the mesh's device; the
        default on a CUDA device where Warp is installed)
    """

    def __init__(
        self,
        scene: Scene,
        *,
        device=None,
        shadows: bool = True,
        origins: VertexOrigins | None = None,
    ):
        self.device = torch.device(device) if device is not None else scene.mesh.device
        # shadows=False drops visibility (every direction above the horizon sees the
        # environment): the transport of plain prefiltered environment mapping, the paper's
        # Figure 6 baseline
        self.shadows = bool(shadows)
        self.scene = scene.to(self.device)
        self.mesh = self.scene.mesh
        self.materials = self.scene.materials
        self.caster = RayCaster(self.mesh)
        self._origins = origins
        # gathering_sharpness by the view's elevation, for a shared isotropic specular lobe
        self._gather_table: torch.Tensor | None = None

    @property
    def origins(self) -> VertexOrigins:
        """Where each vertex's rays start (:func:`lobelight.transport.vertex_origins`, computed
        on first use; or as given to the constructor): every ray this transport casts from a
        vertex, for visibility, the indirect glossy paths' first bounce and the
        interreflection's gather, leaves ``origins.points`` lifted by the caster's offset."""
        if self._origins is None:
            self._origins = vertex_origins(self.mesh, caster=self.caster)
        elif self._origins.points.device != self.device:
            o = self._origins
            self._origins = VertexOrigins(o.points.to(self.device), o.exposed.to(self.device))
        return self._origins

    # ---- visibility ---------------------------------------------------------------------------

    def visibility(self, vidx: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
        """Whether the environment is visible from vertices along directions.

        Only rays above the geometric horizon of the vertex normal are cast; the others are
        reported invisible (their cosine factor is zero anyway).

        Parameters
        ----------
        vidx : (B,) vertex ids;  dirs : (B, ..., 3) or (..., 3) unit directions (broadcast)

        Returns
        -------
        (B, ...) bool
        """
        vidx = vidx.to(self.device)
        b = vidx.shape[0]
        extra = dirs.ndim - 2 if dirs.shape[0] == b and dirs.ndim >= 2 else dirs.ndim - 1
        n = self.mesh.normals[vidx].reshape(b, *([1] * extra), 3)
        d = dirs.to(self.device, n.dtype)
        shape = torch.broadcast_shapes(n.shape, d.shape)[:-1]
        d = d.expand(*shape, 3)
        up = (d * n).sum(-1) > 0
        if not self.shadows:
            return up
        out = torch.zeros(shape, dtype=torch.bool, device=self.device)
        if bool(up.any()):
            p = self.origins.points[vidx].reshape(b, *([1] * extra), 3)
            o = self.caster.spawn(p.expand(*shape, 3)[up], n.expand(*shape, 3)[up], d[up])
            out[up] = ~self.caster.occluded(o, d[up])
        return out

    # ---- direct glossy ------------------------------------------------------------------------

    def direct(
        self,
        vidx: torch.Tensor,
        views: torch.Tensor,
        dirs: torch.Tensor,
        *,
        visibility: torch.Tensor | None = None,
        need: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Direct glossy transport ``f_s(w, v) V(w) max(n.w, 0)`` at given directions.

        Parameters
        ----------
        vidx : (B,) vertex ids;  views : (J, 3)
        dirs : (D, 3) shared directions, or (B, J, K, 3) per vertex and view (e.g. a local grid
            around the lobe's peak)
        visibility : optional precomputed visibility, (B, D) or (B, J, K)
        need : optional (B, J, D) bool with shared directions: where False the transport is not
            evaluated and 0 is returned (a caller's quadrature weight of 0 there)

        Returns
        -------
        (B, J, D or K, 3); 0 for views below the horizon
        """
        vidx = vidx.to(self.device)
        b, j = vidx.shape[0], views.shape[0]
        views = views.to(self.device, torch.float32)
        n = self.mesh.normals[vidx]  # (B, 3)
        spec = self.materials.specular
        below = (views[None] * n[:, None]).sum(-1) <= 0  # (B, J)
        if dirs.ndim == 2:
            d = dirs.to(self.device, torch.float32)  # (D, 3)
            vis = self.visibility(vidx, d) if visibility is None else visibility  # (B, D)
            out = torch.zeros(b, j, d.shape[0], 3, device=self.device)
            if spec is None:
                return out
            # evaluate only where the environment is visible (a third to a half of the sphere
            # for most vertices), from views above the horizon and where the caller needs it:
            # the BRDF evaluation is the cost here, not the rays
            keep = vis[:, None] & ~below[..., None]  # (B, J, D)
            if need is not None:
                keep = keep & need
            bi, ji, di = keep.nonzero(as_tuple=True)  # (T,) each
            dd, nn = d[di], n[bi]  # (T, 3)
            f = spec.take(vidx[bi]).eval(dd, views[ji], nn)  # (T, 3)
            out[bi, ji, di] = f * (dd * nn).sum(-1, keepdim=True).clamp_min(0)
            return out
        d = dirs.to(self.device, torch.float32)  # (B, J, K, 3)
        k = d.shape[2]
        out = torch.zeros(b, j, k, 3, device=self.device)
        if spec is None:
            return out
        # only the views above the horizon, packed: below it the transport is 0, and the
        # local grid of such a view (no lobe there, so it spans the sphere) would otherwise
        # cost a third of all rays for nothing
        bi, ji = (~below).nonzero(as_tuple=True)  # (M,) each
        m = bi.shape[0]
        dm = d[bi, ji]  # (M, K, 3)
        vis = self.visibility(vidx[bi], dm) if visibility is None else visibility[bi, ji]
        s = spec.take(vidx[bi])  # per-element parameters (M, ...)
        s = s.map_params(lambda t, kind: t if t.ndim <= kind else t.reshape(m, 1, *t.shape[1:]))
        nn = n[bi][:, None]  # (M, 1, 3)
        f = s.eval(dm, views[ji][:, None], nn)  # (M, K, 3)
        cos = (dm * nn).sum(-1).clamp_min(0)
        out[bi, ji] = f * (cos * vis)[..., None]
        return out

    # ---- indirect glossy ----------------------------------------------------------------------

    def indirect(
        self,
        vidx: torch.Tensor,
        views: torch.Tensor,
        *,
        paths: int = 64,
        res: int = 16,
        max_bounces: int = 8,
        generator: torch.Generator | None = None,
    ) -> torch.Tensor:
        """Indirect glossy transport density by BRDF-importance-sampled path tracing.

        Parameters
        ----------
        vidx : (B,) vertex ids;  views : (J, 3)
        paths : paths per vertex and view
        res : face resolution of the cube map the escape directions are binned on
        max_bounces : hard cap on bounces off the object (Russian roulette ends most paths
            earlier; the cap bounds the loop)

        Returns
        -------
        (B, J, 6 res^2, 3): sum of escaped throughputs per bin / (paths * bin solid angle), so
        that ``sum_bins T * L * solid_angle`` estimates the radiance these paths carry
        """
        dev = self.device
        b, j = vidx.shape[0], views.shape[0]
        n_bins = 6 * res * res
        acc = torch.zeros(b * j * n_bins, 3, device=dev)
        slot, d, thr = self.escapes(
            vidx, views, paths=paths, max_bounces=max_bounces, generator=generator
        )
        if slot.numel():
            acc.index_add_(0, slot * n_bins + _bin(d, res), thr)
        om = cubemap.texel_solid_angles(res, device=dev).reshape(-1)
        return acc.reshape(b, j, n_bins, 3) / (paths * om[None, None, :, None])

    def indirect_lobes(
        self,
        vidx: torch.Tensor,
        views: torch.Tensor,
        *,
        paths: int = 64,
        max_bounces: int = 8,
        generator: torch.Generator | None = None,
    ) -> Gaussians:
        """Indirect glossy transport as one Gaussian per vertex and view, from its paths.

        The paths of :meth:`escapes` sample the indirect transport as a density over escape
        directions. A path's part after its first bounce does not depend on the view, so every
        escaped path of a vertex serves each of its views: reweighted to view ``v`` by
        ``f(w, v) cos / sum_u pdf(w | u)`` (the balance heuristic over the views' sampling
        densities ``u``, all above the horizon, ``w`` the direction it left in), which keeps
        each view's estimate unbiased while a rough lobe, which overlaps its neighbours'
        lobes, draws on several views' paths instead of its own few. A lobe sharper than
        :data:`SHARED_LAM_MAX`, which its neighbours' paths reach only through their tails,
        keeps its own paths. The paths' weights summed over ``paths`` estimate the transport's
        integral (the Gaussian keeps it exactly), their weighted mean direction its mean, and
        their weighted median angle from that mean its width (a vMF holds half its light
        within ``1 - cos = ln 2 / lam``). The median, not the second moment: a mirror's image
        in a curved mirror is compact with a few wide strays, and the vMF of the paths' second
        moment puts its tail on bright sources the paths miss (docs/method.md has the
        measurement). A lone path (by the weights' effective count) tells no width: it gets
        :data:`LONE_PATH_LAM`.

        The sharpness is then capped by that of the lobe that gathers the light
        (:func:`gathering_sharpness`), the light kept: the indirect radiance seen through the
        BRDF lobe is the radiance arriving at the vertex convolved with that lobe, and the
        light arriving off the object reaches the escape directions through a reflection that
        keeps the lobe's spread (a flat mirror) or widens it (a rough or convex surface, a
        diffuse one most). A concave mirror can focus it and the object's outline can cut it,
        which a rough lobe's next reflection spreads again; an estimate sharper than the lobe
        is otherwise its few paths' noise, which puts spots of the lighting on a smooth
        surface.

        Parameters
        ----------
        vidx : (B,);  views : (J, 3);  paths, max_bounces, generator : as :meth:`indirect`

        Returns
        -------
        Gaussians with w (B, J, 1, 3), mu (B, J, 1, 3), lam (B, J, 1) (sharpness in
        :data:`INDIRECT_LAM_RANGE`; zero weight where no path escaped)
        """
        vidx = vidx.to(self.device)
        views = views.to(self.device, torch.float32)
        b, j = vidx.shape[0], views.shape[0]
        tr = self._trace(vidx, views, paths=paths, max_bounces=max_bounces, generator=generator)
        w = torch.zeros(b, j, 3, device=self.device)
        mu = torch.zeros(b, j, 3, device=self.device)
        lam = torch.ones(b, j, device=self.device)
        cap = torch.full((b, j), math.inf, device=self.device)
        if self.materials.specular is not None and b * j:
            bi, ji = (self.mesh.normals[vidx] @ views.T > 0).nonzero(as_tuple=True)  # (M,) each
            cap[bi, ji] = self._gathering(vidx[bi], views[ji])
        for lo, hi in _groups(torch.bincount(tr.slot // j, minlength=b) * j, _SHARE_PAIRS):
            own = cap[lo:hi] > SHARED_LAM_MAX  # (G, J) lobes too sharp to share
            slot, d, thr = _shared_across_views(self, vidx, views, tr, lo, hi, own)
            gw, gmu, glam = _escape_lobes(slot, d, thr, (hi - lo) * j, paths)
            w[lo:hi], mu[lo:hi] = gw.reshape(-1, j, 3), gmu.reshape(-1, j, 3)
            lam[lo:hi] = glam.reshape(-1, j)
        capped = torch.minimum(lam, cap)
        # the same light in the wider Gaussian: the weight scales by the integrals' ratio
        w = w * (sg.integral(lam) / sg.integral(capped))[..., None]
        lam = capped
        return Gaussians(w.reshape(b, j, 1, 3), mu.reshape(b, j, 1, 3), lam.reshape(b, j, 1))

    def _gathering(self, vid: torch.Tensor, views: torch.Tensor) -> torch.Tensor:
        """:func:`gathering_sharpness` of vertices ``vid`` (M,) for views (M, 3); of one
        material shared by all vertices and isotropic, from a table over the view's
        elevation (the samples cost more than the paths otherwise)."""
        spec, n = self.materials.specular, self.mesh.normals[vid]
        if self._gather_table is None and _shared_isotropic(spec):
            c = (torch.arange(_GATHER_ELEVATIONS, device=self.device) + 0.5) / _GATHER_ELEVATIONS
            v = torch.stack([(1 - c * c).sqrt(), torch.zeros_like(c), c], -1)  # (K, 3)
            z = torch.tensor([0.0, 0.0, 1.0], device=self.device).expand_as(v)
            one = spec.take(torch.zeros(1, dtype=torch.int64, device=self.device))
            self._gather_table = gathering_sharpness(one, z, v)  # (K,)
        if self._gather_table is None:
            return gathering_sharpness(spec.take(vid), n, views)
        cos = (n * views).sum(-1)  # (M,)
        x = (cos * _GATHER_ELEVATIONS - 0.5).clamp(0, _GATHER_ELEVATIONS - 1)
        i = x.floor().long().clamp(max=_GATHER_ELEVATIONS - 2)
        t = x - i
        lam = self._gather_table[i] * (1 - t) + self._gather_table[i + 1] * t
        return torch.where(cos > 0, lam, torch.full_like(lam, math.inf))

    def escapes(
        self,
        vidx: torch.Tensor,
        views: torch.Tensor,
        *,
        paths: int = 64,
        max_bounces: int = 8,
        generator: torch.Generator | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The indirect glossy paths that escape the object after at least one bounce off it.

        ``paths`` paths per vertex and view leave the vertex by importance sampling its
        specular lobe for the view (its diffuse part is the SH term's), bounce off the object
        (full material: Lambert + specular, sampled as a mixture) until Russian roulette ends
        them, and are recorded where they escape.

        Parameters
        ----------
        vidx : (B,) vertex ids;  views : (J, 3)
        max_bounces : hard cap on bounces off the object (bounds the loop)

        Returns
        -------
        slot : (E,) int64 ``vertex * J + view`` of each escaped path;  dirs : (E, 3) its escape
        direction;  thr : (E, 3) its throughput (``f cos / pdf`` products: ``sum thr / paths``
        per slot estimates the indirect transport's integral)
        """
        vidx = vidx.to(self.device)
        views = views.to(self.device, torch.float32)
        e = self._trace(vidx, views, paths=paths, max_bounces=max_bounces, generator=generator)
        return e.slot, e.dirs, e.first_weight * e.rest

    def _trace(
        self,
        vidx: torch.Tensor,
        views: torch.Tensor,
        *,
        paths: int,
        max_bounces: int,
        generator: torch.Generator | None,
    ) -> _Escaped:
        """:meth:`escapes`'s paths with their first bounce kept apart (:class:`_Escaped`)."""
        dev = self.device
        b, j = vidx.shape[0], views.shape[0]
        spec = self.materials.specular
        if spec is None or b * j == 0:
            return _Escaped.none(dev)
        g = generator

        def rand(*shape):
            return torch.rand(*shape, generator=g, device="cpu").to(dev)

        # path state, flattened over (B, J, paths)
        m = b * j * paths
        slot = torch.arange(m, device=dev) // paths  # (m,) which (vertex, view)
        vert = vidx.repeat_interleave(j * paths)  # (m,)
        wo = views.repeat_interleave(paths, 0).repeat(b, 1)  # (m, 3)
        p = self.origins.points[vert]  # the first bounce leaves the vertex's ray origin
        n = self.mesh.normals[vert]
        above = (wo * n).sum(-1) > 0
        # first bounce: the specular lobe at x only (the diffuse part is the SH term's)
        wi, weight, _ = spec.take(vert).sample(wo, n, rand(m, 2))
        w0 = weight * above[:, None]
        alive = (w0.amax(-1) > 0).nonzero().squeeze(-1)
        p, n, wi, w0, slot = p[alive], n[alive], wi[alive], w0[alive], slot[alive]
        first_dir = wi
        # the live paths' index into the first bounce's arrays, and their throughput since
        rest = torch.ones_like(w0)
        k = torch.arange(slot.numel(), device=dev)
        found = []
        for bounce in range(max_bounces + 1):
            if k.numel() == 0:
                break
            o = self.caster.spawn(p, n, wi)
            tri, _, bary = self.caster.first_hit(o, wi)
            esc = tri < 0
            if bounce > 0 and bool(esc.any()):
                # escaped after at least one bounce off the object
                found.append((k[esc], wi[esc], rest[esc]))
            keep = ~esc
            if bounce == max_bounces or not bool(keep.any()):
                break
            tri, bary, wo_y, rest, k = tri[keep], bary[keep], -wi[keep], rest[keep], k[keep]
            corners = self.mesh.faces[tri]  # (h, 3)
            w = bary[..., None]
            p = (self.mesh.vertices[corners] * w).sum(1)
            ns = torch.nn.functional.normalize((self.mesh.normals[corners] * w).sum(1), dim=-1)
            # shade with the normal on the side the ray arrived from (thin or open meshes)
            ns = torch.where(((ns * wo_y).sum(-1) < 0)[:, None], -ns, ns)
            mat = self.materials.interpolate(corners, bary).brdf()
            wi, weight, _ = mat.sample(wo_y, ns, rand(len(tri), 3))
            rest = rest * weight
            # Russian roulette after the second bounce, survival by the throughput's maximum
            if bounce >= 1:
                q = (w0[k] * rest).amax(-1).clamp(0.05, 0.95)
                survive = rand(len(q)) < q
                rest = torch.where(survive[:, None], rest / q[:, None], torch.zeros_like(rest))
            live = ((w0[k] * rest).amax(-1) > 0).nonzero().squeeze(-1)
            p, n, wi, rest, k = p[live], ns[live], wi[live], rest[live], k[live]
        if not found:
            return _Escaped.none(dev)
        k = torch.cat([f[0] for f in found])
        return _Escaped(
            slot[k],
            torch.cat([f[1] for f in found]),
            first_dir[k],
            w0[k],
            torch.cat([f[2] for f in found]),
        )

    # ---- diffuse --------------------------------------------------------------------------

    def diffuse(
        self,
        vidx: torch.Tensor,
        dirs: torch.Tensor,
        solid_angle: torch.Tensor,
        *,
        visibility: torch.Tensor | None = None,
        order: int = DIFFUSE_ORDER,
    ) -> torch.Tensor:
        """Self-shadowed diffuse SH transfer ``(albedo / pi) sum_w Y(w) V(w) cos(w) Omega(w)``.

        Parameters
        ----------
        vidx : (B,);  dirs : (D, 3) quadrature directions;  solid_angle : (D,) their weights
        visibility : optional (B, D) precomputed visibility

        Returns
        -------
        (B, order^2, 3)
        """
        vidx = vidx.to(self.device)
        d = dirs.to(self.device, torch.float32)
        vis = self.visibility(vidx, d) if visibility is None else visibility
        n = self.mesh.normals[vidx]
        cos = (n @ d.T).clamp_min(0)  # (B, D)
        w = cos * vis * solid_angle.to(self.device)[None]
        y = sh.basis(d, order)  # (D, order^2)
        geo = w @ y  # (B, order^2)
        return geo[..., None] * (self.materials.diffuse[vidx] / math.pi)[:, None, :]


def sample(
    scene: Scene,
    vertices=None,
    views=None,
    *,
    res: int = 32,
    indirect: bool = True,
    indirect_res: int = 16,
    paths: int = 64,
    seed: int = 0,
    device=None,
    transport: Transport | None = None,
) -> TransportBatch:
    """Tabulate the transport of some vertices for every view on a cube map of directions.

    Parameters
    ----------
    scene : Scene
    vertices : (B,) vertex ids (default all: mind the memory, B x J x 6 res^2 x 3 floats)
    views : (J, 3) view directions (default the 92 geodesic views)
    res : face resolution of the direction cube map for direct glossy and diffuse
    indirect : also path-trace indirect glossy (``paths`` per vertex and view) on a cube map of
        ``indirect_res``
    seed : random seed of the path tracer (results are deterministic for a seed)

    Returns
    -------
    TransportBatch
    """
    tr = transport if transport is not None else Transport(scene, device=device)
    dev = tr.device
    if vertices is None:
        vertices = torch.arange(tr.mesh.n_vertices)
    vidx = torch.as_tensor(vertices, dtype=torch.int64, device=dev).reshape(-1)
    if vidx.numel() and (int(vidx.min()) < 0 or int(vidx.max()) >= tr.mesh.n_vertices):
        raise InputError("vertices", f"ids must be in [0, {tr.mesh.n_vertices})")
    if views is None:
        views = sphere.geodesic_views(device=dev)
    views = torch.as_tensor(views, dtype=torch.float32, device=dev).reshape(-1, 3)
    if res < 1 or indirect_res < 1 or paths < 1:
        raise InputError("res", "resolutions and path counts must be positive")
    dirs = cubemap.texel_directions(res, device=dev).reshape(-1, 3)
    om = cubemap.texel_solid_angles(res, device=dev).reshape(-1)
    vis = tr.visibility(vidx, dirs)  # (B, D)
    glossy = tr.direct(vidx, views, dirs, visibility=vis)
    below = (views[None] * tr.mesh.normals[vidx][:, None]).sum(-1) <= 0
    ind = None
    if indirect:
        gen = torch.Generator().manual_seed(int(seed))
        ind = tr.indirect(vidx, views, paths=paths, res=indirect_res, generator=gen)
    diffuse = tr.diffuse(vidx, dirs, om, visibility=vis)
    return TransportBatch(
        vertices=vidx,
        views=views,
        below=below,
        dirs=dirs,
        solid_angle=om,
        visibility=vis,
        glossy=glossy,
        indirect=ind,
        indirect_res=indirect_res,
        diffuse=diffuse,
    )


def _bin(dirs: torch.Tensor, res: int) -> torch.Tensor:
    """``(N,)`` the cube-map bin (``(face * res + row) * res + col``) of each of ``dirs (N, 3)``."""
    f, u, v = cubemap.direction_to_face_uv(dirs)
    col = ((u + 1) * res / 2).floor().long().clamp(0, res - 1)
    row = ((v + 1) * res / 2).floor().long().clamp(0, res - 1)
    return (f * res + row) * res + col


def _escape_lobes(slot, d, thr, m: int, paths: int):
    """One Gaussian per group of escaped paths (:meth:`Transport.indirect_lobes`):
    ``(w (m, 3), mu (m, 3), lam (m,))`` for groups ``0..m-1`` given each path's ``slot``."""
    dev = d.device
    s = torch.zeros(m, 3, device=dev).index_add_(0, slot, thr) / paths  # (m, 3) integral
    lum = thr.sum(-1)  # (E,) the direction statistics' weights
    big_l = torch.zeros(m, device=dev).index_add_(0, slot, lum)
    big_q = torch.zeros(m, device=dev).index_add_(0, slot, lum * lum)
    mom = torch.zeros(m, 3, device=dev).index_add_(0, slot, lum[:, None] * d)
    norm = torch.linalg.vector_norm(mom, dim=-1)
    some = (big_l > 0) & (norm > 0)
    up = torch.tensor([0.0, 1.0, 0.0], device=dev)
    mu = torch.where(some[:, None], mom / norm.clamp_min(DIVISOR_F32)[:, None], up)
    # the weighted median of 1 - cos to the mean (half chords: precise for sharp lobes): the
    # paths sorted by slot, then by it; per slot the first at half the slot's weight
    half = 0.5 * ((d - mu[slot]) ** 2).sum(-1)  # (E,)
    order = torch.argsort(slot.double() * 4 + half.double())
    ss, hs = slot[order], half[order]
    before = torch.cumsum(big_l, 0) - big_l  # (m,) the weight of the earlier slots
    frac = (lum[order].cumsum(0) - before[ss]) / big_l[ss].clamp_min(DIVISOR_F32)
    e = ss.numel()
    at = torch.where(frac >= 0.5, torch.arange(e, device=dev), e)
    first = torch.full((m,), e, dtype=torch.int64, device=dev).scatter_reduce(0, ss, at, "amin")
    hm = torch.zeros(m, device=dev)
    hm[first < e] = hs[first[first < e]]
    # a vMF holds half its light within 1 - cos = ln 2 / lam (for lam >> 1); one path (by
    # the throughputs' effective count) tells no width: LONE_PATH_LAM
    lam = (math.log(2) / hm.clamp_min(DIVISOR_F32)).clamp(*INDIRECT_LAM_RANGE)
    n_eff = big_l**2 / big_q.clamp_min(DIVISOR_F32)
    lam = torch.where(some & (n_eff >= 2), lam, torch.full_like(lam, LONE_PATH_LAM))
    w = torch.where(some[:, None], s / sg.integral(lam)[:, None], torch.zeros_like(s))
    return w, mu, lam


def _shared_across_views(tr: Transport, vidx, views, e: _Escaped, lo: int, hi: int, own):
    """The escaped paths of vertices ``vidx[lo:hi]`` shared across their views
    (:meth:`Transport.indirect_lobes`): ``(slot (P,), dirs (P, 3), thr (P, 3))`` per (path,
    view) pair of positive weight, ``slot`` counted from vertex ``lo``.

    A path that left vertex ``x`` in direction ``w`` for its own view weighs, for view ``v``,
    ``f(w, v) max(n.w, 0) / sum_u pdf(w | u)`` times its throughput after the first bounce,
    the sum over the views ``u`` above the horizon, whose lobes drew ``paths`` paths each: the
    balance heuristic over the views' sampling, unbiased for every view. The (vertex, view)s
    where ``own`` (G, J) is True keep their own paths with their own weights instead (also
    unbiased)."""
    j = views.shape[0]
    pick = (e.slot >= lo * j) & (e.slot < hi * j)
    slot, dirs, first, rest = e.slot[pick], e.dirs[pick], e.first[pick], e.rest[pick]
    if slot.numel() == 0:
        return slot, dirs, rest
    bi, ji = slot // j - lo, slot % j  # (E,) vertex in the group, own view
    n = tr.mesh.normals[vidx[lo:hi]]  # (G, 3)
    # the (path, view) pairs of the views above the horizon, which drew paths: (P,) each
    pe, pj = (n @ views.T > 0)[bi].nonzero(as_tuple=True)
    spec = tr.materials.specular.take(vidx[lo:hi][bi[pe]])  # per-pair parameters (P, ...)
    wi, nn, vv = first[pe], n[bi[pe]], views[pj]  # (P, 3) each
    f = spec.eval(wi, vv, nn) * (wi * nn).sum(-1, keepdim=True).clamp_min(0)  # (P, 3)
    q = torch.zeros_like(slot, dtype=f.dtype).index_add_(0, pe, spec.pdf(wi, vv, nn))  # (E,)
    thr = f * (rest[pe] / q.clamp_min(torch.finfo(q.dtype).tiny)[pe, None])  # (P, 3)
    shared = ~own[bi[pe], pj]  # (P,) the pairs of views that share
    mine = own[bi, ji].nonzero().squeeze(-1)  # (K,) paths kept by their own view alone
    k = torch.cat([pe[shared], mine])
    thr = torch.cat([thr[shared], e.first_weight[pick][mine] * rest[mine]])
    slot = bi[k] * j + torch.cat([pj[shared], ji[mine]])
    ok = thr.amax(-1) > 0
    return slot[ok], dirs[k[ok]], thr[ok]


def _groups(counts: torch.Tensor, budget: int) -> list[tuple[int, int]]:
    """Consecutive ``(lo, hi)`` ranges of the items with ``counts`` (B,): the items whose
    running total before them falls in one multiple of ``budget``, so that a range holds at
    most ``budget`` plus its last item's count."""
    b = counts.shape[0]
    if b == 0:
        return []
    start = (torch.cumsum(counts, 0) - counts) // max(int(budget), 1)  # (B,) group of each
    cuts = ((start[1:] != start[:-1]).nonzero().squeeze(-1) + 1).tolist()
    edges = [0, *cuts, b]
    return list(itertools.pairwise(edges))


def _shared_isotropic(spec) -> bool:
    """Whether ``spec`` is isotropic with the same parameters at every element."""
    if not spec.isotropic:
        return False
    same = []

    def check(t, kind):
        same.append(t.ndim <= kind or bool(torch.equal(t, t[:1].expand_as(t))))
        return t

    spec.map_params(check)
    return all(same)


def gathering_sharpness(spec, normals: torch.Tensor, views: torch.Tensor) -> torch.Tensor:
    """The sharpness of the light directions a specular lobe gathers, measured as the indirect
    Gaussians' is (:meth:`Transport.indirect_lobes`).

    The lobe ``f(w, v) max(n.w, 0)`` as a density over light directions ``w``, from a
    stratified grid of its importance samples: the vMF sharpness that holds half its light
    within the samples' weighted median ``1 - cos`` from their weighted mean direction
    (``ln 2 / median``). For GGX of roughness ``alpha`` it is near ``1 / (2 alpha^2)`` at
    normal incidence (the sharpness of its distribution of normals, halved by the
    reflection) and stays finite at grazing views, where the horizon cuts the lobe.

    Parameters
    ----------
    spec : lobelight.brdf.BRDF with per-element parameters ``(M, ...)``, or shared ones
    normals : (M, 3) unit normals;  views : (M, 3) unit view directions

    Returns
    -------
    (M,) float32 in :data:`INDIRECT_LAM_RANGE`; inf where the view is below the horizon (no
    lobe: no bound)
    """
    dev = normals.device
    m = normals.shape[0]
    c = _GATHER_GRID
    g = (torch.arange(c, device=dev, dtype=torch.float32) + 0.5) / c
    u = torch.stack(torch.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)  # (C, 2)
    k = u.shape[0]
    s = spec.map_params(lambda t, kind: t if t.ndim <= kind else t.unsqueeze(1))  # (M, 1, ...)
    wo = views.to(dev, torch.float32)[:, None].expand(m, k, 3)
    wi, weight, _ = s.sample(wo, normals[:, None].expand(m, k, 3), u.expand(m, k, 2))
    lum = weight.sum(-1)  # (M, C)
    mean = torch.nn.functional.normalize((lum[..., None] * wi).sum(-2), dim=-1)  # (M, 3)
    gap = 0.5 * ((wi - mean[:, None]) ** 2).sum(-1)  # (M, C) 1 - cos, as half chords
    gap, order = gap.sort(-1)
    cum = torch.gather(lum, -1, order).cumsum(-1)
    at = (cum < 0.5 * cum[:, -1:]).sum(-1, keepdim=True).clamp(max=k - 1)
    med = torch.gather(gap, -1, at)[:, 0]  # (M,)
    lam = (math.log(2) / med.clamp_min(DIVISOR_F32)).clamp(*INDIRECT_LAM_RANGE)
    return torch.where(cum[:, -1] > 0, lam, torch.full_like(lam, math.inf))
