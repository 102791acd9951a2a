"""What each command of the ``lobelight`` command line does, given its parsed arguments.

:mod:`lobelight.cli` parses and dispatches: ``run_NAME(args) -> dict`` runs the command
``NAME`` and returns its summary (printed as text, or as JSON under ``--json``). Inputs are
checked before any work starts (output folders, sizes, numbers), and bad ones raise
:class:`lobelight.errors.InputError`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib
import math
import os
import shutil
import sys
import tempfile
import time
import warnings
from pathlib import Path

import torch

from .. import bench
from .._io import IMAGE_LIMIT, check_input, check_outputs, note_input
from .._tol import DIVISOR_F64
from ..brdf import sharp_lobe
from ..data import envmap_names, resolve_envmap
from ..envmap import builtin
from ..envmap import load as load_env
from ..errors import InputError, one_line, os_problem
from ..fit import cluster, fit_model
from ..geometry import raycast
from ..geometry.camera import Camera
from ..model import load as load_model
from ..progress import Reporter
from ..render import (
    Lighting,
    Renderer,
    auto_exposure,
    check_output_path,
    export_gltf,
    frame_names,
    gl_available,
    require_display,
    save_image,
    stored_camera,
    turntable,
    view,
)
from ..scene import Scene, default_camera
from ..scene import load as load_scene
from ..web import export_web, serve
from ._gallery import gallery_main
from ._limits import MAX_EXPOSURE
from ._size import check_frames, check_image, parse_size

__all__ = [
    "check_device",
    "run_bake",
    "run_bench",
    "run_compare",
    "run_compare_brdf",
    "run_demo",
    "run_export",
    "run_figure5",
    "run_gallery",
    "run_info",
    "run_lobes_demo",
    "run_render",
    "run_view",
    "use_rays",
]


def _lazy(module: str, name: str):
    """``name`` of ``module``, imported when first called: a command loads only what it runs
    (the studies and benchmarks pull in Mitsuba, numba and the cosine lobes, which a render's
    start would pay for otherwise)."""

    def call(*args, **kwargs):
        return getattr(importlib.import_module(module), name)(*args, **kwargs)

    call.__name__ = call.__qualname__ = name
    call.__doc__ = f"``{module}.{name}``, imported on the first call."
    return call


bench_all = _lazy("lobelight.bench.suite", "bench_all")
bench_brdf_fit = _lazy("lobelight.bench.brdf_fit", "bench_brdf_fit")
bench_lobes = _lazy("lobelight.bench.cosine", "bench_lobes")
bench_rays = _lazy("lobelight.bench.rays", "bench_rays")
bench_tables = _lazy("lobelight.bench.cosine", "bench_tables")
compare = _lazy("lobelight.studies.compare", "compare")
compare_brdf = _lazy("lobelight.studies.compare_brdf", "compare_brdf")
demo = _lazy("lobelight.studies.demo", "demo")
figure5 = _lazy("lobelight.studies.figure5", "figure5")
lobes_demo = _lazy("lobelight.studies.lobes_demo", "lobes_demo")

# --------------------------------------------------------------------------------------------
# feedback


def _progress(args) -> Reporter | None:
    """The commands' progress reporter: stderr, silent with ``--quiet``."""
    return None if args.quiet else Reporter()


def _note(args, text: str) -> None:
    """One line of context on stderr (not under ``--quiet``); names from files (a scene's) are
    escaped."""
    if not args.quiet:
        print(f"lobelight: {one_line(text)}", file=sys.stderr, flush=True)


def _said(load, *args, **kwargs):
    """``load(*args, **kwargs)``, with lobelight's warnings while it reads (what a file asks for
    and lobelight does not use, a parameter taken at its range's end) said in one
    ``lobelight: ...`` line on stderr each, even under ``--quiet``, without Python's
    source-line trailer."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = load(*args, **kwargs)
    for w in caught:
        text = str(w.message)
        if issubclass(w.category, UserWarning) and text.startswith("lobelight: "):
            print(one_line(text), file=sys.stderr, flush=True)  # it may quote the file's names
        else:  # someone else's: shown as Python would have
            warnings.showwarning(w.message, w.category, w.filename, w.lineno)
    return out


def _load_scene(args, scene: str, *, material=None):
    """The scene ``scene`` (:func:`lobelight.scene.load`) on ``args.device``, its warnings said
    as :func:`_said` says them."""
    sc = _said(load_scene, scene, device=args.device, material=material)
    if material is not None and sc.material_records:
        names = ", ".join(repr(r["name"]) for r in sc.material_records)
        _note(args, f"--material replaces the materials of the glTF file ({names})")
    return sc


def _material_rows(records) -> list[dict]:
    """A model's or scene's glTF material records (:attr:`lobelight.scene.Scene.material_records`)
    as table rows: name, model, vertices, textures (slot names without ``Texture``, comma
    separated; ``-`` for none), override (``-`` for none)."""
    rows = []
    for r in records if isinstance(records, list | tuple) else []:
        if not isinstance(r, dict):
            continue
        slots = r.get("textures") or []
        textures = [str(t).removesuffix("Texture") for t in slots if isinstance(t, str)]
        rows.append(
            {
                "name": str(r.get("name", "")),
                "model": str(r.get("model", "")),
                "vertices": r.get("vertices", ""),
                "textures": ", ".join(textures) or "-",
                "override": str(r.get("override") or "-"),
            }
        )
    return rows


#: The largest ``--camera`` coordinate: float32 squares of it stay finite (and a mesh's
#: coordinates are bounded alike).
_MAX_COORDINATE = 1e15


def _camera_from(text: str | None, provenance: dict, mesh):
    """``--camera`` (``ox,oy,oz:tx,ty,tz[:fov]``), else the model's stored camera, else the
    mesh's default framing; a stored camera that is no camera is said on stderr."""
    if text is not None and not text.strip():
        raise InputError("--camera", "is empty: expected 'ox,oy,oz:tx,ty,tz[:fov]'")
    if text:
        try:
            parts = [[float(x) for x in p.split(",")] for p in text.split(":")]
            origin, target = parts[0], parts[1]
            fov = parts[2][0] if len(parts) > 2 else 40.0
            ok = len(origin) == 3 and len(target) == 3 and len(parts) <= 3
            ok = ok and all(abs(v) <= _MAX_COORDINATE for v in (*origin, *target, fov))
        except (ValueError, IndexError):
            ok = False
        if not ok:
            raise InputError(
                "--camera",
                f"expected 'ox,oy,oz:tx,ty,tz[:fov]' with coordinates within "
                f"+-{_MAX_COORDINATE:g}, got {text!r}",
            )
        try:
            return Camera.look_at(origin, target, fov=fov)
        except InputError as e:  # the camera's own checks: said of the flag
            raise InputError("--camera", f"{e.what}: {e.problem}") from None
    try:
        cam = stored_camera(provenance)
    except (TypeError, ValueError, InputError) as e:
        cam = None
        print(f"lobelight: the model's camera is not one ({one_line(str(e))[:200]}): the "
              "mesh's default framing instead (--camera names one)", file=sys.stderr,
              flush=True)  # fmt: skip
    return default_camera(mesh) if cam is None else cam


def _env_source(path: str | None, provenance: dict | None = None) -> str:
    """The environment a command uses: ``--env`` (a file, ``builtin`` or a bundled map's name),
    else the model's stored one (a scene file's or ``bake --env``'s) while its file exists, else
    ``"builtin"``."""
    if path is not None:
        if not str(path).strip():
            raise InputError(
                "--env", "is empty: give a map file, a bundled map's name or 'builtin'"
            )
        return str(path)
    stored = (provenance or {}).get("environment", "builtin")
    if not isinstance(stored, str) or stored == "builtin" or Path(stored).is_file():
        return stored if isinstance(stored, str) else "builtin"
    # the file the model was baked under is not here (the model moved to another machine, or
    # lobelight did): the bundled map of its name, else the built-in sky, said once
    name = Path(stored).stem
    source = name if name in envmap_names() else "builtin"
    if stored not in _MISSING_MAPS_SAID:
        _MISSING_MAPS_SAID.add(stored)
        instead = "the built-in sky" if source == "builtin" else f"the bundled map {name!r}"
        print(f"lobelight: the model's map {one_line(stored)!r} is not here: lit by {instead} "
              "(--env names another)", file=sys.stderr, flush=True)  # fmt: skip
    return source


#: The models' stored maps found missing, each said once per process.
_MISSING_MAPS_SAID: set[str] = set()


def _env_file(source: str) -> str:
    """``source`` as a file path (a bundled map's name resolves to its file), or an InputError
    naming the bundled maps where ``source`` is neither a file nor one of them; a path that is
    there but is no regular file (a FIFO, a device) is said to be what it is."""
    if os.path.isdir(source):
        raise InputError(source, "is a directory, not a map file")
    if os.path.lexists(source):
        check_input(source, limit=IMAGE_LIMIT)  # a FIFO or a dangling link: what it is
    resolved = resolve_envmap(source)
    if resolved is None:
        names = ", ".join(envmap_names())
        raise InputError(source, f"no such file, nor a bundled map's name ({names}) or 'builtin'")
    return resolved


def _env(path: str | None, provenance: dict | None = None):
    source = _env_source(path, provenance)
    return builtin() if source == "builtin" else load_env(_env_file(source))


def _backend(choice: str) -> str:
    """``--backend``: ``auto`` is ``gl`` where an OpenGL context opens, else ``torch``, and then
    says so in one line on stderr (even under ``--quiet``: the frames come slower)."""
    if choice != "auto":
        return choice
    if gl_available():
        return "gl"
    print(
        "lobelight: OpenGL (EGL) is not available here: rendering with the torch renderer "
        "(slower; the README names the system packages EGL needs)",
        file=sys.stderr,
        flush=True,
    )
    return "torch"


def _check_output(path: str | os.PathLike) -> Path:
    """An image path checked before any work: a known extension, an existing writable folder."""
    return check_output_path(path)


def _size(args) -> tuple[int, int]:
    """``--width``/``--height``, or ``--size N`` / ``--size WxH``, checked against this machine's
    memory (:func:`lobelight.cli._size.check_image`)."""
    if getattr(args, "size", None):
        return check_image("--size", *parse_size(args.size))
    return check_image("--width/--height", args.width, args.height)


def _output_folder(path, *, beside: bool = False) -> Path:
    """``-o`` of a command that writes a folder, checked before any work: a folder or nothing
    yet (then made by the command), never a file (an input least of all), in a folder that
    exists; the command must be able to write into it, or with ``beside`` (a folder written
    whole beside it and renamed into place) into the folder that holds it. A path the system
    cannot look up (too long a name, a loop of links) is refused with the system's reason."""
    out = Path(path)
    check_outputs(out)
    try:
        if out.is_symlink() and not out.exists():
            raise InputError(str(out), "is a symbolic link to nothing (or to a loop of links)")
        if out.exists() and not out.is_dir():
            raise InputError(str(out), "is a file, not a folder: name a folder for the outputs")
        parent = out.parent
        if parent.exists() and not parent.is_dir():
            raise InputError(str(out), f"{str(parent)!r} is a file, not a folder")
        if not parent.is_dir():
            raise InputError(str(out), f"the directory {str(parent)!r} does not exist")
        here = out if out.is_dir() and not beside else parent
        if not os.access(here, os.W_OK | os.X_OK):
            raise InputError(str(out), f"the directory {str(here)!r} is not writable")
    except OSError as e:
        raise InputError(str(out), os_problem(e)) from None
    return out


def _check_base_res(args) -> int | str:
    """``--base-res``: ``auto`` or a power of two (its range is the parser's)."""
    n = args.base_res
    if n == "auto":
        return n
    if n & (n - 1):
        raise InputError("--base-res", f"must be a power of two, got {n}")
    return n


def _model_path(scene: str, output: str | None) -> Path:
    """``-o`` exactly as given, else ``NAME.lobelight.npz`` in the working folder (a built-in
    name's ``:`` as ``-``: ``knot:2`` bakes to ``knot-2.lobelight.npz``)."""
    if output:
        if output.endswith(("/", os.sep)):
            raise InputError(output, "is a directory: name the model file (-o DIR/NAME.npz)")
        return _writable_file(Path(output))
    stem = Path(str(scene)).stem.replace(":", "-")
    return _writable_file(Path(f"{stem}.lobelight.npz"))


def _writable_file(out: Path) -> Path:
    """``out`` if a file can be written there (checked before any work), else an InputError."""
    try:
        if out.is_dir():
            raise InputError(str(out), "is a directory: name the file (-o DIR/NAME)")
        if not out.parent.is_dir():
            raise InputError(str(out), f"the directory {str(out.parent)!r} does not exist")
        if not os.access(out.parent, os.W_OK | os.X_OK):
            raise InputError(str(out), f"the directory {str(out.parent)!r} is not writable")
    except OSError as e:
        raise InputError(str(out), os_problem(e)) from None
    return out


def _check_gltf_output(path: str) -> Path:
    """``--gltf``: a ``.glb`` in an existing, writable folder, not a folder, checked before any
    work."""
    out = Path(path)
    if out.suffix.lower() != ".glb":
        raise InputError(str(out), "--gltf writes a glTF binary: name a .glb file")
    return _writable_file(out)


def run_export(args) -> dict:
    if args.web is not None:
        return _run_export_web(args)
    out = _check_gltf_output(args.gltf)
    _check_base_res(args)
    if args.env is not None and len(args.env) > 1:
        raise InputError("--env", "--gltf writes one image-based light: give one map")
    m = _said(load_model, args.model)
    lighting = None
    if args.env is not None:
        lighting = Lighting(_env(args.env[0]), base_res=args.base_res, device=args.device)
    check_outputs(out)  # the model and the map were read: neither is written over
    t0 = time.perf_counter()
    info = export_gltf(m, out, lighting=lighting, float16=args.float16)
    return {
        "command": "export",
        "output": str(out),
        "format": "gltf",
        "environment": None if args.env is None else _env_source(args.env[0]),
        "float16": args.float16,
        **info,
        "seconds": time.perf_counter() - t0,
    }


def _web_inputs(args, m) -> tuple[list, list[str]]:
    """``--env`` maps of a web export (default: the model's own, else the built-in sky) and
    the paths read: the model file and the map files."""
    sources = [_env_source(path, m.provenance) for path in (args.env or [None])]
    envs = [builtin() if s == "builtin" else load_env(_env_file(s)) for s in sources]
    inputs = [args.model] + [_env_file(s) for s in sources if s != "builtin"]
    return envs, inputs


def _run_export_web(args) -> dict:
    """``export MODEL --web DIR``: the viewer's folder, written atomically."""
    _check_base_res(args)
    out = _output_folder(args.web, beside=True)  # written whole beside it, then renamed
    m = _said(load_model, args.model)
    envs, inputs = _web_inputs(args, m)
    t0 = time.perf_counter()
    info = export_web(
        m,
        out,
        envs,
        base_res=args.base_res,
        sun=args.sun,
        device=args.device,
        inputs=inputs,
        float16=args.float16,
    )
    return {
        "command": "export",
        "format": "web",
        "environments": [e.name for e in envs],
        "float16": args.float16,
        **info,
        "open": f"file://{out.resolve()}/index.html",
        "seconds": time.perf_counter() - t0,
    }


def run_bake(args) -> dict:
    out = _model_path(args.scene, args.output)  # checked before any work
    if args.indirect_paths < 0:
        raise InputError("--indirect-paths", f"must be >= 0, got {args.indirect_paths}")
    if args.bounces < 0:
        raise InputError("--bounces", f"must be >= 0, got {args.bounces}")
    if not args.checkpoint_every >= 0:  # NaN too
        raise InputError("--checkpoint-every", f"must be >= 0 seconds, got {args.checkpoint_every}")
    if not (math.isfinite(args.memory_gb) and args.memory_gb > 0):
        raise InputError("--memory-gb", f"must be a positive number, got {args.memory_gb}")
    prog = _progress(args)
    sc = _load_scene(args, args.scene, material=args.material)
    if args.env:  # the model's default lighting (render, view, compare), as a scene file's
        env_file = _env_file(args.env)
        if args.env != "builtin":
            load_env(env_file)  # checked at the door: missing, unreadable, NaN/Inf, bad shape
            env_file = str(Path(env_file).resolve())
        sc = dataclasses.replace(sc, environment=env_file)
    if sc.environment != "builtin":
        note_input(sc.environment)  # named by the model, read by render: an input too
    ckpt = out.with_name(out.name + ".ckpt")
    # every file the scene brought was read: none of them may be written over
    check_outputs(out, ckpt)
    if out.suffix.lower() != ".npz":  # after the inputs' check: "is the input" says more
        raise InputError(str(out), "a model file is an .npz archive: name it NAME.npz")
    if ckpt.exists() and not ckpt.is_file():
        raise InputError(str(ckpt), "is where the bake keeps its checkpoint, and is not a file")
    if ckpt.exists():
        _note(args, f"checkpoint {ckpt} found: resumed where it is this bake's (the same scene "
              "and settings), else the bake starts over")  # fmt: skip
    _note(
        args, f"baking {sc.name}: {sc.mesh.n_vertices} vertices, {args.gaussians} Gaussian(s)/view"
    )
    t0 = time.perf_counter()
    with contextlib.ExitStack() as stack:
        client = None
        if args.cluster is not None or args.workers is not None:
            client = stack.enter_context(cluster(args.cluster, workers=args.workers))
        m = fit_model(
            sc,
            args.gaussians,
            memory_gb=args.memory_gb,
            device=args.device,
            indirect_paths=args.indirect_paths,
            bounces=args.bounces,
            progress=prog,
            seed=args.seed,
            checkpoint=ckpt,
            checkpoint_every=args.checkpoint_every,
            client=client,
            refine=args.refine,
        )
    # the glTF materials the scene brought (and what overrode them), for `lobelight info`
    m.provenance["materials"] = [dict(r) for r in sc.material_records]
    info = m.save(out, float16=args.float16)
    if ckpt.exists():
        ckpt.unlink()  # the model is whole on disk: the checkpoint has served
    return {
        "command": "bake",
        "model": str(out),
        "scene": sc.name,
        "environment": sc.environment,
        "material": sc.materials.model,
        "materials": _material_rows(sc.material_records),
        "vertices": m.mesh.n_vertices,  # the bake mesh's (refined: "refinement")
        "refinement": _refinement(m.provenance.get("refinement")),
        **_glossy_summary(m, m.provenance["n_gaussians"], m.provenance["n_gaussians_choice"]),
        "interreflection": _interreflection(m.provenance, _has_glossy(m)),
        "bytes": info["bytes"],
        "records_kept": info["records"],
        "records_total": info["records_total"],
        "relative_l2_error_mean": m.provenance["relative_l2_error_mean"],
        "relative_l2_error_hint": _ERROR_HINT if _has_glossy(m) else "no glossy lobe to fit",
        "flips_before": m.provenance["flips_before"],
        "flips_after": m.provenance["flips_after"],
        "separated_flips_before": m.provenance["separated_flips_before"],
        "separated_flips_after": m.provenance["separated_flips_after"],
        "stage_seconds": m.provenance["seconds"],
        "memory": m.provenance["memory"],
        "seconds": time.perf_counter() - t0,
    }


def run_info(args) -> dict:
    m = _said(load_model, args.model)
    p = Path(args.model)
    g = m.gaussians
    live = g.w.amax((-1, -2)) > 0
    return {
        "command": "info",
        "model": str(p),
        "bytes": p.stat().st_size,
        "vertices": m.mesh.n_vertices,
        "faces": int(m.mesh.faces.shape[0]),
        "refinement": _refinement(m.provenance.get("refinement")),
        "views": int(m.views.shape[0]),
        # how many and why the bake chose that many (older models' provenance does not say)
        **_glossy_summary(m, m.direct_gaussians, m.provenance.get("n_gaussians_choice")),
        "indirect_gaussians": m.indirect_gaussians if _has_glossy(m) else 0,
        "sh_coefficients": int(m.diffuse.shape[1]),
        "records_with_weight": int(live.sum()),
        "material": m.materials.model,
        # a glTF scene's materials, from the provenance (empty for other scenes)
        "materials": _material_rows(m.provenance.get("materials")),
        "reflection": _reflection(m),
        "albedo": _albedo(m),
        "interreflection": _interreflection(m.provenance, _has_glossy(m)),
        "provenance": m.provenance,
    }


def _refinement(record: dict | None) -> str:
    """What the bake did to the mesh (``lobelight.fit.refine_scene``'s record)."""
    if not record:
        return "not recorded"
    before, after = record["vertices"]
    if after == before:
        return f"none needed ({before} vertices as given)"
    rounds = record["rounds"]
    return (
        f"{before} -> {after} vertices: {rounds} round{'s' if rounds != 1 else ''} of splitting "
        "edges whose ends see the environment differently"
    )


def _albedo(m) -> str:
    """Where the renderers read the model's diffuse albedo: per vertex, or per pixel from its
    textures (how many, of what sizes)."""
    a = m.albedo
    if a is None:
        return "per vertex"
    sizes = ", ".join(f"{img.shape[1]}x{img.shape[0]}" for img in a.images[1:])
    n = len(a.images) - 1
    return f"per pixel from {n} texture{'s' if n != 1 else ''} ({sizes}), the rest per vertex"


def _reflection(m) -> str:
    """How the renderers shade the model's direct glossy light: per pixel for a sharp lobe
    (``lobelight.brdf.sharp_lobe``), with the object it sees shaded where it is seen, with or
    without its visibility and hit tiles in the file."""
    sl = sharp_lobe(m.materials.specular)
    if sl is None:
        return "fitted Gaussians"
    where = "per pixel"
    if sl.sharp is not None:
        n, v = int(sl.sharp.sum()), sl.sharp.shape[0]
        where = f"per pixel at {n} of {v} vertices (the sharp ones), fitted Gaussians at the rest"
    tiles, hits = m.visibility_held, m.hits_held
    if tiles is None or hits is None:
        return f"{where} (visibility and hit tiles computed from the mesh on first render)"
    return f"{where} (visibility and hit tiles {tiles.shape[1]}x{tiles.shape[2]} stored)"


def _interreflection(provenance: dict, glossy: bool = True) -> dict:
    """What a model baked of interreflection: diffuse bounces and indirect glossy paths (0 where
    its provenance does not say, and paths 0 for a material without a glossy lobe, which
    reflects no glossy light to trace)."""
    return {
        "bounces": int(provenance.get("bounces", 0)),
        "indirect_paths": int(provenance.get("indirect_paths", 0)) if glossy else 0,
    }


#: What a bake's ``relative_l2_error_mean`` means, beside the figure.
_ERROR_HINT = (
    "the glossy fit's error on its raw transport samples (visibility edges included), not "
    "the image's: 0 is exact, 0.3-0.6 is usual for plastics and metals (docs/results.md, "
    "'fit error'); lobelight compare scores the image against the path tracer"
)


def _has_glossy(m) -> bool:
    """Whether the model's material has a glossy (specular) lobe."""
    return m.materials.specular is not None


def _glossy_summary(m, n_gaussians, choice) -> dict:
    """``n_gaussians`` and ``n_gaussians_choice`` as a summary says them: 0 and the reason for a
    material without a glossy lobe (no Gaussian carries any light there)."""
    if not _has_glossy(m):
        return {"n_gaussians": 0, "n_gaussians_choice": "diffuse material: no glossy lobe"}
    return {"n_gaussians": n_gaussians, "n_gaussians_choice": choice}


def _exposure(text: str) -> float | None:
    """``--exposure``: stops within +-:data:`lobelight.cli._limits.MAX_EXPOSURE`, or None for
    ``auto``."""
    if text == "auto":
        return None
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not abs(v) <= MAX_EXPOSURE:  # NaN too
        raise InputError(
            "--exposure",
            f"expected stops (-{MAX_EXPOSURE:g}..{MAX_EXPOSURE:g}) or 'auto', got {text[:40]!r}",
        )
    return v


def _render_outputs(args, width: int, height: int) -> list[Path]:
    """The files ``render`` writes, checked before any work: the image, or with
    ``--turntable`` the frames and the animation in the folder ``-o``."""
    if args.turntable is None:
        return [_check_output(args.output)]
    check_frames("--turntable", args.turntable, width, height)
    out_dir = Path(args.output)
    if out_dir.suffix and not out_dir.is_dir():
        raise InputError(str(out_dir), "--turntable writes frames into a folder: -o DIR")
    _output_folder(out_dir)
    frames = [out_dir / name for name in frame_names(args.turntable)]
    return [out_dir, *frames, out_dir / "frames.gif"]


def run_render(args) -> dict:
    if args.spin is not None and args.turntable is None:
        raise InputError("--spin", "turns a turntable: give --turntable FRAMES as well")
    if args.output is None:
        args.output = "render.png" if args.turntable is None else "turntable"
    args.spin = args.spin or "camera"
    width, height = _size(args)
    exposure = _exposure(args.exposure)
    _check_base_res(args)
    if args.rotate is not None:
        args.rotate = math.remainder(args.rotate, 360.0)  # the same turn, in -180..180
    outputs = _render_outputs(args, width, height)
    m = _said(load_model, args.model, device=args.device)
    env = _env(args.env, m.provenance)
    check_outputs(*outputs)  # the model and the map were read: neither is written over
    cam = _camera_from(args.camera, m.provenance, m.mesh)
    backend = _backend(args.backend)
    t0 = time.perf_counter()
    with Renderer(
        m,
        env,
        width,
        height,
        backend=backend,
        base_res=args.base_res,
        sun=args.sun,
        samples=args.samples,
    ) as ren:
        t1 = time.perf_counter()
        parts = dict(
            diffuse=args.parts in ("both", "diffuse"),
            glossy=args.parts in ("both", "glossy"),
            background=args.background,
        )
        if args.turntable is not None:
            out_dir = Path(args.output)
            spin = turntable(
                ren,
                cam,
                args.turntable,
                out_dir,
                exposure=exposure,
                curve=args.tonemap,
                rotate=args.spin,
                light_rotation=args.rotate,
                progress=_progress(args),
                **parts,
            )
            t2 = time.perf_counter()
            return {
                "command": "render",
                "output": str(out_dir),
                **{k: v for k, v in spin.items() if k != "seconds"},
                "environment": _env_source(args.env, m.provenance),
                "backend": backend,
                "size": [width, height],
                "seconds_setup": t1 - t0,
                "seconds_render": t2 - t1,
            }
        img, mask = ren.render(cam, args.rotate, return_mask=True, **parts)
        t2 = time.perf_counter()
    if exposure is None:
        exposure = auto_exposure(img, mask, curve=args.tonemap)
    out = save_image(args.output, img, exposure=exposure, curve=args.tonemap)
    return {
        "command": "render",
        "output": str(out),
        "environment": _env_source(args.env, m.provenance),
        "backend": backend,
        "size": [width, height],
        "samples": args.samples,
        "exposure": exposure,
        "seconds_setup": t1 - t0,
        "seconds_render": t2 - t1,
    }


def run_view(args) -> dict:
    if args.web:
        return _run_view_web(args)
    try:
        require_display()  # no model is loaded where no window can open
    except InputError as e:
        raise InputError(
            "view",
            f"{e.problem}; or serve the viewer to a browser: lobelight view --web MODEL "
            "[--port P] (through an SSH tunnel from another machine)",
        ) from None
    # checked before a window opens; its stored environment is the default
    m = _said(load_model, args.model)
    width, height = _size(args)
    envs = [_env(path, m.provenance) for path in (args.env or [None])]  # each read at the door
    # the model's camera, as render takes it (a stored camera that is no camera is said)
    cam = _camera_from(None, m.provenance, m.mesh)
    return view(m, env=envs, width=width, height=height, sun=args.sun, camera=cam)


def _run_view_web(args) -> dict:
    """``view --web MODEL``: the viewer written to a temporary folder and served on
    localhost until interrupted; the folder is removed after."""
    _size(args)  # the page takes the browser's size, but a size given must still be one
    m = _said(load_model, args.model)
    envs, inputs = _web_inputs(args, m)
    tmp = Path(tempfile.mkdtemp(prefix="lobelight-web-"))
    # the lines for people go to stdout, or to stderr where stdout carries only the JSON
    out = sys.stderr if args.json else sys.stdout
    if not args.quiet:
        print("lobelight: writing the web viewer (the maps' prefiltered chains first)...",
              file=out, flush=True)  # fmt: skip
    try:
        info = export_web(m, tmp / "viewer", envs, sun=args.sun, inputs=inputs)
        serve(tmp / "viewer", args.port, announce=lambda line: print(line, file=out, flush=True))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return {"command": "view", "web": True, "bytes": info["bytes"], "port": args.port}


#: Scene arguments that are bare meshes: they bring a mesh and nothing else (their material is
#: a default, their map the built-in sky), so a model's own material and map take their place.
_BARE_MESH = (".ply", ".obj", ".stl", ".off")
#: Relative tolerance of "the same material": a model stored in half floats keeps parameters
#: to 2^-11 relative (about 5e-4); a material that differs on purpose differs far more.
_SAME_MATERIAL_RTOL = 1e-3
#: Tolerance of "the same mesh", relative to the bounding box's diagonal: half-float vertex
#: positions are within 2^-11 of it; another mesh with the same count is off by far more.
_SAME_MESH_RTOL = 1e-3


def run_compare(args) -> dict:
    width, height = _size(args)
    _check_base_res(args)
    if args.scene is None and args.model is None:
        raise InputError("scene", "give a scene, or --model MODEL to score a model's own scene")
    if args.model is not None and args.gaussians is not None:
        raise InputError(
            "--gaussians", "a model's own Gaussians are scored: give --gaussians without --model"
        )
    model = _said(load_model, args.model, device=args.device) if args.model else None
    sc = _compare_scene(args, model)
    env = _env(args.env) if args.env else None
    _output_folder(args.output)
    return {
        "command": "compare",
        # what is scored: the model's (or the scene's) map unless --env, and material
        "environment": args.env or sc.environment,
        "material": sc.materials.model,
        **compare(
            sc,
            model=model,
            n_gaussians=1 if args.gaussians is None else args.gaussians,
            env=env,
            width=width,
            height=height,
            spp=args.spp,
            light_rotation=args.rotate or None,
            backend=_backend(args.backend),
            baselines=tuple(args.baselines),
            base_res=args.base_res,
            out=args.output,
            device=args.device,
            sun=args.sun,
            progress=_progress(args),
        ),
    }


def _model_scene(model):
    """The scene a model was baked from, as the model holds it: its mesh and material, the map
    and camera of its provenance (the built-in sky where its map file is gone)."""
    prov = model.provenance or {}
    return Scene(
        mesh=model.mesh,
        materials=model.materials,
        environment=_env_file(_env_source(None, prov)),
        camera=_camera_from(None, prov, model.mesh),
        name=str(prov.get("scene", "model")),
    )


def _compare_scene(args, model):
    """The scene ``compare`` scores: the given one without a model; with a model, the model's
    own (:func:`_model_scene`), whose camera a scene file's replaces; a given scene whose mesh,
    material (a scene file's, a glTF's, a built-in's) or map (a scene file's) differs from the
    model's is refused, or scored as given with ``--allow-mismatch`` (its mesh must match)."""
    if model is None:
        return _load_scene(args, args.scene)
    own = _model_scene(model)
    if args.scene is None:
        return own
    sc = _load_scene(args, args.scene)
    _check_mesh(args.model, model.mesh, sc.mesh)
    suffix = Path(str(args.scene)).suffix.lower()
    scene_file = suffix in (".toml", ".json")
    problems = []
    if suffix not in _BARE_MESH and not _same_materials(sc.materials, model.materials):
        problems.append(
            f"the model's material is {model.materials.model}, the scene's "
            f"{sc.materials.model}" + (" with other parameters" if
            sc.materials.model == model.materials.model else "")
        )  # fmt: skip
    if scene_file and not _same_map(sc.environment, own.environment):
        problems.append(f"the model's map is {own.environment}, the scene's {sc.environment}")
    if problems and not args.allow_mismatch:
        raise InputError(
            str(args.scene),
            f"is not the scene {args.model} was baked with ({'; '.join(problems)}): leave the "
            "scene out to score the model's own, or pass --allow-mismatch to score this one",
        )
    if problems:
        _note(args, f"--allow-mismatch: scoring {args.scene} as given ({'; '.join(problems)})")
        return sc if scene_file or suffix not in _BARE_MESH else dataclasses.replace(
            sc, camera=own.camera
        )  # fmt: skip
    return dataclasses.replace(own, camera=sc.camera) if scene_file else own


def _check_mesh(model_path: str, mesh, scene_mesh) -> None:
    """Refuses a scene whose mesh is not the model's (vertex count, positions)."""
    if mesh.n_vertices != scene_mesh.n_vertices:
        raise InputError(
            model_path,
            f"has {mesh.n_vertices} vertices, the scene {scene_mesh.n_vertices}: not a model of "
            "this scene",
        )
    a = mesh.vertices.detach().cpu().double()
    b = scene_mesh.vertices.detach().cpu().double()
    diag = float((a.amax(0) - a.amin(0)).norm())
    if float((a - b).abs().max()) > _SAME_MESH_RTOL * max(diag, DIVISOR_F64):
        raise InputError(
            model_path, "has the scene's vertex count but other vertex positions: another mesh"
        )


def _same_materials(a, b) -> bool:
    """Whether two :class:`lobelight.scene.Materials` agree within :data:`_SAME_MATERIAL_RTOL`."""
    if a.model != b.model:
        return False
    if not _close(a.diffuse, b.diffuse):
        return False
    if a.specular is None or b.specular is None:
        return a.specular is None and b.specular is None
    return _same_params(a.specular.to_dict(), b.specular.to_dict())


def _same_params(x, y) -> bool:
    if isinstance(x, dict) and isinstance(y, dict):
        return x.keys() == y.keys() and all(_same_params(x[k], y[k]) for k in x)
    if isinstance(x, str) or isinstance(y, str):
        return x == y
    if isinstance(x, list) and x and isinstance(x[0], dict):
        return isinstance(y, list) and len(x) == len(y) and all(map(_same_params, x, y))
    try:
        return _close(
            torch.as_tensor(x, dtype=torch.float64), torch.as_tensor(y, dtype=torch.float64)
        )
    except (TypeError, ValueError):
        return x == y


def _close(a: torch.Tensor, b: torch.Tensor) -> bool:
    a, b = a.detach().cpu().double(), b.detach().cpu().double()
    try:
        a, b = torch.broadcast_tensors(a, b)
    except RuntimeError:
        return False
    return bool(torch.allclose(a, b, rtol=_SAME_MATERIAL_RTOL, atol=_SAME_MATERIAL_RTOL))


def _same_map(a: str, b: str) -> bool:
    """Whether two environments (``builtin``, a bundled name or a file) are the same map."""
    fa, fb = _env_file(str(a)), _env_file(str(b))
    if "builtin" in (fa, fb):
        return fa == fb
    return Path(fa).resolve() == Path(fb).resolve()


def run_compare_brdf(args) -> dict:
    size = _square(args, "compare-brdf")
    if args.env:
        note_input(_env_file(args.env))
    _output_folder(args.output)
    backend = {"torch": "torch", "gl": "both", "both": "both"}.get(args.backend)
    if backend is None:  # auto
        backend = "both" if gl_available() else "torch"
    return {
        "command": "compare-brdf",
        **compare_brdf(
            args.output,
            env=_env_file(args.env) if args.env else None,
            size=size,
            ref_spp=args.spp,
            device=args.device,
            backend=backend,
        ),
    }


def _square(args, command: str) -> int:
    w, h = _size(args)
    if w != h:
        raise InputError("--size", f"{command} renders square images: give one number, got {w}x{h}")
    return w


def run_figure5(args) -> dict:
    _output_folder(args.output)
    return {"command": "figure5", **figure5(args.output, device=args.device)}


def run_gallery(args) -> dict:
    check_image("--size", *parse_size(args.size))  # the references' size, at the door
    _check_base_res(args)
    if args.action == "run":
        _output_folder(args.output)
    return {"command": "gallery", "action": args.action, **gallery_main(args)}


def run_lobes_demo(args) -> dict:
    _output_folder(args.output)
    return {
        "command": "lobes-demo",
        **lobes_demo(
            args.output,
            frames=args.frames,
            size=_square(args, "lobes-demo"),
            device=args.device,
            fused=args.fused,
            progress=_progress(args),
        ),
    }


def run_bench(args) -> dict:
    w = args.what
    # each benchmark's own default count unless --repeats is given
    reps = {} if args.repeats is None else {"repeats": args.repeats}
    if w == "all":
        if args.budget is not None and not (math.isfinite(args.budget) and args.budget > 0):
            raise InputError("--budget", f"must be a positive number of seconds, got {args.budget}")
        if args.output is not None:
            check_outputs(_writable_file(Path(args.output)))
        return bench_all(
            device=args.device,
            output=args.output,
            budget_seconds=args.budget,
            progress=_progress(args),
        )
    if w in ("rays", "cluster", "web", "start"):
        return _run_bench_other(args)
    if w == "prefilter":
        _check_base_res(args)
        return bench.bench_prefilter(base_res=args.base_res, device=args.device, **reps)
    if w == "transport":
        return bench.bench_transport(scene=args.scene, device=args.device)
    if w == "fit":
        if not (math.isfinite(args.memory_gb) and args.memory_gb > 0):
            raise InputError("--memory-gb", f"must be a positive number, got {args.memory_gb}")
        return bench.bench_fit(
            scene=args.scene,
            material=args.fit_material,
            n_gaussians=args.gaussians,
            memory_gb=args.memory_gb,
            device=args.device,
            progress=_progress(args),
        )
    if w == "render":
        return bench.bench_render(
            backend=_backend(args.backend),
            sun=args.sun,
            samples=args.samples,
        )
    if w == "lobe-tables":
        return bench_tables(device=args.device)
    if w == "lobes":
        return bench_lobes(device=args.device, **reps)
    if w == "brdf-fit":
        return bench_brdf_fit(material=args.material, device=args.device)
    raise AssertionError(w)


def _run_bench_other(args) -> dict:
    """The benchmarks of ``bench`` with few options: rays, cluster, web, start."""
    w = args.what
    if w == "rays":
        return bench_rays(device=args.device)
    if w == "cluster":
        return bench.bench_cluster(scene=args.scene)
    if w == "web":
        return bench.bench_web()
    # start; --repeats: the warm runs
    return bench.bench_start(**({} if args.repeats is None else {"runs": args.repeats}))


def run_demo(args) -> dict:
    width, height = _size(args)
    _output_folder(args.output)
    return {
        "command": "demo",
        **demo(
            args.output,
            scene=args.scene,
            n_gaussians=args.gaussians,
            width=width,
            height=height,
            spp=args.spp,
            sun=args.sun,
            device=args.device,
            progress=_progress(args),
        ),
    }


def use_rays(engine: str) -> None:
    """``--rays``: the ray engine every ray caster of this command uses (auto, embree, warp)."""
    if engine == "warp" and not raycast.warp_available():
        raise InputError("--rays", "warp: NVIDIA Warp is not installed (pip install warp-lang)")
    raycast.set_default_engine(engine)


def check_device(text: str) -> str:
    """``--device`` checked: a torch device this machine has."""
    try:
        dev = torch.device(text)
    except (RuntimeError, ValueError):
        raise InputError("--device", f"not a torch device: {text!r} (cpu, cuda, cuda:1)") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise InputError("--device", f"{text!r}: this torch has no CUDA device")
    if dev.type not in ("cpu", "cuda"):
        raise InputError("--device", f"{text!r}: lobelight runs on cpu or cuda")
    return text
