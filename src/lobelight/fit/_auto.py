"""How many Gaussians per view a material's glossy transport needs: the rule of
``fit_model(n_gaussians="auto")``, the default.

A second Gaussian per view helps where one Gaussian cannot take the lobe's shape and the lobe's
light is a large share of what the surface reflects (``docs/results.md``): GGX metals of
moderate roughness, whose long tails reach parts of the map the peak does not (α 0.25: Spot
29.3 → 33.9 dB, Suzanne 30.0 → 32.4 dB; a GGX α 0.12 sphere 17.2 → 20.7 dB). It does not help
a sharp metal (α 0.03-0.04: 24.0 → 24.2 dB for a bake 4.4 times as long), whose error is the
reflection's placement between vertices, nor a plastic (specular 0.04, 35-40 dB with one),
whose glossy light is a small share, nor a round lobe that one Gaussian fits (the Phong knot
scores 0.6 dB lower with two). A diffuse material has no glossy lobe to fit.

The rule reads the material's specular BRDF only, through importance samples of its lobe for
a view along the normal (any model, measured alike):

- its **width**, as the equivalent GGX ``alpha``: ``tan(theta / 2)`` of the light-weighted
  median angle ``theta`` between the sampled light directions and the mirror direction (exact
  for GGX, whose half vectors have median ``tan theta_h = alpha``; a Phong exponent ``e`` comes
  out near ``0.59 / sqrt(e)``, a Gaussian of ``sigma = 1 / sqrt(e)`` whose median angle is
  ``sigma sqrt(2 ln 2)``);
- its **tail**: the ratio of the 90th to the 50th percentile of that angle, 1.82 for a round
  (von Mises-Fisher, Phong) lobe, 2.3-3.8 for GGX up to α 0.25;
- its **share**: the specular albedo against specular plus diffuse albedo (luminance).

Two Gaussians where the width is at least :data:`AUTO_MIN_ALPHA` (between the sharp metals
it does not help and the α 0.12 it does), the tail at least :data:`AUTO_MIN_TAIL` and the share
at least :data:`AUTO_MIN_SHARE`; one otherwise. A mesh whose vertices differ (per-vertex
parameters) takes the choice of the majority of its glossy vertices, measured on at most
:data:`AUTO_SAMPLE_VERTICES` of them spread evenly over the vertex order.
"""

from __future__ import annotations

import math

import torch

from ..scene import Materials

__all__ = [
    "AUTO_MIN_ALPHA",
    "AUTO_MIN_SHARE",
    "AUTO_MIN_TAIL",
    "AUTO_SAMPLE_VERTICES",
    "choose_gaussians",
    "lobe_shape",
]

#: Narrowest lobe, as equivalent GGX alpha, given two Gaussians by the rule.
AUTO_MIN_ALPHA = 0.08
#: Smallest tail ratio (90th / 50th percentile angle) given two: above a round lobe's 1.82.
AUTO_MIN_TAIL = 2.0
#: Smallest share of the reflected light in the glossy lobe given two.
AUTO_MIN_SHARE = 0.5
#: Vertices of a per-vertex material the rule measures (evenly spread).
AUTO_SAMPLE_VERTICES = 256
# Stratified samples per axis of the lobe's measurement (its percentiles to about 1/count^2).
_COUNT = 32


def lobe_shape(materials: Materials, vidx: torch.Tensor) -> dict[str, torch.Tensor]:
    """The rule's measurements of the specular lobe of vertices ``vidx`` (B,), each (B,):
    ``alpha`` (equivalent GGX alpha), ``tail`` (90th / 50th percentile angle), ``share``
    (specular albedo / (specular + diffuse albedo)), ``albedo`` (specular albedo); all 0 for
    a material without a specular lobe. Measured for a view along the normal."""
    b = vidx.shape[0]
    dev = materials.diffuse.device
    zero = torch.zeros(b, device=dev)
    diffuse = materials.diffuse[vidx.to(dev)].mean(-1)  # (B,) luminance, as the mean of RGB
    spec = materials.specular
    if spec is None:
        return {"alpha": zero, "tail": zero, "share": zero, "albedo": zero}
    g = (torch.arange(_COUNT, device=dev, dtype=torch.float32) + 0.5) / _COUNT
    u = torch.stack(torch.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)  # (C, 2)
    c = u.shape[0]
    s = spec.take(vidx.to(dev)).map_params(
        lambda t, k: t if t.ndim <= k else t.reshape(b, 1, *t.shape[1:])
    )
    n = torch.tensor([0.0, 0.0, 1.0], device=dev).expand(b, c, 3)
    wi, weight, _ = s.sample(n, n, u.expand(b, c, 2))  # the view along the normal
    lum = weight.mean(-1).clamp_min(0)  # (B, C)
    albedo = lum.mean(-1)  # (B,) the sample mean of f cos / pdf
    angle = torch.acos(wi[..., 2].clamp(-1, 1))  # (B, C) from the mirror direction (n)
    ang_s, order = angle.sort(-1)
    cum = torch.gather(lum, -1, order).cumsum(-1)
    total = cum[..., -1:].clamp_min(1e-30)

    def percentile(q: float) -> torch.Tensor:
        k = (cum < q * total).sum(-1, keepdim=True).clamp(max=c - 1)
        return torch.gather(ang_s, -1, k)[..., 0]

    med, p90 = percentile(0.5), percentile(0.9)
    alpha = torch.tan(med / 2)
    tail = p90 / med.clamp_min(1e-12)
    share = albedo / (albedo + diffuse).clamp_min(1e-12)
    none = albedo <= 0
    return {
        "alpha": torch.where(none, zero, alpha),
        "tail": torch.where(none, zero, tail),
        "share": torch.where(none, zero, share),
        "albedo": albedo,
    }


def choose_gaussians(materials: Materials) -> tuple[int, str]:
    """Gaussians per view for a bake of ``materials`` by the module's rule, and the reason in
    words (for the model's provenance)."""
    v = materials.n_vertices
    if materials.specular is None or v == 0:
        return 1, "no glossy lobe (diffuse material): 1"
    count = min(v, AUTO_SAMPLE_VERTICES)
    vidx = torch.tensor(
        [math.floor(i * v / count) for i in range(count)], dtype=torch.int64
    )  # (count,) evenly spread
    m = lobe_shape(materials, vidx)
    glossy = m["albedo"] > 0
    if not bool(glossy.any()):
        return 1, "no glossy lobe (specular albedo 0): 1"
    two = (m["alpha"] >= AUTO_MIN_ALPHA) & (m["tail"] >= AUTO_MIN_TAIL)
    two &= m["share"] >= AUTO_MIN_SHARE
    frac = float(two[glossy].float().mean())
    n = 2 if frac > 0.5 else 1

    def med(key: str) -> float:
        return float(m[key][glossy].median())

    what = (
        f"glossy lobe of equivalent GGX alpha {med('alpha'):.3g} (two from "
        f"{AUTO_MIN_ALPHA}), tail {med('tail'):.2f} (from {AUTO_MIN_TAIL}), "
        f"{100 * med('share'):.0f}% of the reflected light (from {100 * AUTO_MIN_SHARE:.0f}%)"
    )
    if (v > 1 and not bool(glossy.all())) or _varies(m, glossy):
        what += f"; medians over the glossy vertices, {100 * frac:.0f}% of which call for two"
    return n, f"{what}: {n}"


def _varies(m: dict[str, torch.Tensor], glossy: torch.Tensor) -> bool:
    """Whether the glossy vertices' measurements differ (a per-vertex material)."""
    a = m["alpha"][glossy]
    s = m["share"][glossy]
    return bool((a.amax() - a.amin()) > 1e-6 or (s.amax() - s.amin()) > 1e-6)
