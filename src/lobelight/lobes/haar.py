"""Haar wavelets on cube maps: the non-linear approximation baseline of Ng, Ramamoorthi and
Hanrahan (2003), "All-frequency shadows using non-linear wavelet lighting approximation".

Transform
---------
Each face of a ``(6, R, R, C)`` cube map (docs/conventions.md layout, ``R`` a power of two) gets the
orthonormal 2D *nonstandard* Haar decomposition, channels independently. One level maps every
2 x 2 block ``[[p00, p01], [p10, p11]]`` (rows ``i``, columns ``j``) to::

    a  = (p00 + p01 + p10 + p11) / 2     scaling (average x 2)
    dh = (p00 - p01 + p10 - p11) / 2     detail across columns (a vertical edge)
    dv = (p00 + p01 - p10 - p11) / 2     detail across rows (a horizontal edge)
    dd = (p00 - p01 - p10 + p11) / 2     diagonal detail

(a 4 x 4 Hadamard matrix over 2: orthogonal and its own inverse), and the next level repeats on the
``a`` image. Coefficient layout, per face, in the usual quadrant form: after the level that halves
size ``s`` to ``h = s/2``::

    [:h, :h] -> next levels (finally the scaling coefficient at [0, 0] = face sum / R)
    [:h, h:s] -> dh      [h:s, :h] -> dv      [h:s, h:s] -> dd

so ``coeffs[f, 0, 0]`` is face ``f``'s scaling coefficient, ``[f, 0, 1]``, ``[f, 1, 0]``,
``[f, 1, 1]`` its coarsest details, and the bottom-right ``R/2 x R/2`` quadrant the finest diagonal
details. Because the transform is orthonormal, sums of squares are preserved (Parseval) and
dropping coefficients costs exactly their energy in the texel-space L2 norm.

Texel space, not solid angle
----------------------------
This is plain orthonormal Haar on texels: every texel counts the same. Ng et al. also describe
*area-weighted* selection (weighting coefficients by the solid angle of their support); we do not,
so the L2 norm here is the texel norm, not the spherical one. Texel solid angles on a cube map vary
by ``3 sqrt(3) ~ 5.2`` from face centre to corner, so squared errors weighted by solid angle and
unweighted ones differ by at most that factor (after the overall scale ``4 pi / (6 R^2)``).

Selection
---------
:func:`truncate` keeps the ``k`` largest coefficients over the whole cube map (all six faces, all
levels, scaling coefficients included — nothing is kept by default). With several channels the
ranking is shared, so the same ``k`` positions are kept in every channel, as in Ng 2003, by the
Euclidean norm over channels (``by="norm"``, which minimises the L2 error among shared-position
choices) or by the magnitude of the Rec. 709 luminance of the coefficient (``by="luminance"``);
``by="per_channel"`` keeps ``k`` positions per channel instead.

Loops run over the ``log2 R`` levels only; each level is whole-array reshapes.
"""

from __future__ import annotations

import operator

import torch

from .._backend import as_tensor, dispatch
from .._checks import check_cube
from ..errors import InputError

__all__ = ["approximate", "forward", "inverse", "truncate"]

# Rec. 709 / sRGB luminance weights for by="luminance" on RGB.
_LUMA = (0.2126, 0.7152, 0.0722)


def _forward(x: torch.Tensor) -> torch.Tensor:
    """Nonstandard Haar of (..., R, R, C) images, rows at -3 and columns at -2."""
    res = x.shape[-3]
    lead, ch = x.shape[:-3], x.shape[-1]
    a = x
    details = []  # finest first: (dh, dv, dd) each (..., h, h, C)
    s = res
    while s > 1:
        h = s // 2
        b = a.reshape(*lead, h, 2, h, 2, ch)  # (..., row block, row in block, col block, col, C)
        p00, p01 = b[..., :, 0, :, 0, :], b[..., :, 0, :, 1, :]
        p10, p11 = b[..., :, 1, :, 0, :], b[..., :, 1, :, 1, :]
        top_sum, top_dif = p00 + p01, p00 - p01
        bot_sum, bot_dif = p10 + p11, p10 - p11
        a = (top_sum + bot_sum) / 2
        details.append(((top_dif + bot_dif) / 2, (top_sum - bot_sum) / 2, (top_dif - bot_dif) / 2))
        s = h
    out = a  # (..., 1, 1, C)
    for dh, dv, dd in reversed(details):
        # quadrant layout: [[LL, dh], [dv, dd]]
        out = torch.cat([torch.cat([out, dh], -2), torch.cat([dv, dd], -2)], -3)
    return out


def _inverse(c: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`_forward` on (..., R, R, C)."""
    res = c.shape[-3]
    lead, ch = c.shape[:-3], c.shape[-1]
    a = c[..., :1, :1, :]
    s = 1
    while s < res:
        dh = c[..., :s, s : 2 * s, :]
        dv = c[..., s : 2 * s, :s, :]
        dd = c[..., s : 2 * s, s : 2 * s, :]
        # the level matrix is symmetric and orthogonal, so it is its own inverse
        p00 = (a + dh + dv + dd) / 2
        p01 = (a - dh + dv - dd) / 2
        p10 = (a + dh - dv - dd) / 2
        p11 = (a - dh - dv + dd) / 2
        top = torch.stack([p00, p01], -2)  # (..., s, s, 2, C) column pairs
        bot = torch.stack([p10, p11], -2)
        a = torch.stack([top, bot], -4)  # (..., s, 2, s, 2, C)
        s *= 2
        a = a.reshape(*lead, s, s, ch)
    return a


@dispatch
def forward(cube):
    """Orthonormal nonstandard 2D Haar transform of every face.

    Parameters
    ----------
    cube : (6, R, R, C) cube map, R a power of two

    Returns
    -------
    (6, R, R, C) coefficients in the quadrant layout of the module docstring; dtype and device
    of ``cube``.
    """
    cube = as_tensor(cube)
    check_cube(cube, power_of_two=True)
    return _forward(cube)


@dispatch
def inverse(coeffs):
    """Cube map from Haar coefficients (inverse of :func:`forward`).

    Parameters
    ----------
    coeffs : (6, R, R, C)

    Returns
    -------
    (6, R, R, C), dtype and device of ``coeffs``.
    """
    coeffs = as_tensor(coeffs)
    check_cube(coeffs, "coeffs", power_of_two=True)
    return _inverse(coeffs)


def _keep_top(score: torch.Tensor, k: int) -> torch.Tensor:
    """Boolean mask of the ``k`` largest entries over all but the last axis: (..., X) -> same."""
    flat = score.reshape(-1, score.shape[-1])  # (P, X) positions x independent rankings
    mask = torch.zeros_like(flat, dtype=torch.bool)
    if k > 0:
        idx = torch.topk(flat, k, dim=0).indices  # (k, X), exactly k even with ties
        mask.scatter_(0, idx, True)
    return mask.reshape(score.shape)


@dispatch
def truncate(coeffs, k, *, by="norm"):
    """Keep the ``k`` largest Haar coefficients of a cube map, zero the rest.

    Parameters
    ----------
    coeffs : (6, R, R, C) Haar coefficients (from :func:`forward`)
    k : int in [0, 6 R R], coefficient positions kept over the whole cube map
    by : how positions are ranked (see the module docstring)
        ``"norm"``: Euclidean norm over channels, the same k positions in every channel;
        ``"luminance"``: ``|Rec. 709 luminance|`` (C = 3; for C = 1 the magnitude), shared
        positions;
        ``"per_channel"``: each channel keeps its own k largest magnitudes.

    Returns
    -------
    (6, R, R, C) with exactly k kept positions per channel (a kept coefficient may itself be 0);
    dtype and device of ``coeffs``.
    """
    coeffs = as_tensor(coeffs)
    res = check_cube(coeffs, "coeffs", power_of_two=True)
    total = 6 * res * res
    try:
        kk = None if isinstance(k, bool) else operator.index(k)  # ints and numpy integers
    except TypeError:
        kk = None
    if kk is None or not 0 <= kk <= total:
        raise InputError("k", f"must be an integer in [0, {total}], got {k!r}")
    k = kk
    ch = coeffs.shape[-1]
    if by == "norm":
        score = torch.linalg.vector_norm(coeffs, dim=-1, keepdim=True)  # (6, R, R, 1)
    elif by == "luminance":
        if ch == 1:
            score = coeffs.abs()
        elif ch == 3:
            w = torch.tensor(_LUMA, dtype=coeffs.dtype, device=coeffs.device)
            score = (coeffs @ w).abs().unsqueeze(-1)  # (6, R, R, 1)
        else:
            raise InputError("by", f"'luminance' needs 1 or 3 channels, got {ch}")
    elif by == "per_channel":
        score = coeffs.abs()  # (6, R, R, C)
    else:
        raise InputError("by", f"must be 'norm', 'luminance' or 'per_channel', got {by!r}")
    mask = _keep_top(score.reshape(total, score.shape[-1]), k)  # (6 R R, 1 or C)
    return coeffs * mask.reshape(score.shape).to(coeffs.dtype)


@dispatch
def approximate(cube, k, *, by="norm"):
    """Non-linear Haar approximation: ``inverse(truncate(forward(cube), k, by=by))``.

    Parameters
    ----------
    cube : (6, R, R, C), R a power of two
    k : int, coefficient positions kept over the whole cube map
    by : ranking, see :func:`truncate`

    Returns
    -------
    (6, R, R, C), dtype and device of ``cube``.
    """
    return inverse(truncate(forward(cube), k, by=by))
