"""The ``lobelight`` command line: one entry point, ``--help`` everywhere, ``--json`` for machines.

Commands: ``demo``, ``bake``, ``info``, ``render``, ``view``, ``compare``, ``compare-brdf``,
``figure5``, ``lobes-demo``, ``bench``.

Every command takes ``--json`` (stdout carries only the JSON summary, or a JSON error object),
``--device`` and ``--quiet``. Progress goes to stderr: bars on a terminal, plain lines at most
every few seconds elsewhere (:mod:`lobelight.progress`). Flags share their names across
commands: ``-o/--output``, ``--width/--height``, ``--spp``, ``--sun/--no-sun``, ``--backend``;
older spellings (``--out``, ``--ref-spp``) are kept as aliases.

Exit codes: 0 success; 1 unexpected error; 2 bad input (one line on stderr naming the input and
the problem); 130 interrupted (Ctrl-C), 143 terminated (SIGTERM, as batch schedulers send it):
one line each, and a bake resumes from its checkpoint when run again.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import re
import signal
import sys
import threading
import time
from pathlib import Path

from ._size import check_pixels, parse_size
from .errors import InputError
from .progress import Reporter
from .studies.gallery._args import add_arguments as gallery_arguments

#: A bake's interreflection defaults, :data:`lobelight.transport.BOUNCES` and
#: :data:`lobelight.transport.INDIRECT_PATHS`, restated so that building the parser imports no
#: torch (tests/test_cli.py holds them equal).
_BOUNCES = 4
_INDIRECT_PATHS = 16

__all__ = ["main"]


# --------------------------------------------------------------------------------------------
# feedback


def _progress(args) -> Reporter | None:
    """The commands' progress reporter: stderr, silent with ``--quiet``."""
    return None if args.quiet else Reporter()


def _note(args, text: str) -> None:
    if not args.quiet:
        print(f"lobelight: {text}", file=sys.stderr, flush=True)


def _camera_from(text: str | None, provenance: dict, mesh):
    from .geometry.camera import Camera

    if text:
        try:
            parts = [[float(x) for x in p.split(",")] for p in text.split(":")]
            origin, target = parts[0], parts[1]
            fov = parts[2][0] if len(parts) > 2 else 40.0
            ok = len(origin) == 3 and len(target) == 3 and len(parts) <= 3
            ok = ok and all(math.isfinite(v) for v in (*origin, *target, fov))
        except (ValueError, IndexError):
            ok = False
        if not ok:
            raise InputError("--camera", f"expected 'ox,oy,oz:tx,ty,tz[:fov]', got {text!r}")
        return Camera.look_at(origin, target, fov=fov)
    cam = provenance.get("camera")
    if isinstance(cam, dict):
        try:
            return Camera(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in cam.items()})
        except (TypeError, ValueError, InputError):
            pass
    from .scene._scene import _default_camera

    return _default_camera(mesh)


def _env_source(path: str | None, provenance: dict | None = None) -> str:
    """The environment a command uses: ``--env`` (a file, ``builtin`` or a bundled map's name),
    else the model's stored one (a scene file's or ``bake --env``'s) while its file exists, else
    ``"builtin"``."""
    if path:
        return str(path)
    stored = (provenance or {}).get("environment", "builtin")
    if isinstance(stored, str) and stored != "builtin" and Path(stored).is_file():
        return stored
    return "builtin"


def _env_file(source: str) -> str:
    """``source`` as a file path (a bundled map's name resolves to its file); unresolved, as
    given, so that the loader names what is missing."""
    from .data import resolve_envmap

    return resolve_envmap(source) or source


def _env(path: str | None, provenance: dict | None = None):
    from .envmap import builtin, load

    source = _env_source(path, provenance)
    return builtin() if source == "builtin" else load(_env_file(source))


def _check_output(path: str | os.PathLike) -> Path:
    """An image path checked before any work: a known extension, an existing writable folder."""
    from .render import check_output_path

    return check_output_path(path)


def _size(args) -> tuple[int, int]:
    """``--width``/``--height``, or ``--size N`` / ``--size WxH`` (both checked)."""
    w, h = args.width, args.height
    if getattr(args, "size", None):
        w, h = parse_size(args.size)
    return check_pixels("--width", w), check_pixels("--height", h)


def _model_path(scene: str, output: str | None) -> Path:
    out = Path(output) if output else Path(f"{Path(str(scene)).stem}.lobelight.npz")
    out = Path(str(out).replace(":", "-"))
    if out.is_dir():
        raise InputError(str(out), "is a directory: name the model file (-o DIR/NAME.npz)")
    if not out.parent.is_dir():
        raise InputError(str(out), f"the directory {str(out.parent)!r} does not exist")
    if not os.access(out.parent, os.W_OK):
        raise InputError(str(out), f"the directory {str(out.parent)!r} is not writable")
    return out


def _cmd_bake(args) -> dict:
    from .fit import fit_model
    from .scene import load

    out = _model_path(args.scene, args.output)  # checked before any work
    if args.indirect_paths < 0:
        raise InputError("--indirect-paths", f"must be >= 0, got {args.indirect_paths}")
    if args.bounces < 0:
        raise InputError("--bounces", f"must be >= 0, got {args.bounces}")
    prog = _progress(args)
    sc = load(args.scene, device=args.device, material=args.material)
    if args.env:  # the model's default lighting (render, view, compare), as a scene file's
        from .envmap import load as load_env

        env_file = _env_file(args.env)
        if args.env != "builtin":
            load_env(env_file)  # checked at the door: missing, unreadable, NaN/Inf, bad shape
            env_file = str(Path(env_file).resolve())
        sc = dataclasses.replace(sc, environment=env_file)
    ckpt = out.with_name(out.name + ".ckpt")
    if ckpt.exists():
        _note(args, f"resuming from {ckpt}")
    _note(args, f"baking {sc.name}: {sc.mesh.n_vertices} vertices, {args.lobes} Gaussian(s)/view")
    t0 = time.perf_counter()
    m = fit_model(
        sc,
        args.lobes,
        device=args.device,
        indirect_paths=args.indirect_paths,
        bounces=args.bounces,
        progress=prog,
        seed=args.seed,
        checkpoint=ckpt,
    )
    info = m.save(out, float16=args.float16)
    if ckpt.exists():
        ckpt.unlink()  # the model is whole on disk: the checkpoint has served
    return {
        "command": "bake",
        "model": str(out),
        "scene": sc.name,
        "environment": sc.environment,
        "material": sc.materials.model,
        "vertices": sc.mesh.n_vertices,
        "n_lobes": args.lobes,
        "interreflection": _interreflection(m.provenance),
        "bytes": info["bytes"],
        "records_kept": info["records"],
        "records_total": info["records_total"],
        "relative_l2_error_mean": m.provenance["relative_l2_error_mean"],
        "flips_before": m.provenance["flips_before"],
        "flips_after": m.provenance["flips_after"],
        "separated_flips_before": m.provenance["separated_flips_before"],
        "separated_flips_after": m.provenance["separated_flips_after"],
        "seconds": time.perf_counter() - t0,
    }


def _cmd_info(args) -> dict:
    from .model import load

    m = load(args.model)
    p = Path(args.model)
    g = m.gaussians
    live = g.w.amax((-1, -2)) > 0
    return {
        "command": "info",
        "model": str(p),
        "bytes": p.stat().st_size,
        "vertices": m.mesh.n_vertices,
        "faces": int(m.mesh.faces.shape[0]),
        "views": int(m.views.shape[0]),
        "n_lobes": m.direct_lobes,
        "indirect_lobes": m.indirect_lobes,
        "sh_coefficients": int(m.diffuse.shape[1]),
        "records_with_weight": int(live.sum()),
        "material": m.materials.model,
        "interreflection": _interreflection(m.provenance),
        "provenance": m.provenance,
    }


def _interreflection(provenance: dict) -> dict:
    """What a model baked of interreflection: diffuse bounces and indirect glossy paths (a
    model from before interreflection was baked has no ``bounces``: none)."""
    return {
        "bounces": int(provenance.get("bounces", 0)),
        "indirect_paths": int(provenance.get("indirect_paths", 0)),
    }


def _exposure(text: str) -> float | None:
    """``--exposure``: stops, or None for ``auto``."""
    if text == "auto":
        return None
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not math.isfinite(v):
        raise InputError("--exposure", f"expected stops (a finite number) or 'auto', got {text!r}")
    return v


def _cmd_render(args) -> dict:
    from .model import load
    from .render import Renderer, auto_exposure, save_image, turntable
    from .render._gl import gl_available

    width, height = _size(args)
    exposure = _exposure(args.exposure)
    if not 1 <= args.samples <= 256:
        raise InputError("--samples", f"must be 1..256 samples per pixel, got {args.samples}")
    if args.rotate is not None and not math.isfinite(args.rotate):
        raise InputError("--rotate", f"must be a finite angle in degrees, got {args.rotate}")
    if args.turntable is not None:
        if args.turntable < 1:
            raise InputError("--turntable", f"must be >= 1 frames, got {args.turntable}")
        out_dir = Path(args.output)
        if out_dir.suffix and not out_dir.is_dir():
            raise InputError(str(out_dir), "--turntable writes frames into a folder: -o DIR")
        if not out_dir.parent.is_dir():
            raise InputError(str(out_dir), f"the directory {str(out_dir.parent)!r} does not exist")
    else:
        _check_output(args.output)
    m = load(args.model, device=args.device)
    env = _env(args.env, m.provenance)
    cam = _camera_from(args.camera, m.provenance, m.mesh)
    backend = args.backend
    if backend == "auto":
        backend = "gl" if gl_available() else "torch"
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
        exposure = auto_exposure(img, mask)
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


def _cmd_view(args) -> dict:
    from .model import load
    from .render._window import require_display, view

    require_display()  # no model is loaded where no window can open
    m = load(args.model)  # checked before a window opens; its stored environment is the default
    width, height = _size(args)
    return view(m, env=_env(args.env, m.provenance), width=width, height=height, sun=args.sun)


def _cmd_compare(args) -> dict:
    from .model import load as load_model
    from .scene import load
    from .studies.compare import compare

    width, height = _size(args)
    sc = load(args.scene, device=args.device)
    model = load_model(args.model, device=args.device) if args.model else None
    if model is not None and model.mesh.n_vertices != sc.mesh.n_vertices:
        raise InputError(
            args.model,
            f"has {model.mesh.n_vertices} vertices, the scene "
            f"{sc.mesh.n_vertices}: not a model of this scene",
        )
    return {
        "command": "compare",
        **compare(
            sc,
            model=model,
            n_lobes=args.lobes,
            env=_env(args.env) if args.env else None,
            width=width,
            height=height,
            spp=args.spp,
            light_rotation=args.rotate,
            backend=args.backend,
            baselines=tuple(args.baselines),
            base_res=args.base_res,
            out=args.output,
            device=args.device,
            sun=args.sun,
            progress=_progress(args),
        ),
    }


def _cmd_compare_brdf(args) -> dict:
    from .render._gl import gl_available
    from .studies.compare_brdf import compare_brdf

    size = _square(args, "compare-brdf")
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


def _cmd_figure5(args) -> dict:
    from .studies.figure5 import figure5

    return {"command": "figure5", **figure5(args.output, device=args.device)}


def _cmd_gallery(args) -> dict:
    from .studies.gallery import main_from_args

    return {"command": "gallery", "action": args.action, **main_from_args(args)}


def _cmd_lobes_demo(args) -> dict:
    from .studies.lobes_demo import lobes_demo

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


def _cmd_bench(args) -> dict:
    from .studies import bench

    w = args.what
    # each benchmark's own default count unless --repeats is given
    reps = {} if args.repeats is None else {"repeats": args.repeats}
    if w == "prefilter":
        return bench.bench_prefilter(base_res=args.base_res, device=args.device, **reps)
    if w == "transport":
        return bench.bench_transport(scene=args.scene, device=args.device)
    if w == "fit":
        return bench.bench_fit(scene=args.scene, n_lobes=args.lobes, device=args.device)
    if w == "render":
        return bench.bench_render(
            backend=args.backend if args.backend != "auto" else "gl",
            sun=args.sun,
            samples=args.samples,
        )
    if w == "lobe-tables":
        from .studies.bench_lobes import bench_tables

        return bench_tables(device=args.device)
    if w == "lobes":
        from .studies.bench_lobes import bench_lobes

        return bench_lobes(device=args.device, **reps)
    if w == "brdf-fit":
        from .studies.bench_brdf_fit import bench_fit

        return bench_fit(material=args.material, device=args.device)
    raise AssertionError(w)


def _cmd_demo(args) -> dict:
    from .studies.demo import demo

    width, height = _size(args)
    return {
        "command": "demo",
        **demo(
            args.output,
            scene=args.scene,
            n_lobes=args.lobes,
            width=width,
            height=height,
            spp=args.spp,
            sun=args.sun,
            device=args.device,
            progress=_progress(args),
        ),
    }


# --------------------------------------------------------------------------------------------
# parser


class _UsageError(Exception):
    """A command line argparse cannot parse: reported as bad input (exit 2)."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # argparse prints usage and exits; we report one line
        raise _UsageError(f"{self.prog}: {message}")


class _Help(argparse.ArgumentDefaultsHelpFormatter):
    """Shows each flag's default (where it has one) after its help."""

    def _get_help_string(self, action):
        if action.default in (None, False) or action.default is argparse.SUPPRESS:
            return action.help
        return super()._get_help_string(action)


def _parser() -> argparse.ArgumentParser:
    p = _Parser(
        prog="lobelight",
        description="Relight 3D objects under HDR environment lighting with spherical lobes.",
        epilog="Exit codes: 0 ok, 1 unexpected error, 2 bad input, 130 interrupted (Ctrl-C), "
        "143 terminated (SIGTERM).",
    )
    p.add_argument("--version", action="version", version=f"lobelight {_version()}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND", parser_class=_Parser)

    def cmd(name, fn, help):
        sp = sub.add_parser(name, help=help, description=help, formatter_class=_Help)
        sp.add_argument(
            "--json",
            action="store_true",
            help="print a machine-readable summary on stdout (errors too, as JSON)",
        )
        sp.add_argument(
            "--device", default="cpu", help="torch device of the heavy work (cpu, cuda, cuda:1)"
        )
        sp.add_argument("-q", "--quiet", action="store_true", help="no progress on stderr")
        sp.set_defaults(run=fn)
        return sp

    def output(sp, default, what):
        sp.add_argument("-o", "--output", "--out", default=default, help=what)

    def size(sp, w=512, h=512):
        sp.add_argument("--width", type=int, default=w, help="image width in pixels")
        sp.add_argument("--height", type=int, default=h, help="image height in pixels")
        sp.add_argument("--size", help="N or WxH: sets --width and --height together")

    def square(sp, n):
        sp.set_defaults(width=n, height=n)
        sp.add_argument("--size", default=str(n), help="image size in pixels (square)")

    def sun(sp, default=True):
        sp.add_argument(
            "--sun",
            action=argparse.BooleanOptionalAction,
            default=default,
            help="shade the map's sun per pixel with a shadow map (--no-sun: the paper's terms, "
            "the sun in the SH diffuse and the Gaussians' lighting)",
        )

    def lobes(sp):
        sp.add_argument(
            "--lobes",
            type=int,
            default=1,
            choices=[1, 2, 3],
            help="Gaussians per view fitted to the direct glossy transport (indirect glossy has "
            "one more of its own)",
        )

    def backend(sp):
        sp.add_argument(
            "--backend",
            choices=["auto", "gl", "torch"],
            default="auto",
            help="renderer: GLSL through EGL, or the torch path (auto: gl where a context opens)",
        )

    def base_res(sp, default=256):
        sp.add_argument(
            "--base-res",
            type=int,
            default=default,
            help="face resolution of the sharpest prefiltered level (a power of two)",
        )

    def spp(sp, default):
        sp.add_argument(
            "--spp", "--ref-spp", type=int, default=default, help="reference samples per pixel"
        )

    def samples(sp, default):
        sp.add_argument(
            "--samples",
            type=int,
            default=default,
            help="anti-aliasing samples per pixel, each a full shading pass (1: none)",
        )

    def env(sp, what):
        sp.add_argument(
            "--env",
            help=f".hdr/.exr file, a bundled map's name ({_bundled()}) or 'builtin'; {what}",
        )

    d = cmd("demo", _cmd_demo, "bake the built-in scene, render it, score it, write a report")
    output(d, "lobelight-demo", "output folder")
    d.add_argument("--scene", default="knot", help="scene to bake")
    lobes(d)
    spp(d, 64)
    size(d, 960, 720)
    sun(d)

    b = cmd("bake", _cmd_bake, "fit a model of a mesh or scene (resumes if interrupted)")
    b.add_argument(
        "scene",
        help="mesh (.ply .obj .stl .glb .off), scene (.toml .json; docs/scene-format.md) or a "
        "built-in name (knot, knot:2, sphere:3)",
    )
    output(b, None, "model file (default: NAME.lobelight.npz)")
    env(b, "the lighting render, view and compare use by default (default: the scene file's, "
        "else the built-in sky; the model relights under any)")  # fmt: skip
    b.add_argument(
        "--material",
        help="a bare mesh's material, e.g. 'ggx:alpha=0.05,specular=0.9,0.8,0.6' or "
        "'diffuse:color=0.7' (the keys of a scene file's [material]; docs/scene-format.md)",
    )
    lobes(b)
    b.add_argument(
        "--bounces",
        type=int,
        default=_BOUNCES,
        help="bounces of diffuse interreflection in the SH transfer, carrying the diffuse and "
        "glossy light of the points a vertex sees (0: self-shadowed only)",
    )
    b.add_argument(
        "--indirect-paths",
        type=int,
        default=_INDIRECT_PATHS,
        help="paths per vertex and view for indirect glossy, the light glossy surfaces reflect "
        "off the object (0: direct glossy only)",
    )
    b.add_argument("--float16", action="store_true", help="store half floats (half the size)")
    b.add_argument("--seed", type=int, default=0, help="seed of the fit's random starts")

    i = cmd("info", _cmd_info, "describe a model file")
    i.add_argument("model", help="a model file written by bake")

    r = cmd("render", _cmd_render, "render a model to an image (.png .jpg .exr .hdr)")
    r.add_argument("model", help="a model file written by bake")
    output(r, "render.png", "image (.png/.jpg tone-mapped, .exr/.hdr linear), or a folder with "
           "--turntable")  # fmt: skip
    env(r, "default: the model's, else the built-in sky")
    r.add_argument("--camera", help="'ox,oy,oz:tx,ty,tz[:fov]' (default: the scene's)")
    r.add_argument("--rotate", type=float, default=None, help="turn the lighting (degrees)")
    r.add_argument(
        "--parts", choices=["both", "diffuse", "glossy"], default="both", help="what to shade"
    )
    r.add_argument(
        "--background",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="draw the environment behind the object",
    )
    sun(r)
    r.add_argument("--exposure", default="auto", help="stops, or 'auto' (the object's pixels)")
    r.add_argument(
        "--tonemap", choices=["srgb", "aces"], default="srgb", help="display curve (.png, .jpg)"
    )
    backend(r)
    base_res(r)
    samples(r, 4)
    r.add_argument(
        "--turntable",
        type=int,
        metavar="N",
        help="render N frames around the object into the folder -o, and an animated GIF",
    )
    r.add_argument(
        "--spin",
        choices=["camera", "light"],
        default="camera",
        help="what --turntable turns",
    )
    size(r)

    v = cmd(
        "view",
        _cmd_view,
        "interactive window: drag to orbit, right-drag to turn the "
        "light, wheel to zoom, d/g/b diffuse/glossy/both, +/- exposure",
    )
    v.add_argument("model", help="a model file written by bake")
    env(v, "default: the model's, else the built-in sky")
    sun(v)
    size(v, 1024, 768)

    c = cmd("compare", _cmd_compare, "score a model against the path tracer and baselines")
    c.add_argument("scene", help="the scene (fitted here unless --model is given)")
    c.add_argument("--model", help="a model file of that scene")
    lobes(c)
    env(c, "default: the scene's")
    output(c, "lobelight-compare", "output folder (images, compare.json)")
    spp(c, 1024)
    c.add_argument("--rotate", type=float, default=None, help="turn the lighting (degrees)")
    backend(c)
    c.add_argument(
        "--baselines",
        nargs="*",
        default=["linear", "no_visibility", "sh10"],
        choices=["linear", "no_visibility", "sh10"],
        help="the paper's baselines to score as well",
    )
    base_res(c)
    sun(c)
    size(c, 192, 144)

    cb = cmd(
        "compare-brdf",
        _cmd_compare_brdf,
        "SG-mixture BRDFs vs filtered importance sampling, Wang 2009 and the reference",
    )
    output(cb, "lobelight-compare-brdf", "output folder")
    env(cb, "default: the built-in sky")
    square(cb, 128)
    spp(cb, 4096)
    cb.add_argument(
        "--backend",
        choices=["auto", "gl", "torch", "both"],
        default="auto",
        help="gl (or both) also renders ours and FIS-40 with the GLSL shaders (PSNR and fps "
        "rows); auto: where a context opens",
    )

    ga = cmd(
        "gallery",
        _cmd_gallery,
        "score real scenes against Mitsuba 3 references (DEVELOPERS.md renders them)",
    )
    gallery_arguments(ga)

    f = cmd("figure5", _cmd_figure5, "the paper's Figure 5: Gaussians vs Haar vs SH")
    output(f, "lobelight-figure5", "output folder")

    ld = cmd(
        "lobes-demo",
        _cmd_lobes_demo,
        "cosine lobes: a moving light and occluder with soft shadows, to PNGs and a GIF",
    )
    output(ld, "lobelight-lobes", "output folder")
    ld.add_argument("--frames", type=int, default=24, help="frames of the animation")
    square(ld, 256)
    ld.add_argument(
        "--fused",
        action="store_true",
        help="shade with torch.compile'd kernels (faster frames after a compile of up to a minute)",
    )

    be = cmd("bench", _cmd_bench, "benchmarks with machine-readable output")
    be.add_argument(
        "what",
        choices=["prefilter", "transport", "fit", "render", "lobe-tables", "lobes", "brdf-fit"],
        help="which benchmark",
    )
    be.add_argument("--scene", default="knot:2", help="scene of transport/fit (knot:2: 11.5K)")
    lobes(be)
    be.add_argument("--material", default="ward", help="brdf-fit material (ward, ward_aniso)")
    base_res(be, 512)
    backend(be)
    be.add_argument(
        "--repeats",
        type=int,
        default=None,
        help="timed repeats (default: prefilter 3 builds, lobes 20 frames: on a shared "
        "machine the best of a few frames is mostly noise)",
    )
    sun(be, default=False)
    samples(be, 1)
    return p


def _bundled() -> str:
    from .data import envmap_names

    return ", ".join(envmap_names())


def _version() -> str:
    from . import __version__

    return __version__


def _plain(x):
    if isinstance(x, float) and not math.isfinite(x):
        return str(x)
    return x


def _cell(v) -> str:
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def _print_text(summary: dict) -> None:
    """A summary for people: tables as aligned columns, mappings indented, one line each."""
    for k, v in summary.items():
        if isinstance(v, list) and v and all(isinstance(r, dict) for r in v):
            cols = list(v[0])
            cells = [cols] + [[_cell(r.get(c, "")) for c in cols] for r in v]
            widths = [max(len(row[i]) for row in cells) for i in range(len(cols))]
            print(f"{k}:")
            for row in cells:
                print("  " + "  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)))
        elif isinstance(v, dict):
            print(f"{k}:")
            for kk, vv in v.items():
                print(f"  {kk}: {_cell(vv)}")
        else:
            print(f"{k}: {_cell(v)}")


# options whose values may start with '-' (a camera below the origin, a negative angle)
_SIGNED = ("--camera", "--rotate", "--exposure")
_NUMBERISH = re.compile(r"-[\d.]")


def _join_signed(argv: list[str]) -> list[str]:
    """``--camera -1.6,0.7,-2.6:...`` as ``--camera=-1.6,...``, which argparse would otherwise
    read as an unknown option."""
    out: list[str] = []
    i = 0
    while i < len(argv):
        a = argv[i]
        if a in _SIGNED and i + 1 < len(argv) and _NUMBERISH.match(argv[i + 1]):
            out.append(f"{a}={argv[i + 1]}")
            i += 2
            continue
        out.append(a)
        i += 1
    return out


def _check_device(text: str) -> str:
    import torch

    try:
        dev = torch.device(text)
    except (RuntimeError, ValueError):
        raise InputError("--device", f"not a torch device: {text!r} (cpu, cuda, cuda:1)") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise InputError("--device", f"{text!r}: this torch has no CUDA device")
    if dev.type not in ("cpu", "cuda"):
        raise InputError("--device", f"{text!r}: lobelight runs on cpu or cuda")
    return text


def _fail(json_mode: bool, what: str, problem: str, code: int) -> int:
    """Report an error: one line on stderr, and the JSON error object on stdout under --json."""
    print(f"lobelight: error: {what}: {problem}" if what else f"lobelight: error: {problem}",
          file=sys.stderr)  # fmt: skip
    if json_mode:
        err = {"error": {"code": code, "input": what, "problem": problem}}
        print(json.dumps(err, indent=2))
    return code


class _Terminated(Exception):
    """SIGTERM arrived: unwound like Ctrl-C, so that ``finally`` blocks and checkpoints run."""


def _on_sigterm(signum, frame) -> None:
    raise _Terminated


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the exit code (0 ok, 1 unexpected error, 2 bad input, 130 Ctrl-C,
    143 SIGTERM)."""
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGTERM, _on_sigterm)
        try:
            return _main(argv)
        finally:
            signal.signal(signal.SIGTERM, previous)
    return _main(argv)


def _main(argv: list[str] | None) -> int:
    argv = _join_signed(list(sys.argv[1:] if argv is None else argv))
    json_mode = "--json" in argv
    try:
        args = _parser().parse_args(argv)
    except _UsageError as e:
        return _fail(json_mode, "", str(e), 2)
    try:
        args.device = _check_device(args.device)
        summary = args.run(args)
    except InputError as e:
        return _fail(args.json, e.what, e.problem, 2)
    except (KeyboardInterrupt, _Terminated) as e:
        code, what = (143, "terminated") if isinstance(e, _Terminated) else (130, "interrupted")
        print(f"lobelight: {what} (a bake resumes when run again)", file=sys.stderr)
        if args.json:
            print(json.dumps({"error": {"code": code, "input": "", "problem": what}}))
        return code
    try:
        if args.json:
            print(json.dumps(summary, indent=2, default=_plain))
        else:
            _print_text(summary)
        sys.stdout.flush()
    except BrokenPipeError:
        # the reader went away (`lobelight info m.npz | head -1`): its choice, not an error;
        # point stdout at devnull so that the interpreter's final flush does not fail again
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return 0


if __name__ == "__main__":
    sys.exit(main())
