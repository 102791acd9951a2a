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
from ...render import Lighting, Renderer, gl_available, save_image
from ..score import noise_psnr_display
from ._references import load_reference, reference_status
from ._scenes import (
    GalleryScene,
    data_folder,
    find_map,
    geometry_sha256,
    prepare_mesh,
    select,
    sha256_file,
    to_scene,
)
from ._score import LEGEND, score

__all__ = ["DIFF_SCALE", "FORMAT", "METRICS", "run", "summarise"]

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
}
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
) -> tuple[Any, dict[str, Any]]:
    """The model of one bake, and its record: loaded when a model of the same settings is
    there, else fitted (resuming from its checkpoint) and saved."""
    first = group[0]
    mesh = prepare_mesh(first, data)
    settings = {
        "bake": first.bake_definition(),
        "geometry_sha256": geometry_sha256(mesh),
        "n_gaussians": first.gaussians if n_gaussians is None else n_gaussians,
        "options": options,
    }
    settings = json.loads(json.dumps(settings))
    path, meta = models / f"{first.bake}.npz", models / f"{first.bake}.json"
    try:
        record = json.loads(meta.read_text())
        if record.get("settings") == settings and sha256_file(path) == record.get("sha256"):
            return model_io.load(path, device=device), {**record, "resumed": True}
    except (OSError, ValueError, InputError):
        pass  # none, or not these settings, or damaged: bake
    ckpt = models / f"{first.bake}.checkpoint.npz"
    t = time.perf_counter()
    m = fit_model(
        to_scene(first, data, mesh),
        settings["n_gaussians"],
        device=device,
        progress=progress,
        checkpoint=ckpt,
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
        "fit_seconds": m.provenance.get("seconds"),
    }
    _write_json(meta, record)
    ckpt.unlink(missing_ok=True)
    return m, {**record, "resumed": False}


def run(
    scenes=None,
    *,
    data=None,
    refs,
    out,
    n_gaussians: int | None = None,
    samples: int = 16,
    backend: str = "auto",
    base_res: int = 256,
    sun: bool = True,
    device=None,
    fit_options: dict[str, Any] | None = None,
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
    n_gaussians : Gaussians per view of every bake (None: each bake's own,
        :attr:`GalleryScene.gaussians`);  fit_options : more keyword arguments of ``fit_model``
    backend : "gl", "torch" or "auto" (gl where a context opens)
    base_res : face resolution of the sharpest prefiltered level;  sun : shade the map's sun
        per pixel (:class:`lobelight.render.Lighting`)

    Returns
    -------
    the contents of ``gallery.json``: ``scenes`` (per scene: scores, bake seconds, vertices,
    fit error, ...), ``summary`` (``median`` and ``worst`` of :data:`METRICS`), ``settings``
    """
    data = data_folder(data)
    chosen = select(scenes)
    options = _check_options(fit_options)
    if n_gaussians not in (None, 1, 2, 3):
        raise InputError("--gaussians", f"must be 1, 2 or 3, got {n_gaussians}")
    if backend == "auto":
        backend = "gl" if gl_available() else "torch"
    refs = Path(refs).expanduser()
    for sc in chosen:  # before any bake: a missing reference is found in seconds, not hours
        if reference_status(refs, sc, data)[0] != "ok":
            load_reference(refs, sc, data)  # raises, naming the scene and the command
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
        },
        "legend": {
            **LEGEND,
            "strip": f"reference | ours | |ours - reference| x {DIFF_SCALE} "
            "over object pixels, at the display exposure",
        },
        "scenes": {},
        "bakes": {},
    }
    groups: dict[str, list[GalleryScene]] = {}
    for sc in chosen:
        groups.setdefault(sc.bake, []).append(sc)
    lightings: dict[str, Lighting] = {}
    done = 0
    for bake, group in groups.items():
        note(f"bake {bake}")
        m, record = _bake(
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
            result["scenes"][sc.name] = _scene(
                sc,
                m,
                record,
                ref,
                data,
                out,
                lightings,
                samples=samples,
                backend=backend,
                base_res=base_res,
                sun=sun,
                device=device,
            )
            done += 1
            if progress is not None:
                progress("gallery", done, len(chosen))
            result["summary"] = summarise(result["scenes"])
            result["seconds"] = time.perf_counter() - t0
            _write_json(out / "gallery.json", result)
    return _plain(result)


def _scene(
    sc: GalleryScene,
    m,
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
    device,
) -> dict[str, Any]:
    """Render one scene, score it and write its strip; its entry of ``gallery.json``."""
    key = str(find_map(sc, data))
    if key not in lightings:
        env = envmap.load(key)
        lightings[key] = Lighting(
            env, base_res=base_res, device=m.device, sun=sun, sh_order=m.sh_order
        )
    h, w = ref.mask.shape
    t = time.perf_counter()
    with Renderer(m, lightings[key], w, h, backend=backend, samples=samples) as ren:
        img, cov = ren.render(sc.view(), return_mask="coverage")
    seconds = time.perf_counter() - t
    img, cov = img.cpu(), cov.cpu()
    # the reference's fully covered pixels, less any of them where one of our samples missed
    # the object (the rasteriser's and the ray caster's silhouettes differ by rounding)
    partial = ref.mask & (cov < 1.0 - 0.5 / samples)
    mask = ref.mask & ~partial
    s = score(img, ref.image, mask)
    s["reference_noise_psnr_display"] = noise_psnr_display(
        ref.image, ref.stderr, mask, s["exposure"]
    )
    diff = (img - ref.image).abs() * mask[..., None] * DIFF_SCALE
    strip = torch.cat([ref.image, img, diff], 1)  # (H, 3 W, 3)
    save_image(out / f"{sc.name}.png", strip, exposure=s["exposure"])
    e = ref.entry
    return {
        **s,
        "bake": sc.bake,
        "mesh": sc.mesh,
        "envmap": sc.envmap,
        "material": sc.material,
        "vertices": m.mesh.n_vertices,
        "fit_error": record.get("fit_error"),
        "bake_seconds": record.get("seconds"),
        "render_seconds": seconds,
        "object_pixels": int(mask.sum()),
        # pixels of the reference's mask left out: some of our samples missed the object
        "mask_partial_in_ours": int(partial.sum()),
        "reference": {k: e.get(k) for k in ("settings", "variant", "mitsuba", "reference_noise")},
        "strip": f"{sc.name}.png",
    }
