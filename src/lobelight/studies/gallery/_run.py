"""The gallery run: bake each (mesh, material) once, render its scenes, score, write it down."""

from __future__ import annotations

import inspect
import json
import math
import statistics
import time
from pathlib import Path
from typing import Any

import torch

from ... import envmap
from ... import model as model_io
from ..._io import atomic_writer
from ..._tol import DIVISOR_F64
from ...errors import InputError
from ...fit import fit_model
from ...progress import resolve
from ...render import Lighting, Renderer, auto_base_res, gl_available, save_image
from ..score import highpass_energy, noise_highpass_energy, noise_psnr_display
from . import _references
from ._references import load_reference, reference_status
from ._scenes import (
    GalleryScene,
    data_folder,
    find_map,
    find_mesh,
    geometry_sha256,
    prepare_mesh,
    select,
    sha256_file,
    to_scene,
)
from ._score import LEGEND, score
from ._settings import SWEEP_MAX_SPP
from ._sweep import equal_quality, mitsuba_sweep, spp_levels

__all__ = ["DIFF_SCALE", "FORMAT", "FRAME_REPEATS", "METRICS", "TABLE", "run", "summarise"]

FORMAT = "lobelight-gallery"
VERSION = 1
#: The factor of the strips' error panels.
DIFF_SCALE = 4
#: The scores summarised, each with its better direction: "max", "min", or "one" (nearest 1).
METRICS = {
    "psnr_display": "max",
    "psnr_display_full": "max",
    "rel_l2": "min",
    "energy_ratio": "one",
    "highpass_ratio": "min",
    "speedup": "max",
}
#: Warm frames timed per scene (after the one that is scored); their median is the frame time.
FRAME_REPEATS = 3
#: The columns of the run's ``table`` (one row per scene) and where each comes from.
TABLE = {
    "scene": "the scene's name",
    "psnr_display": "dB, displayed PSNR over the object's pixels",
    "energy_ratio": "ours / reference, luminance over the object's pixels",
    "highpass_ratio": "ours / reference, high-pass energy over the object's pixels",
    "frame_s": "seconds of one of our frames (the scene's size and samples per pixel; not the "
    "bake, not the renderer's set-up)",
    "mitsuba_spp": "Mitsuba's samples per pixel at our psnr_display (the sweep's crossing)",
    "mitsuba_s": "Mitsuba's seconds at that many samples per pixel",
    "speedup": "mitsuba_s / frame_s",
    "bound": "'=' interpolated; '~' extrapolated past the sweep's largest spp (MSE = a / spp + "
    "the reference's noise), up to the reference's spp; '>=' not reached (lower bounds: the "
    "sweep's last render, or the reference's spp by that law); '<=' its first render already "
    "reached our score (upper bounds)",
}
#: fit_model's default Gaussians per view.
_DEFAULT_GAUSSIANS = inspect.signature(fit_model).parameters["n_gaussians"].default
#: fit_model's arguments that run sets itself.
_OWN = ("scene", "n_gaussians", "device", "progress", "checkpoint")


def _plain(x):
    """``x`` with non-finite floats as None (strict JSON)."""
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    return x


def _write_json(path: Path, d: dict) -> None:
    with atomic_writer(path) as f:
        f.write(json.dumps(_plain(d), indent=2, allow_nan=False).encode())


def _check_options(options: dict[str, Any] | None) -> dict[str, Any]:
    options = dict(options or {})
    known = set(inspect.signature(fit_model).parameters) - set(_OWN)
    for k in options:
        if k not in known:
            raise InputError("--fit-option", f"unknown option {k!r}; known: {sorted(known)}")
    try:
        return json.loads(json.dumps(options))  # as it reads back from the bake's record
    except (TypeError, ValueError):
        problem = f"values must be plain numbers or strings: {options}"
        raise InputError("--fit-option", problem) from None


def summarise(scores: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """The median of each of :data:`METRICS` over ``scores`` (``{scene: {metric: value}}``), and
    the worst scene and value of each (an energy ratio is worse the farther from 1)."""
    median: dict[str, float] = {}
    worst: dict[str, dict[str, Any]] = {}
    for k, better in METRICS.items():
        vals = {n: float(s[k]) for n, s in scores.items() if s.get(k) is not None}
        vals = {n: v for n, v in vals.items() if not math.isnan(v)}
        if not vals:
            continue
        median[k] = statistics.median(vals.values())
        if better == "max":
            name = min(vals, key=vals.__getitem__)
        elif better == "min":
            name = max(vals, key=vals.__getitem__)
        else:
            name = max(vals, key=lambda n: abs(math.log(max(vals[n], DIVISOR_F64))))
        worst[k] = {"scene": name, "value": vals[name]}
    return {"median": median, "worst": worst}


def _bake(
    group: list[GalleryScene], data: Path, models: Path, *, n_gaussians, options, device, progress
) -> tuple[Any, Any, dict[str, Any]]:
    """The model of one bake, its prepared mesh and its record: loaded when a model of the
    same settings is there, else fitted (resuming from its checkpoint) and saved. A bake of
    ``fit_model``'s default Gaussians per view records that default, so that a change to it
    bakes again."""
    first = group[0]
    mesh = prepare_mesh(first, data)
    settings = {
        "bake": first.bake_definition(),
        "geometry_sha256": geometry_sha256(mesh),
        "n_gaussians": first.gaussians if n_gaussians is None else n_gaussians,  # None: default
        "options": options,
    }
    if settings["n_gaussians"] is None:
        settings["fit_model_default"] = repr(_DEFAULT_GAUSSIANS)
    settings = json.loads(json.dumps(settings))
    path, meta = models / f"{first.bake}.npz", models / f"{first.bake}.json"
    try:
        record = json.loads(meta.read_text())
        if record.get("settings") == settings and sha256_file(path) == record.get("sha256"):
            return model_io.load(path, device=device), mesh, {**record, "resumed": True}
    except (OSError, ValueError, InputError):
        pass  # none, or not these settings, or damaged: bake
    ckpt = models / f"{first.bake}.checkpoint.npz"
    t = time.perf_counter()
    count = {} if settings["n_gaussians"] is None else {"n_gaussians": settings["n_gaussians"]}
    m = fit_model(
        to_scene(first, data, mesh),
        device=device,
        progress=progress,
        checkpoint=ckpt,
        **count,
        **options,
    )
    seconds = time.perf_counter() - t
    m.save(path)
    record = {
        "settings": settings,
        "sha256": sha256_file(path),
        "file": path.name,
        "seconds": seconds,
        "vertices": m.mesh.n_vertices,
        "fit_error": m.provenance.get("relative_l2_error_mean"),
        "gaussians": m.provenance.get("n_gaussians"),
        "gaussians_choice": m.provenance.get("n_gaussians_choice"),
        "fit_seconds": m.provenance.get("seconds"),
    }
    _write_json(meta, record)
    ckpt.unlink(missing_ok=True)
    return m, mesh, {**record, "resumed": False}


def run(
    scenes=None,
    *,
    data=None,
    refs,
    out,
    n_gaussians: int | str | None = None,
    samples: int = 16,
    backend: str = "auto",
    base_res: int | str = "auto",
    sun: bool = True,
    device=None,
    fit_options: dict[str, Any] | None = None,
    sweep: bool = True,
    sweep_max_spp: int = SWEEP_MAX_SPP,
    progress=True,
) -> dict[str, Any]:
    """Bake, render and score gallery scenes against their references; write ``gallery.json``
    and one strip per scene (``NAME.png``: reference | ours | error x :data:`DIFF_SCALE`, at
    the display exposure; the error over object pixels) into ``out``.

    Each (mesh, material) is baked once by :func:`lobelight.fit.fit_model` and kept in
    ``out/models/BAKE.npz`` with a record of its settings (``BAKE.json``): a rerun loads a
    model whose settings and checksum match, and an interrupted bake resumes from its
    checkpoint. Scenes are rendered at their reference's size with ``samples`` points per
    pixel (a box filter over the pixel, like the references' box filter) and scored on the
    reference's mask (:mod:`lobelight.studies.gallery`) less the pixels where some of our samples
    missed the object (``mask_partial_in_ours`` counts them; the scores' mask is one for both
    images). ``gallery.json`` is rewritten after each scene.

    Parameters
    ----------
    scenes : names (of scenes or bakes) or :class:`GalleryScene`; default all
    data : the data folder (default ``$LOBELIGHT_DATA``);  refs : the references folder
    n_gaussians : Gaussians per view of every bake, 1, 2, 3 or ``"auto"`` (None: each bake's
        own, :attr:`GalleryScene.gaussians`, else ``fit_model``'s default);  fit_options : more
        keyword arguments of ``fit_model``
    backend : "gl", "torch" or "auto" (gl where a context opens)
    base_res : face resolution of the sharpest prefiltered level, or ``"auto"`` (per bake and
        map, :func:`lobelight.render.auto_base_res`; each scene records the one it used);
        sun : shade the map's sun
        per pixel (:class:`lobelight.render.Lighting`)

    Returns
    -------
    the contents of ``gallery.json``: ``scenes`` (per scene: scores, bake seconds, vertices,
    fit error, ...), ``summary`` (``median`` and ``worst`` of :data:`METRICS`), ``settings``
    """
    data = data_folder(data)
    chosen = select(scenes)
    options = _check_options(fit_options)
    if isinstance(n_gaussians, bool) or n_gaussians not in (None, "auto", 1, 2, 3):
        raise InputError("--gaussians", f"must be 'auto', 1, 2 or 3, got {n_gaussians!r}")
    levels = spp_levels(sweep_max_spp) if sweep else []
    if backend == "auto":
        backend = "gl" if gl_available() else "torch"
    refs = Path(refs).expanduser()
    for sc in chosen:  # before any bake: a missing file or reference is found in seconds
        find_mesh(sc, data)
        find_map(sc, data)
        if reference_status(refs, sc, data)[0] != "ok":
            load_reference(refs, sc, data)  # raises, naming the scene and the command
    if sweep and chosen:  # and a missing Mitsuba too
        _references._mitsuba(None)
    out = Path(out).expanduser()
    if out.exists() and not out.is_dir():
        raise InputError("--output", f"is not a folder: {str(out)!r}")
    models = out / "models"
    models.mkdir(parents=True, exist_ok=True)
    progress = resolve(progress)
    note = getattr(progress, "note", None) or (lambda _: None)
    t0 = time.perf_counter()
    result: dict[str, Any] = {
        "format": FORMAT,
        "version": VERSION,
        "settings": {
            "n_gaussians": n_gaussians,
            "fit_options": options,
            "samples": samples,
            "backend": backend,
            "base_res": base_res,
            "sun": sun,
            "device": str(device or "cpu"),
            "sweep_spp": levels,
            "frame_repeats": FRAME_REPEATS,
        },
        "legend": {
            **LEGEND,
            "strip": f"reference | ours | |ours - reference| x {DIFF_SCALE} "
            "over object pixels, at the display exposure",
            "table": TABLE,
        },
        "scenes": {},
        "bakes": {},
    }
    groups: dict[str, list[GalleryScene]] = {}
    for sc in chosen:
        groups.setdefault(sc.bake, []).append(sc)
    render = {
        "samples": samples,
        "backend": backend,
        "base_res": base_res,
        "sun": sun,
        "levels": levels,
        "progress": progress,
    }
    lightings: dict[tuple, Any] = {}  # _lighting's
    for bake, group in groups.items():
        note(f"bake {bake}")
        m, mesh, record = _bake(
            group,
            data,
            models,
            n_gaussians=n_gaussians,
            options=options,
            device=device,
            progress=progress,
        )
        result["bakes"][bake] = record
        for sc in group:
            ref = load_reference(refs, sc, data)
            if ref.entry.get("geometry_sha256") != record["settings"]["geometry_sha256"]:
                raise InputError(
                    f"{sc.name}: reference",
                    "was rendered from another mesh than the bake's (a different mesh "
                    "library or data file); render the references again",
                )
            note(f"scene {sc.name}")
            result["scenes"][sc.name] = _scene(
                sc, m, mesh, record, ref, data, out, lightings, **render
            )
            if progress is not None:
                progress("gallery", len(result["scenes"]), len(chosen))
            result["summary"] = summarise(result["scenes"])
            result["table"] = [_row(n, e) for n, e in result["scenes"].items()]
            result["seconds"] = time.perf_counter() - t0
            _write_json(out / "gallery.json", result)
    return _plain(result)


def _row(name: str, e: dict[str, Any]) -> dict[str, Any]:
    """One scene's row of the run's ``table`` (:data:`TABLE`)."""
    eq = e.get("equal_quality") or {}
    return {
        "scene": name,
        "psnr_display": e.get("psnr_display"),
        "energy_ratio": e.get("energy_ratio"),
        "highpass_ratio": e.get("highpass_ratio"),
        "frame_s": e.get("frame_seconds"),
        "mitsuba_spp": eq.get("spp"),
        "mitsuba_s": eq.get("seconds"),
        "speedup": eq.get("speedup"),
        "bound": eq.get("bound"),
    }


def _lighting(sc: GalleryScene, m, data, lightings, *, base_res, sun) -> Lighting:
    """The scene's :class:`Lighting`, made once per map and base resolution (``"auto"``:
    the model's, :func:`lobelight.render.auto_base_res`); ``lightings`` holds the maps read,
    keyed ``(path,)``, and the lightings made, keyed ``(path, base_res)``."""
    path = str(find_map(sc, data))
    env = lightings.get((path,))
    if env is None:
        env = lightings[(path,)] = envmap.load(path)
    res = auto_base_res(m, env) if base_res == "auto" else base_res
    key = (path, res)
    if key not in lightings:
        lightings[key] = Lighting(env, base_res=res, device=m.device, sun=sun, sh_order=m.sh_order)
    return lightings[key]


def _render(m, lighting, view, w, h, *, samples, backend):
    """``(image, coverage, seconds, frame_seconds)``: our render of ``view`` with its
    coverage, the seconds of that first call (the renderer's set-up included) and the median
    of :data:`FRAME_REPEATS` warm frames after it."""
    t = time.perf_counter()
    with Renderer(m, lighting, w, h, backend=backend, samples=samples) as ren:
        img, cov = ren.render(view, return_mask="coverage")
        seconds = time.perf_counter() - t
        frames = []
        for _ in range(FRAME_REPEATS):
            t = time.perf_counter()
            ren.render(view)
            frames.append(time.perf_counter() - t)
    return img.cpu(), cov.cpu(), seconds, statistics.median(frames)


def _scene(
    sc: GalleryScene,
    m,
    mesh,
    record,
    ref,
    data,
    out,
    lightings,
    *,
    samples,
    backend,
    base_res,
    sun,
    levels,
    progress,
) -> dict[str, Any]:
    """Render one scene, score it, time Mitsuba at equal quality (``levels``: the sweep's
    samples per pixel, none for no sweep) and write its strip; its entry of
    ``gallery.json``."""
    lighting = _lighting(sc, m, data, lightings, base_res=base_res, sun=sun)
    h, w = ref.mask.shape
    img, cov, seconds, frame = _render(
        m, lighting, sc.view(), w, h, samples=samples, backend=backend
    )
    # the reference's fully covered pixels, less any of them where one of our samples missed
    # the object (the rasteriser's and the ray caster's silhouettes differ by rounding)
    partial = ref.mask & (cov < 1.0 - 0.5 / samples)
    mask = ref.mask & ~partial
    s = score(img, ref.image, mask)
    s["reference_noise_psnr_display"] = noise_psnr_display(
        ref.image, ref.stderr, mask, s["exposure"]
    )
    share = _noise_share(ref, mask, s["exposure"])
    s["reference_noise_highpass"] = share
    s["highpass_ratio_detail"] = (
        None
        if share is None
        else [s["highpass_ratio"] / (1 - f) if f < 1 else math.inf for f in share]
    )
    diff = (img - ref.image).abs() * mask[..., None] * DIFF_SCALE
    strip = torch.cat([ref.image, img, diff], 1)  # (H, 3 W, 3)
    save_image(out / f"{sc.name}.png", strip, exposure=s["exposure"])
    mitsuba, eq = None, None
    if levels:
        target = s["psnr_display"] if math.isfinite(s["psnr_display"]) else None
        mitsuba = mitsuba_sweep(
            to_scene(sc, data, mesh),
            ref,
            mask,
            s["exposure"],
            target,
            max_spp=levels[-1],
            progress=progress,
        )
        noise = s["reference_noise_psnr_display"]
        noise_mse = 10 ** (-noise / 10) if math.isfinite(noise) else 0.0
        cap = (ref.entry.get("settings") or {}).get("spp")
        eq = equal_quality(target, mitsuba["sweep"], frame, noise_mse=noise_mse, cap_spp=cap)
    e = ref.entry
    return {
        **s,
        "bake": sc.bake,
        "mesh": sc.mesh,
        "envmap": sc.envmap,
        "material": sc.material,
        "vertices": m.mesh.n_vertices,
        "base_res": lighting.base_res,
        "fit_error": record.get("fit_error"),
        "gaussians": record.get("gaussians"),
        "bake_seconds": record.get("seconds"),
        "render_seconds": seconds,
        "frame_seconds": frame,
        "equal_quality": eq,
        "mitsuba_sweep": mitsuba,
        "object_pixels": int(mask.sum()),
        # pixels of the reference's mask left out: some of our samples missed the object
        "mask_partial_in_ours": int(partial.sum()),
        "reference": {k: e.get(k) for k in ("settings", "variant", "mitsuba", "reference_noise")},
        "strip": f"{sc.name}.png",
    }


def _noise_share(ref, mask, exposure: float) -> list[float] | None:
    """``[low, high]``: the share of the reference's high-pass energy that its own noise is
    expected to make, its colour channels' noise taken as independent and as fully correlated
    (:func:`lobelight.studies.score.noise_highpass_energy`); None where it has none."""
    own = highpass_energy(ref.image, mask, exposure)
    if not own > 0:
        return None
    return [
        noise_highpass_energy(ref.image, ref.stderr, mask, exposure, correlated=c) / own
        for c in (False, True)
    ]
