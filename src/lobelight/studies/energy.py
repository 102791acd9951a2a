"""Where a fitted glossy transport's light goes: a study of each step, against quadrature.

Per (vertex, view) glossy transport ``T(w) = f_s(w, v) V(w) max(n.w, 0)``, the study measures

(a) ``int T``, the truth: a dense nested-shell quadrature (:func:`reference_rule`) of
    :meth:`lobelight.transport.Transport.direct`, visibility included, over half vectors about
    the normal for the microfacet-type models and over light directions about the mirror
    direction for the others (:func:`reference_integral`); checked against BRDF importance
    sampling where nothing occludes (:func:`albedo_mc`);
(b) the integral of the data the fit sees (:func:`lobelight.fit.gather`: its quadrature);
(c) the integral of the fitted Gaussians, ``sum_k w_k 2 pi / lam_k (1 - exp(-2 lam_k))``;
(d) what the renderer's prefiltered lookup returns for them under a constant white
    environment, against (c);
(e) the light of the Gaussians interpolated to views between the stored ones (the renderer's
    blend of carried light, :func:`lobelight.model.blend_lobes`), against (a) at those views;

and, apart from any mesh, :func:`prefilter_check`: ``Prefiltered.integrate`` against the
exact SG integral of a smooth map and of a small bright source from ``lam = 1`` to the chain's
largest. Every ratio is summarised by its mean, mean absolute deviation from 1 and
percentiles (:func:`summary`). ``python -m lobelight.studies.energy --json FILE`` runs the whole
study.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time

import torch

from .. import brdf, envmap, fit, scene, transport
from ..fit import half_vector_lobes
from ..geometry import cubemap, sphere
from ..lobes import sg
from ..model import blend_lobes
from ..scene import Materials, Scene

__all__ = [
    "albedo_mc",
    "energy_study",
    "fitted_integral",
    "metal",
    "prefilter_check",
    "reference_integral",
    "reference_rule",
    "summary",
    "wall_scene",
]

#: Materials of the study: Fresnel-free rough conductors, as the user report's metals.
MODELS = ("ggx", "beckmann")
ALPHAS = (0.02, 0.05, 0.1, 0.25, 0.5)


def metal(sc: Scene, model: str, alpha: float) -> Scene:
    """``sc`` with every vertex a black-diffuse GGX or Beckmann conductor, Fresnel 1."""
    spec = brdf.from_dict({"type": model, "alpha": alpha})
    mats = Materials(torch.zeros(sc.mesh.n_vertices, 3), spec)
    return dataclasses.replace(sc, materials=mats, name=f"{sc.name}-{model}-{alpha}")


def wall_scene(*, n: int = 9) -> Scene:
    """A floor (``y = 0``, ``2 x 2``) meeting a wall (``z = -1``, 2 high) at a right angle.

    Floor vertices next to the wall see it cover the half of their sky towards ``-z``: their
    glossy lobes are cut by visibility for views from ``+z`` (the mirror directions of those
    views point into the wall). Vertex ``i * n + k`` of the first ``n * n`` is the floor point
    at ``x = -1 + 2 k / (n - 1)``, ``z = -1 + 2 i / (n - 1)``; the floor is open to ``+z``.
    """
    t = torch.linspace(-1, 1, n, dtype=torch.float64)
    zz, xx = torch.meshgrid(t, t, indexing="ij")
    floor = torch.stack([xx, torch.zeros_like(xx), zz], -1).reshape(-1, 3)
    yy, xw = torch.meshgrid(torch.linspace(0, 2, n, dtype=torch.float64), t, indexing="ij")
    wall = torch.stack([xw, yy, torch.full_like(xw, -1.0)], -1).reshape(-1, 3)
    q = torch.arange(n - 1)
    i, k = torch.meshgrid(q, q, indexing="ij")
    a = (i * n + k).reshape(-1)  # (Q,) each quad's first corner
    # floor triangles wound to face +y, wall triangles to face +z (towards the floor); the
    # wall's vertices are not welded to the floor's, so the floor's normals stay (0, 1, 0)
    floor_f = torch.stack([a, a + n, a + 1, a + 1, a + n, a + n + 1], -1).reshape(-1, 3)
    wall_f = torch.stack([a, a + 1, a + n, a + 1, a + n + 1, a + n], -1).reshape(-1, 3) + n * n
    mesh = scene.mesh_from_arrays(
        torch.cat([floor, wall]).numpy(),
        torch.cat([floor_f, wall_f]).numpy(),
        name="wall",
        weld=False,
    )
    mats = Materials(torch.zeros(mesh.n_vertices, 3), brdf.GGX(0.1))
    return Scene(mesh, mats, "builtin", name="wall")


# --------------------------------------------------------------------------------------------
# the truth


def reference_rule(
    axis: torch.Tensor,
    *,
    s_min: float = 1e-6,
    ratio: float = 4.0,
    n_s: int = 8,
    n_phi: int = 96,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Nested-shell quadrature of the whole sphere about ``axis``.

    Shells in ``s = 1 - cos`` from the axis: ``[0, s_min]``, then ``ratio`` times wider each
    out to 2, each with ``n_s`` Gauss-Legendre nodes, times ``n_phi`` equal steps in ``phi``.
    It integrates an SG centred on the axis to float32 rounding at any sharpness from 1 to
    3e4, one 0.1 rad off the axis to 1e-6 up to ``lam = 1e3`` (tests/test_fit_energy.py), and
    a GGX or Beckmann lobe to within 1e-4 of BRDF importance sampling.

    Parameters
    ----------
    axis : (..., 3) unit

    Returns
    -------
    dirs : (..., K, 3);  weights : (..., K) solid angles, ``K = shells n_s n_phi``
    """
    edges = [0.0, s_min]
    while edges[-1] * ratio < 2:
        edges.append(edges[-1] * ratio)
    edges.append(2.0)
    x, wx = sphere.gauss_legendre(n_s)
    e = torch.tensor(edges, dtype=torch.float64)
    lo, hi = e[:-1, None], e[1:, None]
    s = (lo + 0.5 * (x + 1) * (hi - lo)).reshape(-1)  # (R,) ring offsets
    ws = (0.5 * wx * (hi - lo)).reshape(-1)
    phi = (torch.arange(n_phi, dtype=torch.float64) + 0.5) * (2 * math.pi / n_phi)
    sin_t = torch.sqrt(s * (2 - s))
    lx, ly = sin_t[:, None] * phi.cos(), sin_t[:, None] * phi.sin()  # (R, n_phi)
    lz = (1 - s)[:, None].expand_as(lx)
    dev, batch = axis.device, axis.shape[:-1]
    t, b, a = (v.reshape(*batch, 1, 1, 3) for v in sphere.frame(axis.double()))
    d = lx.to(dev)[..., None] * t + ly.to(dev)[..., None] * b + lz.to(dev)[..., None] * a
    w = (ws[:, None] * (2 * math.pi / n_phi)).expand_as(lx).reshape(-1).to(dev)
    k = lx.numel()
    return d.reshape(*batch, k, 3).to(axis.dtype), w.expand(*batch, k).to(axis.dtype)


def _rule_dirs(tr: transport.Transport, vidx, views, **rule):
    """The reference rule's light directions and solid angles per vertex and view: shells of
    half vectors about the normal (mapped to light directions, ``dw = 4 (v.h) dh``) for the
    microfacet-type models, of light directions about the mirror direction otherwise."""
    b, j = vidx.shape[0], views.shape[0]
    n = tr.mesh.normals[vidx][:, None].expand(b, j, 3)
    v = views[None].expand(b, j, 3)
    if half_vector_lobes(tr.materials.specular):
        h, w = reference_rule(n, **rule)  # (B, J, K, 3), (B, J, K)
        vh = (h * v[:, :, None]).sum(-1, keepdim=True)
        d = torch.nn.functional.normalize(2 * vh * h - v[:, :, None], dim=-1)
        return d, w * 4 * vh[..., 0].clamp_min(0)
    refl = 2 * (v * n).sum(-1, keepdim=True) * n - v
    return reference_rule(refl, **rule)


def reference_integral(
    tr: transport.Transport,
    vidx: torch.Tensor,
    views: torch.Tensor,
    *,
    env: envmap.EnvMap | None = None,
    batch: int = 1,
    **rule,
) -> torch.Tensor:
    """``int T`` per vertex and view by :func:`reference_rule`, ``(B, J, 3)``, and with
    ``env`` also ``int T L`` (stacked first: ``(2, B, J, 3)``; the rule resolves the transport,
    not a map's small bright lights: use a smooth ``env``); ``batch`` vertices at a time
    (``batch x J x K`` directions in memory)."""
    out = []
    for s in range(0, vidx.shape[0], batch):
        vb = vidx[s : s + batch]
        d, w = _rule_dirs(tr, vb, views, **rule)
        t = tr.direct(vb, views, d) * w[..., None]  # (b, J, K, 3)
        part = [t.sum(2)]
        if env is not None:
            lit = env.radiance(d.reshape(-1, 3)).reshape(*d.shape[:-1], 3)
            part.append((t * lit).sum(2))
        out.append(torch.stack(part))
    res = torch.cat(out, 1)
    return res if env is not None else res[0]


def albedo_mc(
    tr: transport.Transport, vidx: torch.Tensor, views: torch.Tensor, *, count: int = 20000
) -> tuple[torch.Tensor, torch.Tensor]:
    """Directional albedo ``int f_s cos`` (no visibility) by BRDF importance sampling: mean and
    standard error, ``(B, J, 3)`` each (fixed seed)."""
    b, j = vidx.shape[0], views.shape[0]
    n = tr.mesh.normals[vidx][:, None].expand(b, j, 3)
    spec = tr.materials.specular.take(vidx).map_params(
        lambda p, k: p if p.ndim <= k else p.reshape(1, b, 1, *p.shape[1:])
    )
    g = torch.Generator().manual_seed(0)
    u = torch.rand(count, b, j, 2, generator=g)
    _, wt, _ = spec.sample(views[None, None].expand(count, b, j, 3), n.expand(count, b, j, 3), u)
    return wt.mean(0), wt.std(0) / math.sqrt(count)


# --------------------------------------------------------------------------------------------
# the fit and the renderer


def fitted_integral(g: fit.Gaussians) -> torch.Tensor:
    """The light the Gaussians carry, ``sum_k w_k int G_k``, ``(B, J, 3)``."""
    return (g.w * sg.integral(g.lam)[..., None]).sum(-2)


def _interpolated(g: fit.Gaussians, dirs: torch.Tensor) -> torch.Tensor:
    """The carried light at view directions ``dirs`` (B, M, 3) between the stored views, as
    the renderer blends it (:func:`lobelight.model.blend_lobes`), ``(B, M, 3)``."""
    idx, bary = sphere.locate_views(dirs)  # (B, M, 3) each
    rows = torch.arange(g.w.shape[0])[:, None, None].expand_as(idx)
    lam = g.lam[rows, idx]  # (B, M, 3, N)
    e = g.w[rows, idx] * sg.integral(lam)[..., None]
    e, _, _ = blend_lobes(e, g.mu[rows, idx], lam.rsqrt(), bary)
    return e.sum(-2)


def summary(x: torch.Tensor) -> dict[str, float]:
    """Mean, mean |x - 1|, and the 1st, 5th, 50th, 95th and 99th percentiles of ratios."""
    x = x.double().reshape(-1)
    if x.numel() == 0:
        return {"count": 0}
    q = torch.quantile(x, torch.tensor([0.01, 0.05, 0.5, 0.95, 0.99], dtype=x.dtype))
    return {
        "count": int(x.numel()),
        "mean": float(x.mean()),
        "mean_abs_dev": float((x - 1).abs().mean()),
        "p1": float(q[0]),
        "p5": float(q[1]),
        "p50": float(q[2]),
        "p95": float(q[3]),
        "p99": float(q[4]),
    }


def _constant_prefiltered(base_res: int) -> envmap.Prefiltered:
    return envmap.prefilter(torch.ones(6, base_res, base_res, 3), base_res=base_res)


def study_case(
    sc: Scene,
    vidx: torch.Tensor,
    *,
    n_gaussians: int = 1,
    conserve: bool = True,
    white: envmap.Prefiltered | None = None,
    seed: int = 0,
) -> dict:
    """Steps (a)-(e) of the module docstring for some vertices of one scene, all 92 views.

    Ratios are taken over the (vertex, view) functions carrying at least 2 % of light (above
    the horizon, and not all but wholly occluded: a lobe inside an occluder leaks a few
    thousandths through its tails, whose ratio is noise); ``grazing`` are those with ``n.v <
    0.2``; ``light_weighted`` ratios are sums over all functions (the overall brightness).
    """
    views = sphere.geodesic_views()
    nbr = sphere.geodesic_neighbor_table()
    tr = transport.Transport(sc)
    t0 = time.perf_counter()
    ref = reference_integral(tr, vidx, views)[..., 0]  # (B, J); grey metals: one channel
    t1 = time.perf_counter()
    data = fit.gather(tr, vidx, views)
    g, terms = fit.fit_batch(data, n_gaussians, nbr, conserve=conserve)
    t2 = time.perf_counter()
    seen = (data.weights[..., None] * data.values).sum(2)[..., 0]
    carried = fitted_integral(g)[..., 0]
    ok = ref > 0.02
    cosv = (views[None] * tr.mesh.normals[vidx][:, None]).sum(-1)
    graz = ok & (cosv < 0.2)
    out: dict = {
        "scene": sc.name,
        "vertices": vidx.tolist(),
        "functions": int(ok.sum()),
        "seconds": {"reference": t1 - t0, "gather_and_fit": t2 - t1},
        "relative_l2_error_mean": float(terms["D"].clamp_min(0).sqrt().mean()),
        "window_over_truth": summary((seen / ref)[ok]),
        "fit_over_truth": summary((carried / ref)[ok]),
        "fit_over_window": summary((carried / seen)[ok]),
        "fit_over_truth_grazing": summary((carried / ref)[graz]),
        "light_weighted": {
            "window_over_truth": float(seen.sum() / ref.sum()),
            "fit_over_truth": float(carried.sum() / ref.sum()),
        },
    }
    if white is not None:  # (d): constant white lighting, one lookup per lobe
        live = g.w[..., 0] > 0
        got = (white.integrate(g.mu[live], g.lam[live])[..., 0] * g.w[live][..., 0]).double()
        want = (g.w[live][..., 0] * sg.integral(g.lam[live])).double()
        out["lookup_over_fit_white"] = summary(got / want)
    # (e): views between the stored ones, the same 92 random ones for every vertex (those
    # below a vertex's horizon carry no light there and drop out of the ratios)
    gen = torch.Generator().manual_seed(seed)
    rnd = torch.nn.functional.normalize(torch.randn(92, 3, generator=gen), dim=-1)
    ref_i = reference_integral(tr, vidx, rnd)[..., 0]  # (B, M)
    blend = _interpolated(g, rnd.expand(len(vidx), -1, 3))[..., 0]
    ok_i = ref_i > 0.02
    graz_i = ok_i & ((rnd[None] * tr.mesh.normals[vidx][:, None]).sum(-1) < 0.2)
    out["interpolated_over_truth"] = summary((blend / ref_i)[ok_i])
    out["interpolated_over_truth_grazing"] = summary((blend / ref_i)[graz_i])
    return out


def prefilter_check(
    *, base_res: int = 128, lams=(1.0, 4.0, 16.0, 64.0, 256.0, 1024.0, 4096.0), seed: int = 0
) -> dict:
    """``Prefiltered.integrate`` against the exact SG integral, per ``lam``.

    Two maps: a smooth one, ``L(w) = 1 + 0.5 w_x + 0.3 w_y w_z + 0.2 (3 w_z^2 - 1)`` (the exact
    integral by :func:`reference_rule`), and a small bright source, a disc of 1 degree radius
    and radiance 1000 on a black map (exactly: the cube map's own texels, each integrated
    against the SG by a 4 x 4 sub-texel rule). Lobes at random axes; for the source, axes
    about 3 lobe widths from it (a Gaussian offset). ``lams`` beyond the chain's largest
    (``lam_max``; 655 at 128, 10486 at 512) are looked up at its sharpest level, and the chain's
    largest is always checked too. Returns per ``lam`` the ratio summaries.
    """

    gen = torch.Generator().manual_seed(seed)
    res = base_res
    d = cubemap.texel_directions(res).reshape(-1, 3).double()

    def smooth(w: torch.Tensor) -> torch.Tensor:
        x, y, z = w.unbind(-1)
        return 1 + 0.5 * x + 0.3 * y * z + 0.2 * (3 * z * z - 1)

    smooth_map = smooth(d).reshape(6, res, res, 1).expand(6, res, res, 3).float()
    src = torch.nn.functional.normalize(torch.tensor([0.3, 0.8, 0.5], dtype=torch.float64), dim=0)
    # the disc on the cube map by 4 x 4 sub-texel coverage (its texels' exact content), over
    # the texels whose centre lies within the disc's radius and a texel diagonal of it
    near = (d @ src) > math.cos(math.radians(1.0) + 3 / res)  # (D,)
    sub = (torch.arange(4, dtype=torch.float64) + 0.5) / 4 - 0.5
    f, u, v = cubemap.direction_to_face_uv(d[near].float())
    h = 2 / res
    su, sv = torch.meshgrid(sub, sub, indexing="ij")
    pu = u.double()[:, None] + h * su.reshape(-1)[None]  # (D', 16)
    pv = v.double()[:, None] + h * sv.reshape(-1)[None]
    pts = cubemap.face_uv_to_direction(f[:, None].expand_as(pu), pu, pv).double()
    pts = torch.nn.functional.normalize(pts, dim=-1)  # (D', 16, 3)
    inside = (pts @ src) > math.cos(math.radians(1.0))
    cover = torch.zeros(d.shape[0], dtype=torch.float64)
    cover[near] = inside.double().mean(-1)
    om = cubemap.texel_solid_angles(res).reshape(-1).double()[near]
    disc_map = (1000 * cover).reshape(6, res, res, 1).expand(6, res, res, 3).float()
    pf_s = envmap.prefilter(smooth_map, base_res=res)
    pf_d = envmap.prefilter(disc_map, base_res=res)
    out: dict = {"base_res": res, "lam_max": pf_s.lam_max, "smooth": {}, "source": {}}
    for lam in sorted({*map(float, lams), pf_s.lam_max}):
        axes = torch.nn.functional.normalize(torch.randn(64, 3, generator=gen), dim=-1).double()
        rd, rw = reference_rule(axes, n_s=12, n_phi=96)
        exact = sg.evaluate(rd, axes[:, None], torch.tensor(lam, dtype=torch.float64)) * rw
        exact = (exact * smooth(rd)).sum(-1)
        got = pf_s.integrate(axes.float(), torch.full((64,), lam))[:, 0].double()
        out["smooth"][str(lam)] = summary(got / exact)
        # source: axes within 3 widths of it (the lobes that see it)
        kick = torch.randn(64, 3, generator=gen).double() * (3 / math.sqrt(lam)) / math.sqrt(3)
        ax = torch.nn.functional.normalize(src + kick, dim=-1)
        g = torch.exp(lam * ((pts @ ax.T) - 1))  # (D', 16, 64) the SG over each texel
        exact = (g.mean(1) * (1000 * cover[near] * om)[:, None]).sum(0)  # (64,)
        got = pf_d.integrate(ax.float(), torch.full((64,), lam))[:, 0].double()
        keep = exact > 1e-6 * exact.max()
        out["source"][str(lam)] = summary((got / exact)[keep])
    return out


def _pick(sc: Scene, count: int, *, only: torch.Tensor | None = None) -> torch.Tensor:
    """``count`` vertex ids spread evenly over the mesh (or over the ids ``only``)."""
    ids = torch.arange(sc.mesh.n_vertices) if only is None else only
    pos = torch.linspace(0, len(ids) - 1, count).round().long()
    return ids[pos]


def energy_study(
    *,
    models=MODELS,
    alphas=ALPHAS,
    vertices: int = 8,
    n_gaussians: int = 1,
    conserve: bool = True,
    progress=None,
) -> dict:
    """The whole study: the prefiltered lookup (:func:`prefilter_check`, at the renderer's
    default base resolution 128 and at 512), then a sphere (no occlusion) and the knot
    (self-occlusion and its ground), each as a GGX and a Beckmann metal at each roughness,
    ``vertices`` vertices each. A ``--json``-able dict; ``progress(result)`` is called with the
    result so far after each step."""
    res: dict = {"n_gaussians": n_gaussians, "conserve": conserve, "prefilter": [], "cases": []}
    for base in (128, 512):
        res["prefilter"].append(prefilter_check(base_res=base))
        if progress is not None:
            progress(res)
    sphere_sc = scene.builtin("sphere", subdivisions=2)
    knot_sc = scene.builtin("knot")
    knot_ids = torch.arange(2592)  # the tube's vertices (72 x 36); the ground follows
    shapes = [
        ("sphere", sphere_sc, _pick(sphere_sc, vertices)),
        ("knot", knot_sc, _pick(knot_sc, vertices, only=knot_ids)),
    ]
    white = _constant_prefiltered(128)
    for name, sc, vidx in shapes:
        for model in models:
            for alpha in alphas:
                r = study_case(
                    metal(sc, model, alpha),
                    vidx,
                    n_gaussians=n_gaussians,
                    conserve=conserve,
                    white=white,
                )
                r.update(shape=name, model=model, alpha=alpha)
                res["cases"].append(r)
                if progress is not None:
                    progress(res)
    return res


def _line(r: dict) -> str:
    f, w = r["fit_over_truth"], r["window_over_truth"]
    return (
        f"{r['shape']:6s} {r['model']:8s} {r['alpha']:<5} window/truth {w['mean']:.3f} "
        f"(|1-x| {w['mean_abs_dev']:.3f})  fit/truth {f['mean']:.3f} (|1-x| "
        f"{f['mean_abs_dev']:.3f}, p5 {f['p5']:.3f}, p95 {f['p95']:.3f})  "
        f"rel. L2 {r['relative_l2_error_mean']:.3f}"
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m lobelight.studies.energy", description=__doc__)
    ap.add_argument("--json", help="write the result here")
    ap.add_argument("--vertices", type=int, default=8)
    ap.add_argument("--gaussians", type=int, default=1)
    ap.add_argument("--no-conserve", action="store_true", help="plain L2 weights")
    args = ap.parse_args(argv)

    def report(res: dict) -> None:
        if res["cases"]:
            print(_line(res["cases"][-1]), flush=True)
        if args.json:  # after every step: a long study stopped halfway keeps what it measured
            with open(args.json, "w") as f:
                json.dump(res, f, indent=1)

    energy_study(
        vertices=args.vertices,
        n_gaussians=args.gaussians,
        conserve=not args.no_conserve,
        progress=report,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
