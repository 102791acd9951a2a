"""Scored comparisons of rendered models: against the Monte Carlo reference and the baselines
of Green et al. 2006.

Every image is rendered at the pixel centres with the same camera; errors are measured over
the object's pixels (the background is the environment in all of them):

``ours``            the model rendered by :class:`lobelight.render.Renderer` (per-pixel
                    interpolation of Gaussian parameters, prefiltered lookups)
``linear``          the same Gaussians, but each view's lobes are integrated against the
                    lighting first and the *radiance* is blended across views and then across
                    the triangle (Gouraud): the cross-fading the paper avoids (its Figure 2)
``no_visibility``   a model fitted to transport without visibility (and so without
                    interreflection), rendered the same way: prefiltered environment mapping
                    (the paper's Figure 6)
``sh10``            the glossy transport of every vertex and view projected onto order-10
                    spherical harmonics (100 coefficients, by the fit's own quadrature),
                    integrated against the lighting's order-10 projection, blended linearly
``ours_sh_diffuse`` (with a sun, ``sun=True``) ours with the paper's diffuse term alone: the
                    whole map, sun included, through the order-5 SH transfer, no per-pixel
                    sun shadow; ``ours`` takes the sun out of the SH and shades it per pixel
                    with a shadow test (:func:`lobelight.envmap.extract_sun`)
``reference``       :func:`lobelight.reference.paths.render` through the pixel centres, with the
                    light the model holds: paths of ``REFERENCE_DEPTH`` (interreflection) for
                    a model baked with bounces or indirect paths, direct lighting
                    (``max_depth = 2``) for one baked without; the glossy reference (diffuse
                    albedo zero everywhere) then leaves out glossy light that arrives by way
                    of diffuse surfaces, which a baked model's Gaussians hold

Two PSNRs, both over object pixels (:mod:`lobelight.studies.score`): ``psnr`` is
``10 log10(peak^2 / MSE)`` on linear radiance with ``peak`` the reference's largest object-pixel
value (a sun's reflection makes that peak huge and the figure generous), and ``psnr_display``
is the same on the displayed images (the reference's auto exposure, clipped to [0, 1],
sRGB-encoded, peak 1): what a viewer compares. The relative L2 error is ``|a - b| / |b|`` on
linear radiance over object pixels. The glossy component is compared against a reference of
the same scene with its diffuse albedo set to zero.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path
from typing import Any

import torch

from .._io import atomic_writer
from .._tol import DIVISOR_F32
from ..fit import fit_model, gather
from ..geometry import sphere
from ..geometry.camera import Camera
from ..geometry.raycast import RayCaster
from ..lobes import sh
from ..progress import resolve
from ..reference import paths as reference
from ..render import (
    Lighting,
    Renderer,
    as_rotation,
    auto_base_res,
    auto_exposure,
    gl_available,
    save_image,
)
from ..transport import Transport
from .score import noise_psnr, psnr, psnr_display, relative_l2

#: The factor of the difference images.
DIFF_SCALE = 4
#: Path length (Mitsuba's ``max_depth``) of the reference for a model baked with
#: interreflection.
REFERENCE_DEPTH = 8


def reference_depth(model) -> int:
    """The reference's ``max_depth`` for ``model``: :data:`REFERENCE_DEPTH` when its provenance
    says it holds interreflection (diffuse bounces or indirect glossy paths), else 2."""
    prov = model.provenance or {}
    baked = int(prov.get("bounces", 0) or 0) > 0 or int(prov.get("indirect_paths", 0) or 0) > 0
    return REFERENCE_DEPTH if baked else 2


__all__ = ["BASELINES", "compare", "linear_glossy", "reference_depth", "sh_glossy"]

#: The baselines :func:`compare` knows, and what each costs beside the model's own render:
#: ``linear`` reuses the model's Gaussians (seconds); ``no_visibility`` fits a new model of the
#: scene without visibility (no interreflection either); ``sh10`` gathers the glossy transport
#: of every vertex and view again; each takes at least as long as the model's fit stage.
BASELINES = ("linear", "no_visibility", "sh10")


#: What each score and picture of a comparison means (also in ``compare.json``).
LEGEND = {
    "psnr_display": "dB, displayed images: both with the reference's exposure, clipped to "
    "[0, 1], sRGB-encoded, peak 1; what a viewer compares",
    "psnr": "dB, linear radiance, peak = the reference's brightest object pixel (a sun's "
    "reflection makes it large and this figure generous)",
    "rel_l2": "|ours - reference| / |reference|, linear radiance over object pixels",
    "reference_depth": "the reference's path length (Mitsuba's max_depth): 8 for a model "
    "baked with interreflection, 2 (direct light) for one baked without",
    "reference_noise": "the reference's mean standard error / its mean (Monte Carlo noise)",
    "reference_noise_psnr": "dB, the linear PSNR that the reference's own noise allows: scores "
    "near it are limited by the reference, not the model (raise --spp)",
    "diff images": f"|image - reference| x {DIFF_SCALE} over object pixels, at the "
    "reference's exposure",
}


def _hits(model, camera: Camera, width: int, height: int):
    o, d = camera.rays(width, height)
    tri, _, bary = RayCaster(model.mesh, offset=0.0).first_hit(o.reshape(-1, 3), d.reshape(-1, 3))
    return tri.reshape(height, width), bary.reshape(height, width, 3)


def _gouraud(model, colours: torch.Tensor, tri: torch.Tensor, bary: torch.Tensor):
    """Per-pixel barycentric blend of per-vertex colours ``(V, 3)``: ``(H, W, 3)``, 0 off."""
    out = torch.zeros(*tri.shape, 3)
    hit = tri >= 0
    c = model.mesh.faces.cpu()[tri[hit]]  # (P, 3)
    out[hit] = (colours.cpu()[c] * bary[hit][..., None]).sum(1)
    return out


def _vertex_views(model, camera: Camera):
    eye = torch.tensor(camera.origin, dtype=torch.float32, device=model.device)
    view = torch.nn.functional.normalize(eye - model.mesh.vertices, dim=-1)  # (V, 3)
    return sphere.locate_views(view)  # (V, 3), (V, 3)


def linear_glossy(model, lighting: Lighting, camera: Camera, rot, tri, bary) -> torch.Tensor:
    """The cross-fading baseline's glossy image ``(H, W, 3)`` (module docstring)."""
    idx, b = _vertex_views(model, camera)
    v = torch.arange(model.mesh.n_vertices, device=model.device)[:, None].expand_as(idx)
    g = model.gaussians
    light = lighting.integrate(g.mu[v, idx], g.lam[v, idx], rot)  # (V, 3, N, 3)
    per_view = (g.w[v, idx] * light).sum(-2)  # (V, 3, 3)
    colours = (per_view * b[..., None]).sum(1)  # (V, 3)
    return _gouraud(model, colours, tri, bary)


def sh_glossy(
    scene,
    model,
    lighting: Lighting,
    camera: Camera,
    rot,
    tri,
    bary,
    *,
    order: int = 10,
    progress=None,
) -> torch.Tensor:
    """The order-``order`` SH baseline's glossy image ``(H, W, 3)`` (module docstring);
    ``progress(stage, done, total)`` is called per batch of vertices (stage ``"transport"``)."""

    tr = Transport(scene, device=model.device)
    views = model.views
    idx, b = _vertex_views(model, camera)
    light = sh.project_envmap(lighting.env, order, res=64).to(torch.float32)  # (n, 3)
    light = sh.rotate(light, rot.double()).to(torch.float32)
    colours = torch.zeros(model.mesh.n_vertices, 3, device=model.device)
    for s in range(0, model.mesh.n_vertices, 32):  # bounded memory: 32 vertices x 92 views
        vidx = torch.arange(s, min(s + 32, model.mesh.n_vertices), device=model.device)
        data = gather(tr, vidx, views)
        y = sh.basis(data.dirs, order).to(torch.float32)  # (B, J, S, n)
        coef = torch.einsum("bjsn,bjs,bjsc->bjnc", y, data.weights, data.values)
        per_view = (coef * light).sum(-2)  # (B, J, 3): int T L in the SH basis
        pv = per_view.gather(1, idx[vidx][..., None].expand(-1, -1, 3))  # (B, 3, 3)
        colours[vidx] = (pv * b[vidx][..., None]).sum(1)
        if progress is not None:
            progress("transport", int(vidx[-1]) + 1, model.mesh.n_vertices)
    return _gouraud(model, colours, tri, bary)


def compare(
    scene,
    *,
    model=None,
    n_gaussians: int = 1,
    env=None,
    width: int = 192,
    height: int = 144,
    spp: int = 1024,
    light_rotation=None,
    backend: str = "auto",
    base_res: int | str = "auto",
    baselines: tuple[str, ...] = ("linear",),
    out=None,
    device=None,
    seed: int = 0,
    sun: bool = True,
    progress=True,
) -> dict[str, Any]:
    """Render ``scene``'s model and the baselines, score them against the reference.

    Parameters
    ----------
    scene : Scene;  model : its fitted Model (fitted here when None, with ``n_gaussians``)
    env : EnvMap (default the scene's);  spp : reference samples per pixel (its own noise
        bounds the scores: ``reference_noise_psnr``)
    backend : "gl", "torch" or "auto" (gl when a context can be made)
    base_res : the prefiltered chain's base resolution, or ``"auto"``
        (:func:`lobelight.render.auto_base_res`)
    out : folder for the images (PNG, tone-mapped with the reference's exposure) and
        ``compare.json``; nothing is written when None
    sun : shade the map's sun per pixel with shadows (:class:`Lighting`: its diffuse light,
        and its glossy light where the BRDF allows); the paper's lighting (the sun in the SH
        diffuse and in the Gaussians' lighting) is then scored too, as ``ours_sh_diffuse``
    baselines : names from :data:`BASELINES`; the default, ``linear``, reuses the model's
        Gaussians; ``no_visibility`` and ``sh10`` take at least a bake's fit stage each
    progress : True (stderr), None/False (silent) or ``progress(stage, done, total)``, for
        every long stage, each under its own name (``fit``, ``reference``, ``reference,
        glossy``, ``no_visibility baseline: ...``, ``sh10 baseline: transport``;
        :mod:`lobelight.progress`); a reporter with a ``note(text)`` method (as
        :class:`lobelight.progress.Reporter`) is also told the plan before the reference
        starts, and the expected seconds in all once its first batches are timed

    Returns
    -------
    dict with ``table`` (rows: method, component, psnr, rel_l2), timings, the reference's
    noise (mean standard error relative to the mean) and image paths
    """

    unknown = [b for b in baselines if b not in BASELINES]
    if unknown:
        raise ValueError(f"unknown baseline {unknown[0]!r} (known: {', '.join(BASELINES)})")
    progress = resolve(progress)
    t0 = time.perf_counter()
    timings: dict[str, float] = {}
    env = scene.load_environment() if env is None else env
    rot = as_rotation(light_rotation)
    camera = scene.camera
    if model is None:
        model = fit_model(scene, n_gaussians, device=device, progress=progress)
        timings["fit"] = time.perf_counter() - t0
    if base_res == "auto":
        base_res = auto_base_res(model, env)
    lighting = Lighting(
        env, base_res=base_res, device=model.device, sun=sun, sh_order=model.sh_order
    )
    # the paper's lighting (all of it in the SH diffuse), sharing the prefiltered chain
    plain = (
        lighting
        if lighting.sun is None
        else Lighting(
            env, device=model.device, prefiltered=lighting.prefiltered, sh_order=model.sh_order
        )
    )
    if backend == "auto":
        backend = "gl" if gl_available() else "torch"
    # one sample per pixel, at its centre, as the reference traces (jitter=False below)
    ren = Renderer(model, lighting, width, height, backend=backend, samples=1)
    t = time.perf_counter()
    full, mask = ren.render(camera, rot, return_mask=True)
    glossy = ren.render(camera, rot, diffuse=False)
    diffuse = ren.render(camera, rot, glossy=False)
    ren.close()
    timings["ours"] = time.perf_counter() - t
    full_sh = None
    if plain is not lighting:
        with Renderer(model, plain, width, height, backend=backend, samples=1) as r_sh:
            full_sh = r_sh.render(camera, rot)

    # references: the environment is turned by rotating the map itself (independent of ours)
    ref_env = env if light_rotation is None else env.rotate(rot)
    depth = reference_depth(model)
    kw = dict(width=width, height=height, spp=spp, max_depth=depth, seed=seed, jitter=False)
    first = _say_plan(progress, model, kw, baselines, timings["ours"])
    t = time.perf_counter()
    ref_full, err_full = reference.render(
        scene, ref_env, camera, return_stderr=True, progress=first, **kw
    )
    dark = dataclasses.replace(scene.materials, diffuse=torch.zeros_like(scene.materials.diffuse))
    glossy_scene = dataclasses.replace(scene, materials=dark)
    ref_glossy, err_glossy = reference.render(
        glossy_scene,
        ref_env,
        camera,
        return_stderr=True,
        progress=_named(progress, "reference, glossy"),
        **kw,
    )
    timings["reference"] = time.perf_counter() - t
    mask = mask.cpu()

    images = {"ours": full.cpu(), "ours_glossy": glossy.cpu(), "ours_diffuse": diffuse.cpu()}
    images.update(reference=ref_full.cpu(), reference_glossy=ref_glossy.cpu())
    rows = []
    exposure = auto_exposure(ref_full, mask)

    def score(method: str, component: str, img: torch.Tensor) -> None:
        ref = ref_full if component == "full" else ref_glossy
        rows.append(
            {
                "method": method,
                "component": component,
                "psnr": psnr(img.cpu(), ref.cpu(), mask),
                "psnr_display": psnr_display(img.cpu(), ref.cpu(), mask, exposure),
                "rel_l2": relative_l2(img.cpu(), ref.cpu(), mask),
            }
        )

    score("ours", "full", full)
    score("ours", "glossy", glossy)
    if full_sh is not None:
        images["ours_sh_diffuse"] = full_sh.cpu()
        score("ours_sh_diffuse", "full", full_sh)
    tri, bary = _hits(model, camera, width, height)
    diff_only = diffuse.cpu() * mask[..., None]
    background = full.cpu() * (~mask)[..., None]
    for name in baselines:
        t = time.perf_counter()
        stage = _named(progress, f"{name} baseline", prefix=True)
        if name == "linear":
            g = linear_glossy(model, lighting, camera, rot, tri, bary)
        elif name == "sh10":
            g = sh_glossy(scene, model, lighting, camera, rot, tri, bary, progress=stage)
        else:  # no_visibility
            g, d2 = _no_visibility(
                scene, model, plain, camera, rot, (width, height), backend, stage
            )
            images[name] = g + d2 + background
            score(name, "full", images[name])
            score(name, "glossy", g + background)
            timings[name] = time.perf_counter() - t
            continue
        g = g * mask[..., None]
        images[name] = g + diff_only + background
        score(name, "full", images[name])
        score(name, "glossy", g + background)
        timings[name] = time.perf_counter() - t

    noise = {
        "full": float(err_full[mask].mean() / ref_full[mask].mean().clamp_min(DIVISOR_F32)),
        "glossy": float(err_glossy[mask].mean() / ref_glossy[mask].mean().clamp_min(DIVISOR_F32)),
    }
    result: dict[str, Any] = {
        "scene": scene.name,
        "vertices": model.mesh.n_vertices,
        "n_gaussians": model.direct_gaussians,
        "indirect_gaussians": model.indirect_gaussians,
        "size": [width, height],
        "spp": spp,
        "backend": backend,
        "light_rotation": rot.tolist(),
        "sun": None
        if lighting.sun is None
        else {
            "direction": lighting.sun.direction.tolist(),
            "irradiance": lighting.sun.irradiance.tolist(),
        },
        "table": rows,
        "legend": LEGEND,
        "reference_depth": depth,
        "reference_noise": noise,
        "reference_noise_psnr": noise_psnr(ref_full, err_full, mask),
        "object_pixels": int(mask.sum()),
        "seconds": {**timings, "total": time.perf_counter() - t0},
    }
    if out is not None:
        result["images"] = _write(Path(out), images, mask, result)
    return result


def _named(progress, name: str, *, prefix: bool = False):
    """``progress`` with its stage named ``name`` (``prefix``: ``"name: stage"``), or None."""
    if progress is None:
        return None
    if prefix:
        return lambda stage, done, total: progress(f"{name}: {stage}", done, total)
    return lambda _, done, total: progress(name, done, total)


def _no_visibility(scene, model, plain: Lighting, camera, rot, size, backend, progress):
    """The ``no_visibility`` baseline's glossy and diffuse images: a model of ``scene`` fitted
    to transport without visibility (and so without interreflection: plain environment
    mapping), rendered without shadows under ``plain`` (the sun in the SH)."""
    nv = fit_model(
        scene,
        model.direct_gaussians,
        device=model.device,
        shadows=False,
        indirect_paths=0,
        bounces=0,
        progress=progress,
    )
    with Renderer(nv, plain, *size, backend=backend, samples=1) as r2:
        g = r2.render(camera, rot, diffuse=False, background=False).cpu()
        d2 = r2.render(camera, rot, glossy=False, background=False).cpu()
    return g, d2


def _baseline_seconds(model, baselines) -> dict[str, float]:
    """The expected seconds of the baselines that fit or gather transport again: the model's
    own fit stage from its provenance, less its indirect glossy paths (0 where it does not
    say)."""
    stages = (model.provenance or {}).get("seconds") or {}
    fit_s = float(stages.get("fit", 0.0) or 0.0)
    direct_fit = max(fit_s - float(stages.get("indirect_glossy", 0.0) or 0.0), 0.0)
    return {name: direct_fit for name in baselines if name in ("no_visibility", "sh10")}


def _say_plan(progress, model, kw, baselines, ours_s: float):
    """Tells a reporter with a ``note`` (:class:`lobelight.progress.Reporter`) the stages to
    come and what each costs; returns the first reference image's progress, which adds the
    expected seconds of the whole comparison once the path tracer's first batches are timed
    (:class:`_Forecast`), or the plain named progress where there is no ``note``."""
    note = getattr(progress, "note", None)
    if not callable(note):
        return _named(progress, "reference")
    est = _baseline_seconds(model, baselines)
    parts = [f"ours {ours_s:.1f} s (done)"]
    parts.append(
        f"the reference, 2 path-traced images {kw['width']}x{kw['height']} at {kw['spp']} spp "
        "(its seconds follow from its first batches)"
    )
    for name in baselines:
        cost = {"linear": "a few seconds", "no_visibility": "fits a model without visibility",
                "sh10": "gathers the transport again"}[name]  # fmt: skip
        if name in est:
            # a floor, not a forecast: the baselines' work per vertex is not the fit's
            cost += f", {est[name]:.0f} s or more" if est[name] > 0 else ", time unknown"
        parts.append(f"{name} baseline: {cost}")
    note("compare: " + "; ".join(parts))
    return _Forecast(progress, note, kw["spp"], ours_s + sum(est.values()), floor=bool(est))


class _Forecast:
    """The first reference image's progress (stage ``reference``) that, from its second batch
    on and once a sixteenth of its samples are done, notes once the comparison's expected
    seconds in all: the two images' set-up and samples, timed
    on the batches so far (the first batch's time, less its samples', is the set-up), plus
    ``other_s`` (done and expected stages; ``floor``: a lower bound, said "at least")."""

    def __init__(self, progress, note, spp: int, other_s: float, *, floor: bool = False):
        self.progress, self.note, self.spp, self.other_s = progress, note, spp, other_s
        self.floor = floor  # other_s holds a floor, not an estimate: "at least"
        self.t0 = time.perf_counter()
        self.first: tuple[float, int] | None = None
        self.said = False

    def __call__(self, _stage, done: int, total: int) -> None:
        self.progress("reference", done, total)
        now = time.perf_counter()
        if self.first is None:
            self.first = (now, done)
            return
        if self.said or done <= self.first[1] or 16 * done < self.spp:
            return  # timed on a sixteenth of the samples at least: steadier under load
        per_spp = (now - self.first[0]) / (done - self.first[1])
        setup = max(self.first[0] - self.t0 - self.first[1] * per_spp, 0.0)
        ref_s = 2.0 * (setup + self.spp * per_spp)
        self.note(
            f"compare: expected {'at least ' if self.floor else ''}about "
            f"{self.other_s + ref_s:.0f} s in all (the reference "
            f"about {ref_s:.0f} s, timed on its first {done} samples per pixel)"
        )
        self.said = True


def _write(out: Path, images: dict, mask, result: dict) -> dict[str, str]:
    out.mkdir(parents=True, exist_ok=True)
    exposure = auto_exposure(images["reference"], mask)
    paths = {}
    for k, img in images.items():
        paths[k] = str(save_image(out / f"{k}.png", img, exposure=exposure))
        if k in ("ours", "reference"):
            save_image(out / f"{k}.exr", img)
    # difference images, scaled so that small errors show (LEGEND)
    for k in ("ours", "ours_sh_diffuse", "linear", "no_visibility", "sh10"):
        if k in images:
            diff = (images[k] - images["reference"]).abs() * mask[..., None] * DIFF_SCALE
            paths[f"diff_{k}"] = str(save_image(out / f"diff-{k}.png", diff, exposure=exposure))
    result = {**result, "images": paths}
    with atomic_writer(out / "compare.json") as f:
        f.write(json.dumps(result, indent=2, default=str).encode())
    return paths
