"""Blending a vertex's Gaussians between stored views, as every renderer does per pixel.

A view direction between stored views blends the records of the geodesic triangle it falls in
(:func:`lobelight.geometry.sphere.locate_views`) with its barycentric weights:
:func:`blend_lobes` blends carried light, means and widths; :func:`horizon_scale` keeps a view
just above the horizon from blending in the dark records below it.
"""

from __future__ import annotations

import torch

__all__ = ["LIVE_FLOOR", "MIN_SAY", "blend_lobes", "horizon_scale"]

#: Carried light below which a record is dead: it has no say in a blended lobe's shape. Far
#: below the light any fitted lobe carries, and above float32's smallest normal number, so a
#: record of underflowed weights counts as dead.
LIVE_FLOOR = 1e-30
#: A blended lobe whose live records have less barycentric weight than this carries no light.
MIN_SAY = 1e-6


def blend_lobes(e, mu, sigma, b, *, frame=None):
    """Blend corresponding Gaussians of three records (views of a vertex, or vertices of a
    triangle) with barycentric weights ``b``.

    The light a lobe carries, ``e = w * integral(lam)`` (RGB), blends linearly; its width and
    mean blend linearly (the mean then renormalised) over the *live* records, those carrying
    light (mean of ``e`` over colour at least ``LIVE_FLOOR``), with their barycentric weights
    renormalised.

    Why not blend peak weights and widths independently, the paper's literal wording: where a
    slot is a sharp lobe in one record and a broad or dead one in the next, the sharp lobe's
    peak weight (thousands) is spread over the blended width and the light grows by the ratio
    of the integrals, which makes images several times too bright (docs/method.md). Blending
    the carried light conserves it exactly. Why not weight the shape by the light too: that
    pins a highlight to the brighter record's mean instead of letting it travel across the
    triangle as the means do, the point of the paper's nonlinear interpolation, and renders
    worse than this rule. Dead records are left out because their means and widths are never
    fitted to anything (the M and V fill may be poor). The shader does the same, per vertex
    explicitly and per pixel with varyings premultiplied by the live flag.

    ``frame = (base, target)`` blends the means as offsets from per-record directions ``base``
    and adds them to ``target`` before normalising. The renderer passes each triangle corner's
    mirror direction (its view reflected about its normal) and the point's own, computed from
    its interpolated normal and view: a mirror-like lobe then follows the reflection per pixel
    as Phong shading does, instead of a blend of corner directions that differ by tens of
    degrees across a coarse mesh's triangles (docs/method.md measures the gain). At a corner
    (``b`` a unit vector) the corner's own mean comes back exactly.

    Parameters
    ----------
    e : (..., 3, N, C) light carried (>= 0);  mu : (..., 3, N, 3) unit;  sigma : (..., 3, N)
    b : (..., 3) barycentric weights;  frame : optional (base (..., 3, 3), target (..., 3))

    Returns
    -------
    e : (..., N, C), zero where the live records' weight is below ``MIN_SAY`` (then at most
    ``MIN_SAY`` of the largest record's light is dropped);  mu : (..., N, 3) unit (``+z`` for a
    lobe without light);  sigma : (..., N) (1 for a lobe without light)
    """
    bn = b[..., None]  # (..., 3, 1)
    live = e.mean(-1) >= LIVE_FLOOR  # (..., 3, N)
    a = torch.where(live, bn, torch.zeros_like(bn))
    s = a.sum(-2)  # (..., N)
    ok = s >= MIN_SAY
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
    ok = ((view_dirs * n).sum(-1) > 0) & (say >= MIN_SAY)
    return torch.where(ok, 1.0 / torch.where(ok, say, torch.ones_like(say)), torch.ones_like(say))
