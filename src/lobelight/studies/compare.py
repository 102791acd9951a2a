"""Scored comparisons of rendered models: against the Monte Carlo reference and the baselines
of Green et al. 2006.

Every image is rendered at the pixel centres with the same camera; errors are measured over
the object's pixels (the background is the environment in all of them):

``ours``            the model rendered by :class:`lobelight.render.Renderer` (per-pixel
                    interpolation of Gaussian parameters, prefiltered lookups)
``linear``          the same Gaussians, but each view's lobes are integrated against the
                    lighting first and the *radiance* is blended across views and then across
                    the triangle (Gouraud): the cross-fading the paper avoids (its Figure 2)
``no_visibility``   a model fitted to transport without visibility, rendered the same way:
                    prefiltered environment mapping (the paper's Figure 6)
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
from ..render import Lighting, Renderer, as_rotation, auto_exposure, gl_available, save_image
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


__all__ = ["compare", "linear_glossy", "reference_depth", "sh_glossy"]


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
    scene, model, lighting: Lighting, camera: Camera, rot, tri, bary, *, order: int = 10
) -> torch.Tensor:
    """The order-``order`` SH baseline's glossy image ``(H, W, 3)`` (module docstring)."""

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
    base_res: int = 256,
    baselines: tuple[str, ...] = ("linear", "no_visibility", "sh10"),
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
    out : folder for the images (PNG, tone-mapped with the reference's exposure) and
        ``compare.json``; nothing is written when None
    sun : shade the map's sun per pixel with shadows (:class:`Lighting`: its diffuse light,
        and its glossy light where the BRDF allows); the paper's lighting (the sun in the SH
        diffuse and in the Gaussians' lighting) is then scored too, as ``ours_sh_diffuse``
    progress : True (stderr), None/False (silent) or ``progress(stage, done, total)``, for
        the fit and the reference renders (:mod:`lobelight.progress`)

    Returns
    -------
    dict with ``table`` (rows: method, component, psnr, rel_l2), timings, the reference's
    noise (mean standard error relative to the mean) and image paths
    """

    progress = resolve(progress)
    t0 = time.perf_counter()
    timings: dict[str, float] = {}
    env = scene.load_environment() if env is None else env
    rot = as_rotation(light_rotation)
    camera = scene.camera
    if model is None:
        model = fit_model(scene, n_gaussians, device=device, progress=progress)
        timings["fit"] = time.perf_counter() - t0
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
    t = time.perf_counter()
    depth = reference_depth(model)
    kw = dict(width=width, height=height, spp=spp, max_depth=depth, seed=seed, jitter=False)

    def step(name):  # one progress bar per reference image
        return None if progress is None else (lambda _, done, total: progress(name, done, total))

    ref_full, err_full = reference.render(
        scene, ref_env, camera, return_stderr=True, progress=step("reference"), **kw
    )
    dark = dataclasses.replace(scene.materials, diffuse=torch.zeros_like(scene.materials.diffuse))
    glossy_scene = dataclasses.replace(scene, materials=dark)
    ref_glossy, err_glossy = reference.render(
        glossy_scene, ref_env, camera, return_stderr=True, progress=step("reference, glossy"), **kw
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
        if name == "linear":
            g = linear_glossy(model, lighting, camera, rot, tri, bary)
        elif name == "sh10":
            g = sh_glossy(scene, model, lighting, camera, rot, tri, bary)
        elif name == "no_visibility":
            nv = fit_model(
                scene, model.direct_gaussians, device=model.device, shadows=False, progress=progress
            )
            r2 = Renderer(nv, plain, width, height, backend=backend, samples=1)  # no shadows
            g = r2.render(camera, rot, diffuse=False, background=False).cpu()
            # unshadowed diffuse as well: plain environment mapping has no visibility at all
            d2 = r2.render(camera, rot, glossy=False, background=False).cpu()
            r2.close()
            images[name] = g + d2 + background
            score(name, "full", images[name])
            score(name, "glossy", g + background)
            timings[name] = time.perf_counter() - t
            continue
        else:
            raise ValueError(f"unknown baseline {name!r}")
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
