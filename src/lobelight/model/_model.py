"""The fitted model: per vertex and view, the Gaussians of glossy transport and the SH diffuse
transfer, with the mesh, materials and provenance; saved and loaded in the file format of
:mod:`lobelight.model._format`."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import torch

from ..brdf import sharp_lobe
from ..errors import InputError
from ..geometry import sphere
from ..lobes import sg
from ..lobes.sg import Gaussians
from ..scene import AlbedoTexture, Materials, Mesh
from ._blend import blend_lobes, horizon_scale
from ._format import read, write
from ._stored import HitTexels
from ._visibility import hit_tiles, visibility_tiles

__all__ = ["ALBEDO_MIN", "Model", "load", "per_unit_albedo", "save"]

#: A vertex albedo below this (per channel) holds no transfer to divide out: its transfer per
#: unit albedo is taken as zero (the light it reflects is zero either way).
ALBEDO_MIN = 1e-6


def per_unit_albedo(transfer: torch.Tensor, albedo: torch.Tensor) -> torch.Tensor:
    """Diffuse transfer per unit albedo of the receiving vertex: ``transfer / albedo`` per
    channel (0 where the albedo is below :data:`ALBEDO_MIN`).

    The diffuse transfer a bake computes is the receiver's albedo over pi times what reaches it
    (directly, and bounced off the rest of the object), so the division is exact.

    Parameters
    ----------
    transfer : (V, n, 3);  albedo : (V, 3) the albedo it was computed with

    Returns
    -------
    (V, n, 3)
    """
    a = albedo.to(transfer)[:, None, :]
    return torch.where(a >= ALBEDO_MIN, transfer / a.clamp_min(ALBEDO_MIN), 0.0)


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
        the object; left out, an object under a map with a sun renders too dark)
    indirect_gaussians : how many of the last Gaussians per view hold indirect glossy transport
        (light reflected off the object itself before it reaches the vertex's glossy lobe).
        A renderer that shades the sun's glossy light per pixel, with the other lobes seeing
        the map without it, lets the sun light these (render/_sun_glossy.py):
        a mirror shows the sun's reflection in another mirror
    albedo : optional diffuse albedo per pixel (:class:`lobelight.scene.AlbedoTexture`, a glTF
        asset's base colour textures). With it ``diffuse`` and ``bounce`` hold the transfer
        per unit albedo of the receiving vertex (:func:`per_unit_albedo`), and a renderer
        multiplies the interpolated diffuse light by the albedo read at the pixel: exact for
        direct light, while the light bounced off the object keeps each sender's per-vertex
        albedo (``materials.diffuse``, the texture averaged over its one-ring)
    """

    mesh: Mesh
    views: torch.Tensor
    gaussians: Gaussians
    diffuse: torch.Tensor
    materials: Materials
    provenance: dict[str, Any] = field(default_factory=dict)
    bounce: torch.Tensor | None = None
    indirect_gaussians: int = 0
    albedo: AlbedoTexture | None = None
    _visibility: torch.Tensor | None = field(default=None, init=False, repr=False)
    _hits: tuple[torch.Tensor, torch.Tensor] | None = field(default=None, init=False, repr=False)
    # the hit tiles as a file holds them (the texels that hit); _hits, once made, is the same
    _hit_texels: HitTexels | None = field(default=None, init=False, repr=False)

    def __post_init__(self):
        n = int(self.gaussians.shape[-1])
        if not 0 <= self.indirect_gaussians < n:
            raise InputError(
                "indirect_gaussians", f"must be in 0..{n - 1}, got {self.indirect_gaussians}"
            )
        if self.albedo is not None and self.albedo.n_vertices != self.mesh.n_vertices:
            raise InputError(
                "albedo", f"{self.albedo.n_vertices} entries for {self.mesh.n_vertices} vertices"
            )

    @property
    def n_gaussians(self) -> int:
        """Gaussians per view, direct and indirect."""
        return int(self.gaussians.shape[-1])

    @property
    def direct_gaussians(self) -> int:
        """Gaussians per view fitted to the direct glossy transport."""
        return self.n_gaussians - self.indirect_gaussians

    @property
    def sh_order(self) -> int:
        """Order of the SH diffuse transfer (``order**2`` coefficients per vertex)."""
        return round(self.diffuse.shape[1] ** 0.5)

    @property
    def device(self) -> torch.device:
        return self.gaussians.device

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

    @property
    def visibility_held(self) -> torch.Tensor | None:
        """The visibility tiles if the model holds them (read from its file, or computed by
        :meth:`visibility`), else None; computes nothing."""
        return self._visibility

    def visibility(self) -> torch.Tensor:
        """Each vertex's visibility of the environment on an octahedral tile, ``(V, R, R)``
        uint8 (:func:`lobelight.model.visibility_tiles`), computed from the mesh on first use
        and kept."""
        if self._visibility is None:
            self._visibility = visibility_tiles(self.mesh)
        return self._visibility

    @property
    def hits_held(self) -> tuple[torch.Tensor, torch.Tensor] | None:
        """The hit tiles (:meth:`hits`) if the model holds them (read from its file, or
        computed by :meth:`hits`), else None; casts no ray."""
        return None if self._hits is None and self._hit_texels is None else self.hits()

    def hits(self) -> tuple[torch.Tensor, torch.Tensor]:
        """What each vertex sees of the object along its tile's texel centres: ``face (V, R, R)``
        int32 (-1: none) and ``distance (V, R, R)`` float16 (:func:`lobelight.model.hit_tiles`,
        at the visibility tiles' resolution): made whole from the file's texels that hit, or
        computed from the mesh, on first use, and kept."""
        if self._hits is None:
            if self._hit_texels is not None:  # on the CPU as read: placed on the model's device
                face, dist = self._hit_texels.tiles()
                self._hits = (face.to(self.device), dist.to(self.device))
            else:
                self._hits = hit_tiles(self.mesh, res=int(self.visibility().shape[-1]))
        return self._hits

    def hit_texels(self) -> HitTexels:
        """The hit tiles (:meth:`hits`) as their texels that hit: as the file holds them, without
        making the tiles whole, or taken from :meth:`hits`."""
        if self._hit_texels is not None:
            return self._hit_texels
        return HitTexels.of_tiles(*self.hits())

    def sees_itself(self) -> bool:
        """Whether any vertex's hit tile (:meth:`hits`) finds the object; where none does, the
        renderers and the web page compile the shading of the hits out."""
        if self._hit_texels is not None:
            return self._hit_texels.found()
        return bool((self.hits()[0] >= 0).any())

    def to(self, device) -> Model:
        """The model with every tensor on ``device`` (in place; returns it)."""
        self.mesh = self.mesh.to(device)
        self.views = self.views.to(device)
        self.gaussians = self.gaussians.to(device)
        self.diffuse = self.diffuse.to(device)
        self.materials = self.materials.to(device)
        if self.bounce is not None:
            self.bounce = self.bounce.to(device)
        if self.albedo is not None:
            self.albedo = self.albedo.to(device)
        if self._visibility is not None:
            self._visibility = self._visibility.to(device)
        if self._hits is not None:
            self._hits = (self._hits[0].to(device), self._hits[1].to(device))
        return self

    def save(self, path, *, float16: bool = False, drop: bool = True) -> dict[str, Any]:
        """Write the model to ``path`` (see :func:`save`); returns sizes. A material whose BRDF
        the renderers evaluate per pixel (:attr:`lobelight.brdf.BRDF.sun_model`) has its
        visibility tiles (:meth:`visibility`) written too, and one whose lobe they shade per
        pixel (:func:`lobelight.brdf.sharp_lobe`) its hit tiles (:meth:`hits`), so that no
        renderer computes them again: a sharp lobe reads both per pixel, a rough one's direct
        Gaussians are corrected per vertex with the visibility tiles
        (``lobelight.render._lobe_visibility``)."""
        spec = self.materials.specular
        if spec is not None and spec.sun_model is not None:
            self.visibility()
        if sharp_lobe(spec) is not None and self._hit_texels is None:
            self.hits()
        return write(
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
            visibility=self._visibility,
            hits=self._hits if self._hit_texels is None else self._hit_texels,
            albedo=self.albedo,
        )


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
    return write(
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


def load(path, *, device=None) -> Model:
    """Read and check a model file (:func:`lobelight.model._format.read`).

    Raises
    ------
    InputError
        naming the file: missing, not a model file, unknown version, missing or malformed
        arrays, non-finite values, inconsistent shapes.
    """
    fields = read(path)
    visibility = fields.pop("visibility")
    hits = fields.pop("hits")
    model = Model(**fields)
    model._visibility = visibility
    if isinstance(hits, HitTexels):
        model._hit_texels = hits
    else:
        model._hits = hits
    return model.to(device) if device is not None else model
