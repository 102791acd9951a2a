"""What the fit sees of a transport function: directions, quadrature weights, values.

Each (vertex, view) transport function is sampled on two sets that together form one quadrature
rule of the sphere (Green et al.'s "arbitrary bandwidth" needs the sharp part resolved):

local
    A cap grid (:func:`graded_cap`) around the glossy lobe, sized to it. The lobe's axis,
    extent and peak come from the material itself (:func:`lobe_estimate`): a stratified set of
    BRDF samples for the view gives the mean direction and the mean resultant length, hence a
    vMF sharpness that sizes the cap (four times wider in ``lam``, so the lobe and its tails
    lie inside), and the median offset, which sets the peak's scale. The rings are graded
    geometrically from the peak out to the cap's edge: a GGX lobe's peak is a tenth of the
    width its tails give the vMF, and rings equally spaced across the cap leave it between the
    first two, where they integrate such a lobe short of its light (docs/method.md compares the
    two).
    For the microfacet-type models the grid is laid over half vectors about their mean and
    mapped to light directions (:func:`half_vector_lobes`): towards grazing views such a lobe
    is a sliver in light directions, round in half vectors.
    global
    Cube-map texel directions outside that cap (weights set to 0 inside, where the local grid
    already integrates), for everything the lobe estimate does not predict: the indirect
    transport, light leaking around occluders.

So ``sum_s weight_s f(dir_s)`` approximates ``int f`` for any transport function, and the L2
data term of the fit is the same quadrature applied to the squared residual.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from .. import brdf
from ..geometry import cubemap, sphere
from ..lobes import sg
from ..transport import Transport

__all__ = [
    "FitData",
    "gather",
    "graded_cap",
    "half_vector_lobes",
    "lobe_estimate",
]


@dataclass(eq=False)
class FitData:
    """Samples of the glossy transport of B vertices x J views.

    Attributes
    ----------
    dirs : (B, J, S, 3) sample directions (global frame)
    weights : (B, J, S) quadrature solid angles (0 for unused samples)
    values : (B, J, S, 3) transport values (RGB); 0 where the weight is 0 (not evaluated
        there: no integral of the fit sees those samples)
    below : (B, J) bool, view below the vertex's horizon (transport 0, weight forced to 0)
    visibility : (cap (B, J, K) bool, global set (B, D) bool), whether each sample direction
        sees the environment, as :func:`gather` cast it (before :meth:`compact`), for a caller
        that samples the same directions again (:func:`gather`'s ``visibility``); None on
        other data
    """

    dirs: torch.Tensor
    weights: torch.Tensor
    values: torch.Tensor
    below: torch.Tensor
    _unit: torch.Tensor | None = field(default=None, init=False, repr=False)
    _energy: torch.Tensor | None = field(default=None, init=False, repr=False)
    _light: torch.Tensor | None = field(default=None, init=False, repr=False)
    visibility: tuple[torch.Tensor, torch.Tensor] | None = field(default=None, repr=False)

    @property
    def shape(self) -> tuple[int, int, int]:
        b, j, s, _ = self.dirs.shape
        return b, j, s

    def unit_dirs(self) -> torch.Tensor:
        """``dirs`` as float64 unit vectors (B, J, S, 3), formed once (the fit evaluates its
        Gaussians at them many times, :func:`lobelight.fit._objective.gaussians_at`)."""
        if self._unit is None:
            self._unit = torch.nn.functional.normalize(self.dirs.double(), dim=-1)
        return self._unit

    def energy(self) -> torch.Tensor:
        """``int |T|^2`` per vertex and view, summed over channels, (B, J); formed once (a
        chunk's fit asks for it at every start and solve)."""
        if self._energy is None:
            self._energy = (self.weights[..., None] * self.values**2).sum((-1, -2))
        return self._energy

    def light(self) -> torch.Tensor:
        """``int max(T, 0)`` per vertex, view and channel, (B, J, 3); formed once."""
        if self._light is None:
            self._light = (self.weights[..., None] * self.values.clamp_min(0)).sum(2)
        return self._light

    def compact(self) -> FitData:
        """The same quadrature without the samples of weight 0: each (vertex, view) keeps its
        samples of positive weight first, in their order, and all keep as many as the fullest
        one has (the rest, weight 0, pad). A sample of weight 0 adds nothing to any integral
        of the fit (data term, weights' normal equations, moments, energy), so every result
        is the same up to the order of summation, for less work: a broad lobe's cap covers most
        of the global set, whose samples there have weight 0. Where that would drop under a
        tenth of the samples (a sharp lobe's small cap) the data is returned as it is: the
        reordering would cost more than it saves.
        """
        keep = self.weights > 0  # (B, J, S)
        s_new = max(int(keep.sum(-1).amax()) if keep.numel() else 0, 1)
        if s_new > 0.9 * keep.shape[-1]:
            return self
        order = torch.argsort((~keep).to(torch.int8), dim=-1, stable=True)[..., :s_new]
        return FitData(
            dirs=torch.gather(self.dirs, 2, order[..., None].expand(-1, -1, -1, 3)),
            weights=torch.gather(self.weights, 2, order),
            values=torch.gather(self.values, 2, order[..., None].expand(-1, -1, -1, 3)),
            below=self.below,
        )


#: The samples of :func:`gather`: a cap grid of ``N_THETA x 2 N_THETA`` points per (vertex,
#: view) and the texels of a cube map of face resolution ``GLOBAL_RES`` per vertex.
N_THETA = 12
GLOBAL_RES = 8
CAP_SAMPLES = 2 * N_THETA**2
GLOBAL_SAMPLES = 6 * GLOBAL_RES**2


def half_vector_lobes(spec: brdf.BRDF | None) -> bool:
    """Whether ``spec``'s lobe is best resolved over half vectors ``h = normalise(w + v)``: the
    models whose lobe is a distribution of half vectors about the normal
    (:attr:`lobelight.brdf.BRDF.half_vector_lobe`; their local grid is laid out over half
    vectors, :func:`gather`).

    A microfacet lobe is round in ``h`` (the distribution ``D(h)`` about the normal) but not in
    the light direction ``w = 2 (v.h) h - v``: towards grazing views the map squeezes it across
    the plane of incidence by ``2 v.h``, into a sliver a fiftieth as wide as it is long at
    ``n.v = 0.02``, which rings around a light-direction axis miss or hit by chance (a sharp
    GGX lobe's grazing views then integrate to several times too little or too much light). The
    mirror-symmetric lobes
    (Phong, Lafortune) are round in ``w`` and squeezed in ``h``, so they keep the light
    directions.
    """
    return spec is not None and spec.half_vector_lobe


def lobe_estimate(
    tr: Transport, vidx: torch.Tensor, views: torch.Tensor, *, count: int = 8
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Axis, vMF sharpness and peak scale of each vertex's glossy lobe for each view, from BRDF
    samples: of the light directions, or of the half vectors for the models whose lobe is a
    distribution of half vectors (:func:`half_vector_lobes`).

    The sharpness is the vMF concentration of the samples' mean resultant length: it sees the
    whole lobe, tails included, and sizes the cap the lobe lives in. A long-tailed lobe (GGX)
    has a peak far narrower than that vMF (at alpha 0.1 a tenth of its width), so the peak
    scale is measured separately, robustly to the tails: half the weighted median of
    ``1 - axis.w`` over the samples (``ln 2 / (2 lam)`` for an exact vMF of sharpness ``lam``).

    Parameters
    ----------
    vidx : (B,);  views : (J, 3);  count : samples per axis of the stratified grid (count^2)

    Returns
    -------
    axis : (B, J, 3) (the mirror direction, or the normal for half vectors, where there is no
    lobe);  lam : (B, J) (0 where the material has no specular lobe);  scale : (B, J) peak scale
    in ``1 - cos`` (2 where there is no lobe)
    """
    dev = tr.device
    b, j = vidx.shape[0], views.shape[0]
    spec = tr.materials.specular
    n = tr.mesh.normals[vidx]
    if spec is None:
        axis = n[:, None].expand(b, j, 3).clone()
        return axis, torch.zeros(b, j, device=dev), torch.full((b, j), 2.0, device=dev)
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
    half = half_vector_lobes(spec)
    if half:
        d = torch.nn.functional.normalize(wi + wo, dim=-1)  # the samples' half vectors
        rest = n[:, None].expand(b, j, 3)
    else:
        d = wi
        rest = 2 * (views[None] * n[:, None]).sum(-1, keepdim=True) * n[:, None] - views[None]
    axis, lam, _ = sg.fit_from_samples(d, lum, ones)
    none = lum.sum(-1) <= 0
    axis = torch.where(none[..., None], rest, axis)
    # weighted median of 1 - axis.d: the first sorted sample at which half the weight is in
    gap = 0.5 * ((d - axis[:, :, None]) ** 2).sum(-1)  # (B, J, C)
    gap_s, order = gap.sort(-1)
    cum = torch.gather(lum, -1, order).cumsum(-1)
    half = (cum < 0.5 * cum[..., -1:]).sum(-1, keepdim=True).clamp(max=c - 1)
    med = torch.gather(gap_s, -1, half)[..., 0]
    # floor: a mirror-sharp lobe still gets a grid a float32 direction can resolve
    scale = torch.where(none, torch.full_like(med, 2.0), (0.5 * med).clamp(1e-6, 2.0))
    return axis, torch.where(none, torch.zeros_like(lam), lam), scale


def graded_cap(
    axis: torch.Tensor,
    scale: torch.Tensor,
    s_max: torch.Tensor,
    *,
    n_theta: int,
    n_phi: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Cap grid around ``axis`` graded from a peak of scale ``scale`` out to ``s_max``.

    Rings: Gauss-Legendre in ``u = ln(1 + s / scale)`` on ``[0, ln(1 + s_max / scale)]`` (``s =
    1 - cos`` from the axis, ``ds = (s + scale) du``). Equal steps in ``u`` are equal ratios of
    ``s`` beyond the peak, so a lobe is resolved from its peak through its tail whatever the
    ratio of the two, where rings equally spaced in ``s`` leave a GGX peak (or the peak of a
    lobe sized by its tails) between the first two. An SG of scale ``1 / lam`` becomes a smooth
    bump in ``u``, a power-law tail ``s^-2`` a decaying exponential, both integrated by
    Gauss-Legendre nearly exactly.

    Around each ring, ``n_phi`` equal steps in ``phi`` (midpoints). A ring the horizon cuts
    needs nothing more: the transport's ``max(n.w, 0)`` takes it to 0 continuously there, so
    extra points on the arcs either side of the cut leave the integrals as they are.

    Parameters
    ----------
    axis : (..., 3) unit centres;  scale, s_max : (...) in ``1 - cos`` (``s_max <= 2``)

    Returns
    -------
    dirs : (..., n_theta n_phi, 3);  weights : (..., n_theta n_phi) solid angles
    """
    dev = axis.device
    x, wx = sphere.gauss_legendre(n_theta)
    x, wx = x.to(dev), wx.to(dev)
    c = scale.double()[..., None]  # (..., 1)
    top = torch.log1p(s_max.double()[..., None] / c)
    u = 0.5 * (x + 1) * top  # (..., n_theta)
    s = c * torch.expm1(u)
    ws = 0.5 * wx * top * (s + c)  # (..., n_theta) ring weights in s
    sin_t = torch.sqrt((s * (2 - s)).clamp_min(0))
    # the rings' radii and heights are formed in float64 (``1 - s`` of a mirror-sharp lobe's
    # first ring is 1 - 1e-6), the points in the axis' dtype: each point is its local
    # coordinates times the frame (one batched product), whose rounding is that of the
    # returned directions
    dt = axis.dtype
    frame = torch.stack(sphere.frame(axis.double()), -2).to(dt)  # (..., 3, 3) rows t, b, axis
    phi = (torch.arange(n_phi, dtype=torch.float64, device=dev) + 0.5) * (2 * math.pi / n_phi)
    batch = axis.shape[:-1]
    m, p = n_theta * n_phi, math.prod(batch)
    radius = sin_t.to(dt)[..., None]  # (..., n_theta, 1)
    local = torch.stack(
        [
            radius * phi.cos().to(dt),
            radius * phi.sin().to(dt),
            (1 - s).to(dt)[..., None].expand(*batch, n_theta, n_phi),
        ],
        -1,
    ).reshape(p, m, 3)
    dirs = torch.bmm(local, frame.reshape(p, 3, 3))
    w = (ws * (2 * math.pi / n_phi)).to(dt)[..., None].expand(*batch, n_theta, n_phi)
    return dirs.reshape(*batch, m, 3), w.reshape(*batch, m)


def gather(
    tr: Transport,
    vidx: torch.Tensor,
    views: torch.Tensor,
    *,
    global_res: int = GLOBAL_RES,
    n_theta: int = N_THETA,
    indirect: torch.Tensor | None = None,
    indirect_res: int = 16,
    lobe: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None = None,
    visibility: tuple[torch.Tensor, torch.Tensor] | None = None,
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
    visibility : the samples' visibility (:attr:`FitData.visibility`) from an earlier gather
        of the same vertices, views and ``lobe``, if the caller kept it: no ray is cast

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
    axis, lam, scale = lobe_estimate(tr, vidx, views) if lobe is None else lobe
    # cap where the (4x wider) vMF of the whole lobe is above 1e-6 of its peak; very broad
    # lobes cover the sphere
    lam_cap = (lam / 4).clamp_min(1e-3)
    s_max = (math.log(1e6) / lam_cap).clamp(max=2.0)
    # rings graded from the peak's scale out to the cap's edge
    half = half_vector_lobes(tr.materials.specular)
    v = views[None].expand(b, j, 3)
    ldirs, lw = graded_cap(
        axis,
        scale.minimum(s_max),
        s_max,
        n_theta=n_theta,
        n_phi=2 * n_theta,
    )
    if half:
        # the cap's points are half vectors: their light directions w = 2 (v.h) h - v, and
        # d w = 4 (v.h) d h (half vectors facing away from v reflect onto light directions
        # that others already cover: weight 0)
        vh = (ldirs * v[:, :, None]).sum(-1, keepdim=True)  # (B, J, K, 1)
        ldirs = torch.nn.functional.normalize(2 * vh * ldirs - v[:, :, None], dim=-1)
        lw = lw * 4 * vh[..., 0].clamp_min(0)
    gd = cubemap.texel_directions(global_res, device=dev).reshape(-1, 3)  # (D, 3)
    if visibility is None:
        # the cap's rays of the views above the horizon (the others' transport is 0), as
        # Transport.direct would cast them, and the global set's, shared by all views
        vis_cap = torch.zeros(ldirs.shape[:-1], dtype=torch.bool, device=dev)
        bi, ji = (~below).nonzero(as_tuple=True)
        vis_cap[bi, ji] = tr.visibility(vidx[bi], ldirs[bi, ji])
        visibility = (vis_cap, tr.visibility(vidx, gd))
    lvals = tr.direct(vidx, views, ldirs, visibility=visibility[0])  # (B, J, K, 3)
    gom = cubemap.texel_solid_angles(global_res, device=dev).reshape(-1)
    # the global set leaves out the directions the cap covers (in its own domain): weight 0,
    # and the transport is not evaluated there
    gcap = gd[None, None] + v[:, :, None] if half else gd[None, None].expand(b, j, -1, 3)
    gcap = torch.nn.functional.normalize(gcap, dim=-1)  # (B, J, D, 3)
    inside = (axis[:, :, None] * gcap).sum(-1) > (1 - s_max)[..., None]  # (B, J, D)
    gw = torch.where(inside, torch.zeros_like(inside, dtype=gom.dtype), gom.expand(b, j, -1))
    gvals = tr.direct(vidx, views, gd, need=~inside, visibility=visibility[1])  # (B, J, D, 3)
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
        # (the direct transport is 0 below the horizon already)
        values = torch.where(below[..., None, None], torch.zeros_like(values), values)
    return FitData(dirs=dirs, weights=weights, values=values, below=below, visibility=visibility)
