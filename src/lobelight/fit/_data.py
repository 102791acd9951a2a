"""What the fit sees of a transport function: directions, quadrature weights, values.

Each (vertex, view) transport function is sampled on two sets that together form one quadrature
rule of the sphere (Green et al.'s "arbitrary bandwidth" needs the sharp part resolved):

local
    A cap grid (:func:`lobelight.sphere.local_grid`) around the glossy lobe, sized to it. The
    lobe's axis and width come from the material itself: a stratified set of BRDF samples for
    the view gives the mean direction and the mean resultant length, hence a vMF sharpness. The
    cap is taken four times wider in ``lam`` than the estimate, so the lobe and its shoulders
    lie inside.
global
    Cube-map texel directions outside that cap (weights set to 0 inside, where the local grid
    already integrates), for everything the lobe estimate does not predict: the indirect
    transport, light leaking around occluders.

So ``sum_s weight_s f(dir_s)`` approximates ``int f`` for any transport function, and the L2
data term of the fit is the same quadrature applied to the squared residual.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from .. import cubemap, sg, sphere
from ..transport import Transport

__all__ = ["FitData", "gather"]


@dataclass(eq=False)
class FitData:
    """Samples of the glossy transport of B vertices x J views.

    Attributes
    ----------
    dirs : (B, J, S, 3) sample directions (global frame)
    weights : (B, J, S) quadrature solid angles (0 for unused samples)
    values : (B, J, S, 3) transport values (RGB)
    below : (B, J) bool, view below the vertex's horizon (transport 0, weight forced to 0)
    """

    dirs: torch.Tensor
    weights: torch.Tensor
    values: torch.Tensor
    below: torch.Tensor

    @property
    def shape(self) -> tuple[int, int, int]:
        b, j, s, _ = self.dirs.shape
        return b, j, s

    def energy(self) -> torch.Tensor:
        """``int |T|^2`` per vertex and view, summed over channels, (B, J)."""
        return (self.weights[..., None] * self.values**2).sum((-1, -2))


def lobe_estimate(
    tr: Transport, vidx: torch.Tensor, views: torch.Tensor, *, count: int = 8
) -> tuple[torch.Tensor, torch.Tensor]:
    """Axis and vMF sharpness of each vertex's glossy lobe for each view, from BRDF samples.

    Parameters
    ----------
    vidx : (B,);  views : (J, 3);  count : samples per axis of the stratified grid (count^2)

    Returns
    -------
    axis : (B, J, 3);  lam : (B, J) (0 where the material has no specular lobe)
    """
    dev = tr.device
    b, j = vidx.shape[0], views.shape[0]
    spec = tr.materials.specular
    n = tr.mesh.normals[vidx]
    if spec is None:
        return n[:, None].expand(b, j, 3).clone(), torch.zeros(b, j, device=dev)
    g = (torch.arange(count, device=dev, dtype=torch.float32) + 0.5) / count
    u = torch.stack(torch.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)  # (C, 2)
    c = u.shape[0]
    s = spec.take(vidx).map_params(
        lambda t, k: t if t.ndim <= k else t.reshape(b, 1, 1, *t.shape[1:])
    )
    wo = views[None, :, None].expand(b, j, c, 3)
    nn = n[:, None, None].expand(b, j, c, 3)
    wi, weight, _ = s.sample(wo, nn, u.expand(b, j, c, 2))
    lum = weight.sum(-1)  # (B, J, C)
    ones = torch.ones_like(lum)
    axis, lam, _ = sg.fit_from_samples(wi, lum, ones)
    refl = 2 * (views[None] * n[:, None]).sum(-1, keepdim=True) * n[:, None] - views[None]
    none = lum.sum(-1) <= 0
    axis = torch.where(none[..., None], refl, axis)
    return axis, torch.where(none, torch.zeros_like(lam), lam)


def gather(
    tr: Transport,
    vidx: torch.Tensor,
    views: torch.Tensor,
    *,
    global_res: int = 8,
    n_theta: int = 12,
    indirect: torch.Tensor | None = None,
    indirect_res: int = 16,
    lobe: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> FitData:
    """Sample the glossy transport of vertices for views where the fit needs it.

    Parameters
    ----------
    tr : Transport;  vidx : (B,);  views : (J, 3)
    global_res : cube-map resolution of the global set
    n_theta : local cap grid size (``n_theta x 2 n_theta`` points)
    indirect : optional (B, J, 6 indirect_res^2, 3) indirect glossy density (from
        :meth:`Transport.indirect`), added at every sample by nearest bin
    lobe : :func:`lobe_estimate` of these vertices and views, if the caller has it

    Returns
    -------
    FitData with ``S = 2 n_theta^2 + 6 global_res^2``
    """
    dev = tr.device
    vidx = vidx.to(dev)
    views = views.to(dev, torch.float32)
    b, j = vidx.shape[0], views.shape[0]
    n = tr.mesh.normals[vidx]
    below = (views[None] * n[:, None]).sum(-1) <= 0  # (B, J)
    axis, lam = lobe_estimate(tr, vidx, views) if lobe is None else lobe
    # cap where the (4x wider) lobe is above 1e-6 of its peak; very broad lobes cover the sphere
    lam_cap = (lam / 4).clamp_min(1e-3)
    ldirs, lw = sphere.local_grid(axis, lam_cap, n_theta=n_theta)  # (B, J, K, 3), (B, J, K)
    ldirs, lw = ldirs.to(torch.float32), lw.to(torch.float32)
    lvals = tr.direct(vidx, views, ldirs)  # (B, J, K, 3)
    gd = cubemap.texel_directions(global_res, device=dev).reshape(-1, 3)  # (D, 3)
    gom = cubemap.texel_solid_angles(global_res, device=dev).reshape(-1)
    gvals = tr.direct(vidx, views, gd)  # (B, J, D, 3)
    cap_cos = torch.cos(sphere.lobe_cap_angle(lam_cap))  # (B, J)
    inside = (axis[:, :, None] * gd[None, None]).sum(-1) > cap_cos[..., None]  # (B, J, D)
    gw = torch.where(inside, torch.zeros_like(inside, dtype=gom.dtype), gom.expand(b, j, -1))
    dirs = torch.cat([ldirs, gd.expand(b, j, -1, 3)], 2)
    weights = torch.cat([lw, gw], 2)
    values = torch.cat([lvals, gvals], 2)
    if indirect is not None:
        r = indirect_res
        f, u, v = cubemap.direction_to_face_uv(dirs)
        col = ((u + 1) * r / 2).floor().long().clamp(0, r - 1)
        row = ((v + 1) * r / 2).floor().long().clamp(0, r - 1)
        idx = (f * r + row) * r + col  # (B, J, S)
        values = values + torch.gather(indirect.to(dev), 2, idx[..., None].expand(-1, -1, -1, 3))
    values = torch.where(below[..., None, None], torch.zeros_like(values), values)
    return FitData(dirs=dirs, weights=weights, values=values, below=below)
