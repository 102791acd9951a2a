"""The EM paper's comparison (its sec. VI) in one harness: quality and speed of four renderers.

A unit sphere (orthographic, seen from +Z, :func:`lobelight.sgbrdf.sphere_hits`) made of Ward
(``ks = 1``, grey) at each roughness, lit by a real HDR map, shaded per sphere pixel by

``ours``       the fitted SG mixture (:func:`lobelight.sgbrdf.fit`; 8 lobes, 16 for
               anisotropic materials: ``LOBES``, ``ANISO_LOBES``) with the exact
               Gaussian-prefiltered chain (:class:`lobelight.envmap.Prefiltered`)
``ours_mip``   the same mixture read from a box-filtered mip chain at the paper's eq. (10) level
               (:class:`lobelight.sgbrdf.MipChain`, coverage ``a = 0.5``)
``fis40``      filtered importance sampling with 40 Hammersley samples (:func:`shade_fis`)
``wang09``     the single warped lobe of Wang et al. 2009 (:func:`shade_wang09`)
``reference``  Monte Carlo with MIS of BRDF and environment sampling (:func:`shade_reference`)

Metrics, per material and method, over the sphere pixels only
    ``psnr``: of the display image, ``srgb(clip(k x, 0, 1))`` with one exposure ``k`` per
    material (the reference's 99th-percentile luminance maps to 1), peak 1, as for the paper's
    8-bit figures. ``rel_l2``: ``||x - ref|| / ||ref||`` of the linear radiance (HDR energy
    errors the display clip hides). ``fps``: 1 / seconds to shade all sphere pixels (best of
    ``REPEATS`` interleaved rounds after a warm-up; one-time setup — fitting, prefiltering,
    the mip chain, the environment sampler — excluded and reported separately; the reference
    is timed once).
    The reference's own noise is reported per material: its relative standard error and the
    PSNR it alone would cap a perfect method at (``ref_psnr_ceiling``); every method row has
    ``noise_share``, the part of its display MSE the reference's noise accounts for.

With ``backend="both"`` two more rows per material come from the OpenGL shaders
(:class:`lobelight.render.GLSGBRDFRenderer`, headless EGL): ``ours_gl`` (the same
fit and Prefiltered chain) and ``fis40_gl`` (40-sample FIS on a GL cube map whose base level is
the mip chain's level 0, its coarser levels built by ``glGenerateMipmap``). Their ``fps`` is of
whole frames of the ``size x size`` image drawn back to back with one ``ctx.finish()``, for at
least ``GL_MIN_SECONDS`` (:func:`lobelight.bench.time_frames`), best of
``GL_ROUNDS`` alternating rounds: shader against shader. They are not in the image grid.
"""

from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from PIL import Image

from .. import envmap
from .._io import atomic_path, atomic_writer
from .._tol import DIVISOR_F32
from ..bench import machine, sync, time_frames
from ..brdf import Ward
from ..data import DATA_ENV
from ..envmap import prefilter
from ..errors import InputError
from ..reference.paths import EnvSampler
from ..reference.sgbrdf import shade_reference
from ..render import GLSGBRDFRenderer, create_context
from ..sgbrdf import (
    COVERAGE,
    FIS_SAMPLES,
    fit_many,
    is_isotropic,
    mip_chain,
    shade,
    shade_fis,
    shade_wang09,
    sphere_hits,
)
from .score import LUMA, display, psnr_from_mse, relative_l2

__all__ = ["METHODS", "compare_brdf", "default_envmap"]

#: Column order of the table and the image grid.
METHODS = ("reference", "ours", "ours_mip", "fis40", "wang09")
#: Timed rounds (every method once per round; its best is reported) after one warm-up.
REPEATS = 5
#: The map used when none is given (a studio: a sharp-edged softbox and a round light).
DEFAULT_ENVMAP = "studio_small_03_1k.hdr"
#: Lobes per view of ``ours``: the paper's 8 for isotropic materials; 16 for anisotropic ones,
#: where 8 isotropic lobes cannot follow a 20:1 streak (the fit errors of both: docs/sgbrdf.md).
LOBES = 8
ANISO_LOBES = 16
#: Amplification of the difference images in the grid.
DIFF_GAIN = 4.0
#: Rows added by ``backend="both"`` (OpenGL shaders), and their timing.
GL_METHODS = ("ours_gl", "fis40_gl")
GL_MIN_SECONDS = 1.0
GL_ROUNDS = 2
BACKENDS = ("torch", "both")


def default_envmap() -> Path | None:
    """The default real map: ``DEFAULT_ENVMAP`` (else the first ``.hdr``) in the data folder's
    ``envmaps/``, the folder named by ``$LOBELIGHT_DATA`` as for the gallery; None when the
    variable is unset or the folder holds no map."""
    data = os.environ.get(DATA_ENV)
    if not data:
        return None
    d = Path(data) / "envmaps"
    if (d / DEFAULT_ENVMAP).is_file():
        return d / DEFAULT_ENVMAP
    found = sorted(d.rglob("*.hdr")) if d.is_dir() else []
    return found[0] if found else None


def _load_env(env: Any, device: Any):
    if env is None:
        path = default_envmap()
        env = envmap.load(path) if path is not None else envmap.builtin()
    elif isinstance(env, (str, Path)):
        env = envmap.load(env)
    elif not hasattr(env, "radiance"):
        raise InputError("env", f"must be an EnvMap, a path or None, got {type(env).__name__}")
    return env.to(device)


def _base_res(env) -> int:
    """Face resolution of the chains: a power of two near the map's own density (a lat-long
    ``W`` wide has about ``W / 4`` texels per cube face; 2x oversampled), at most 512."""
    w = env.data.shape[-2] // 2 if env.layout == "latlong" else env.data.shape[1]
    return int(min(512, max(8, 2 ** math.floor(math.log2(max(w, 1))))))


def _materials(alphas, aniso) -> list[tuple[str, Ward]]:
    try:
        al = [float(a) for a in alphas]
    except (TypeError, ValueError):
        raise InputError("alphas", f"must be a list of roughness values, got {alphas!r}") from None
    if any(not (0 < a <= 1) for a in al):
        raise InputError("alphas", f"each must be in (0, 1], got {al}")
    mats = [(f"ward a={a:g}", Ward(1.0, a)) for a in al]
    if aniso is not None:
        try:
            ax, ay = (float(v) for v in aniso)
        except (TypeError, ValueError):
            raise InputError("aniso", f"must be a pair (ax, ay) or None, got {aniso!r}") from None
        if not (0 < ax <= 1 and 0 < ay <= 1):
            raise InputError("aniso", f"both must be in (0, 1], got ({ax}, {ay})")
        mats.append((f"ward ax={ax:g} ay={ay:g}", Ward(1.0, ax, ay)))
    if not mats:
        raise InputError("alphas", "no material to compare (empty alphas and no aniso)")
    return mats


def _timed_all(runs: dict, repeats: int, device: torch.device) -> tuple[dict, dict]:
    """Results and best times of ``runs`` (name -> zero-argument callable).

    One warm-up call each, then ``repeats`` rounds that call every method once in turn, so a
    change of load on a shared machine hits all methods alike rather than whichever happened
    to run during it; each method's best round is its time.
    """
    out = {name: fn() for name, fn in runs.items()}
    best = dict.fromkeys(runs, math.inf)
    for _ in range(repeats):
        for name, fn in runs.items():
            sync(device)
            t0 = time.perf_counter()
            out[name] = fn()
            sync(device)
            best[name] = min(best[name], time.perf_counter() - t0)
    return out, best


def _exposure(ref: torch.Tensor) -> float:
    """The display's scale ``k``: the reference's 99th-percentile luminance maps to 1."""
    lum = (ref.double() * torch.tensor(LUMA, dtype=torch.float64, device=ref.device)).sum(-1)
    p99 = float(torch.quantile(lum.cpu(), 0.99)) if lum.numel() else 1.0
    return 1.0 / p99 if p99 > 0 else 1.0


def _write_png(img: np.ndarray, path: Path) -> None:
    out = (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)
    with atomic_path(path) as tmp:
        Image.fromarray(out).save(tmp, format="PNG")


def _write_json(obj: dict, path: Path) -> None:
    text = json.dumps(obj, indent=2, allow_nan=False) + "\n"
    with atomic_writer(path) as f:
        f.write(text.encode())


def compare_brdf(
    out: Any,
    *,
    env: Any = None,
    size: int = 256,
    alphas: Any = (0.01, 0.05, 0.1, 0.15, 0.2),
    aniso: Any = (0.01, 0.2),
    device: Any = "cpu",
    ref_spp: int = 8192,
    seed: int = 0,
    backend: str = "torch",
) -> dict:
    """Render the comparison of the module docstring and write its image grid and JSON.

    Parameters
    ----------
    out : folder for ``compare-brdf.png`` and ``compare-brdf.json`` (created; files replaced
        atomically: written to a temporary name, then renamed)
    env : an :class:`lobelight.envmap.EnvMap`, a path to an ``.hdr``/``.exr`` map, or None for
        :func:`default_envmap` (else the built-in sky)
    size : image width = height in pixels (the sphere fills it)
    alphas : isotropic Ward roughness values;  aniso : ``(ax, ay)`` of one anisotropic Ward,
        or None
    device : torch device of every computation
    ref_spp : Monte Carlo samples per pixel of the reference (half BRDF, half environment)
    seed : seed of the reference's random numbers
    backend : "torch" (default: the torch renderers only) or "both" (also the GLSL rows
        ``GL_METHODS`` of the module docstring; needs a headless OpenGL 3.3 context)

    Returns
    -------
    dict (JSON-serialisable, also written as ``compare-brdf.json``) with keys
    ``benchmark`` ("compare_brdf"), ``env`` (name), ``size``, ``pixels`` (sphere pixels),
    ``device``, ``ref_spp``, ``seed``, ``methods``, ``materials``, ``settings`` (chains,
    lobes, samples), ``setup_seconds`` (one-time work, excluded from fps),
    ``table`` (rows ``{material, method, psnr, rel_l2, fps, seconds, noise_share}``; the
    reference row has ``psnr``/``rel_l2``/``noise_share`` None), ``reference_noise`` (per
    material ``{material, rel_stderr, psnr_ceiling, exposure}``), ``goals`` (``psnr_ours_ge_fis``
    per material, ``all_psnr_ours_ge_fis``, ``ours_faster_than_fis_per_material``, and
    ``ours_faster_than_fis``: the summed shading time over all materials; with
    ``backend="both"`` also ``gl_psnr_ours_ge_fis``, ``gl_all_psnr_ours_ge_fis``,
    ``gl_ours_faster_than_fis_per_material`` and ``gl_ours_faster_than_fis``), ``image`` and
    ``json`` (paths), ``backend``, ``gl`` (None, or the GL renderer string and timing rule),
    ``machine``.
    """
    dev, out = _check_arguments(out, size=size, ref_spp=ref_spp, device=device, backend=backend)
    mats = _materials(alphas, aniso)
    gl_ctx = None
    if backend == "both":
        gl_ctx = create_context()  # fails early, with its reason, where there is no OpenGL
    out.mkdir(parents=True, exist_ok=True)
    env_map = _load_env(env, dev)
    setup, models, res, pf, chain, sampler = _prepare(mats, env_map, dev)

    hits = sphere_hits(size, device=dev)
    mask = hits["mask"]
    n, v, tg = (hits[k][mask] for k in ("normals", "views", "tangents"))  # (P, 3) each
    names = METHODS + (GL_METHODS if gl_ctx is not None else ())

    table: list[dict] = []
    noise: list[dict] = []
    goals: dict[str, Any] = {"psnr_ours_ge_fis": {}, "ours_faster_than_fis_per_material": {}}
    images: list[list[np.ndarray]] = []
    for (label, b), model in zip(mats, models, strict=True):
        runs = {
            "ours": lambda model=model: shade(model, pf, n, v, tangents=tg),
            "ours_mip": lambda model=model: shade(model, chain, n, v, tangents=tg),
            "fis40": lambda b=b: shade_fis(b, chain, n, v, tangents=tg, samples=FIS_SAMPLES),
            "wang09": lambda b=b: shade_wang09(b, pf, n, v),
        }
        sync(dev)
        t0 = time.perf_counter()
        ref, se = shade_reference(
            b, env_map, n, v, tangents=tg, spp=ref_spp, seed=seed, sampler=sampler
        )
        sync(dev)
        ref_seconds = time.perf_counter() - t0  # one run: it is the slow, offline method
        got, secs = _timed_all(runs, REPEATS, dev)
        got["reference"], secs["reference"] = ref, ref_seconds
        if gl_ctx is not None:
            _run_gl(gl_ctx, model, b, pf, chain, size, mask, got, secs)
        rows, noise_row, row_imgs = _score_material(label, names, got, secs, se, mask)
        table += rows
        noise.append(noise_row)
        images.append(row_imgs)
        _material_goals(goals, label, {r["method"]: r for r in rows}, gl=gl_ctx is not None)
    _overall_goals(goals, table, gl=gl_ctx is not None)
    gl_info = None
    if gl_ctx is not None:
        gl_info = {
            "renderer": str(gl_ctx.info.get("GL_RENDERER", "")),
            "timing": f"frames of {size}x{size} back to back, one ctx.finish(), "
            f">= {GL_MIN_SECONDS:g} s, best of {GL_ROUNDS} alternating rounds",
            "fis_mipmaps": "glGenerateMipmap (2 x 2 means) from the mip chain's level 0",
        }
        gl_ctx.release()

    png = out / "compare-brdf.png"
    grid = np.concatenate([np.concatenate(r, 1) for r in images], 0)
    _write_png(grid, png)
    result = {
        "benchmark": "compare_brdf",
        "env": str(getattr(env_map, "name", "envmap")),
        "size": size,
        "pixels": int(mask.sum()),
        "device": str(dev),
        "ref_spp": ref_spp,
        "seed": seed,
        "methods": list(METHODS) + (list(GL_METHODS) if gl_info is not None else []),
        "materials": [label for label, _ in mats],
        "settings": {
            "lobes": {label: m.n_lobes for (label, _), m in zip(mats, models, strict=True)},
            "prefilter_base_res": res,
            "mip_base_res": res,
            "coverage": COVERAGE,
            "fis_samples": FIS_SAMPLES,
            "timing_repeats": REPEATS,
            "psnr": "display sRGB of clip(k x), k = 1 / p99 reference luminance, peak 1",
            "grid": "rows materials; columns "
            + ", ".join(METHODS)
            + f", then |display difference| x {DIFF_GAIN:g} of "
            + ", ".join(METHODS[1:]),
        },
        "setup_seconds": setup,
        "table": table,
        "reference_noise": noise,
        "goals": goals,
        "image": str(png),
        "json": str(out / "compare-brdf.json"),
        "backend": backend,
        "gl": gl_info,
        "machine": machine(str(dev)),
    }
    _write_json(result, out / "compare-brdf.json")
    return result


def _check_arguments(
    out: Any, *, size: Any, ref_spp: Any, device: Any, backend: Any
) -> tuple[torch.device, Path]:
    """``device`` as a torch device and ``out`` as a path, once the arguments are checked."""
    if not isinstance(size, int) or isinstance(size, bool) or size < 4:
        raise InputError("size", f"must be an integer >= 4, got {size!r}")
    if not isinstance(ref_spp, int) or isinstance(ref_spp, bool) or ref_spp < 16:
        raise InputError("ref_spp", f"must be an integer >= 16, got {ref_spp!r}")
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError):
        raise InputError("device", f"not a torch device: {device!r}") from None
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(str(out), "must be a folder")
    if backend not in BACKENDS:
        raise InputError("backend", f"must be one of {', '.join(BACKENDS)}, got {backend!r}")
    return dev, out


def _prepare(mats: list, env_map: Any, dev: torch.device) -> tuple:
    """The one-time work before any shading, timed: the fits of ``mats`` (one batch per lobe
    count), the prefiltered chain, the mip chain and the environment sampler. Returns
    ``(setup seconds, models, chains' base resolution, prefiltered, mip chain, sampler)``."""
    setup: dict[str, float] = {}
    t0 = time.perf_counter()
    iso = [is_isotropic(b) for _, b in mats]
    models: list[Any] = [None] * len(mats)
    for flag, lobes in ((True, LOBES), (False, ANISO_LOBES)):
        idx = [i for i, f in enumerate(iso) if f == flag]
        if idx:
            got = fit_many([mats[i][1] for i in idx], n_lobes=lobes, device=dev)
            for i, m in zip(idx, got, strict=True):
                models[i] = m
    setup["fit"] = time.perf_counter() - t0
    res = _base_res(env_map)
    t0 = time.perf_counter()
    pf = prefilter(env_map, base_res=res)
    setup["prefilter"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    chain = mip_chain(env_map, base_res=res)
    setup["mip_chain"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    sampler = EnvSampler(env_map)
    setup["env_sampler"] = time.perf_counter() - t0
    return setup, models, res, pf, chain, sampler


def _score_material(
    label: str, names: tuple, got: dict, secs: dict, se: torch.Tensor, mask: torch.Tensor
) -> tuple[list[dict], dict, list[np.ndarray]]:
    """One material's table rows (``names`` in order), its reference-noise record and its row
    of the image grid, from the sphere pixels ``got`` (``(P, 3)`` per method, the reference's
    standard errors ``se``) and the seconds ``secs`` of each method."""
    ref = got["reference"]
    k = _exposure(ref)
    d_ref = display(ref, k)
    # the reference's noise seen through the display curve (central difference)
    d_noise = 0.5 * (display(ref + se, k) - display((ref - se).clamp_min(0), k))
    mse_noise = float((d_noise**2).mean())
    ref_norm = float(ref.double().norm())
    noise = {
        "material": label,
        "rel_stderr": float(se.double().norm()) / max(ref_norm, DIVISOR_F32),
        "psnr_ceiling": psnr_from_mse(mse_noise) if mse_noise > 0 else None,
        "exposure": k,
    }
    rows, row_imgs = [], []
    for name in names:
        x = got[name]
        row = {"material": label, "method": name, "fps": 1 / secs[name], "seconds": secs[name]}
        if name == "reference":
            row.update(psnr=None, rel_l2=None, noise_share=None)
        else:
            mse = float(((display(x, k) - d_ref) ** 2).mean())
            row["psnr"] = psnr_from_mse(mse)
            row["rel_l2"] = relative_l2(x, ref)
            row["noise_share"] = mse_noise / mse if mse > 0 else None
        rows.append(row)
        if name in METHODS:
            row_imgs.append(_tile(x, mask, k))
    for name in METHODS[1:]:
        row_imgs.append(_tile(got[name], mask, k, diff_to=ref))
    return rows, noise, row_imgs


def _material_goals(goals: dict, label: str, rows: dict, *, gl: bool) -> None:
    """One material's goals into ``goals``, from its rows by method: ours against FIS-40 in
    PSNR and fps (and the GLSL rows' with ``gl``)."""
    goals["psnr_ours_ge_fis"][label] = bool(rows["ours"]["psnr"] >= rows["fis40"]["psnr"])
    goals["ours_faster_than_fis_per_material"][label] = bool(
        rows["ours"]["fps"] > rows["fis40"]["fps"]
    )
    if gl:
        goals.setdefault("gl_psnr_ours_ge_fis", {})[label] = bool(
            rows["ours_gl"]["psnr"] >= rows["fis40_gl"]["psnr"]
        )
        goals.setdefault("gl_ours_faster_than_fis_per_material", {})[label] = bool(
            rows["ours_gl"]["fps"] > rows["fis40_gl"]["fps"]
        )


def _overall_goals(goals: dict, table: list[dict], *, gl: bool) -> None:
    """The goals over all materials into ``goals``: every material's PSNR goal, and the total
    shading time of ours against FIS's (one frame of each material); the GLSL rows' with
    ``gl``."""
    goals["all_psnr_ours_ge_fis"] = all(goals["psnr_ours_ge_fis"].values())
    total = {m: sum(r["seconds"] for r in table if r["method"] == m) for m in ("ours", "fis40")}
    goals["ours_faster_than_fis"] = bool(total["ours"] < total["fis40"])
    if gl:
        goals["gl_all_psnr_ours_ge_fis"] = all(goals["gl_psnr_ours_ge_fis"].values())
        total = {m: sum(r["seconds"] for r in table if r["method"] == m) for m in GL_METHODS}
        goals["gl_ours_faster_than_fis"] = bool(total["ours_gl"] < total["fis40_gl"])


def _run_gl(ctx, model, brdf, pf, chain, size: int, mask, got: dict, secs: dict) -> None:
    """Render and time ``GL_METHODS`` for one material into ``got`` (sphere pixels ``(P, 3)``,
    as the torch rows) and ``secs`` (seconds per frame)."""
    rs = {
        "ours_gl": GLSGBRDFRenderer(model, pf, size, size, ctx=ctx, method="ours"),
        "fis40_gl": GLSGBRDFRenderer(
            model, pf, size, size, ctx=ctx, method="fis", brdf=brdf, chain=chain
        ),
    }
    try:
        for name, r in rs.items():
            img, _ = r.render()  # orthographic from +Z: the rays of sphere_hits
            got[name] = img.to(mask.device)[mask]
        best = dict.fromkeys(rs, math.inf)
        for _ in range(GL_ROUNDS):
            for name, r in rs.items():
                best[name] = min(best[name], 1.0 / time_frames(r, GL_MIN_SECONDS)["fps"])
        secs.update(best)
    finally:
        for r in rs.values():
            r.release()


def _tile(x: torch.Tensor, mask: torch.Tensor, k: float, diff_to: Any = None) -> np.ndarray:
    """An ``(H, W, 3)`` display image of sphere pixels ``x (P, 3)`` (or of its difference to
    ``diff_to``, amplified), black off the sphere."""
    if diff_to is None:
        d = display(x, k)
    else:
        d = ((display(x, k) - display(diff_to, k)).abs() * DIFF_GAIN).clamp(0, 1)
    img = torch.zeros(*mask.shape, 3, dtype=torch.float64, device=x.device)
    img[mask] = d
    return img.cpu().numpy()
