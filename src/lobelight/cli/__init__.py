"""The ``lobelight`` command line: one entry point, ``--help`` everywhere, ``--json`` for machines.

Commands: ``demo``, ``bake``, ``info``, ``render``, ``view``, ``compare``, ``compare-brdf``,
``figure5``, ``lobes-demo``, ``bench``.

Every command takes ``--json`` (stdout carries only the JSON summary, or a JSON error object),
``--device`` and ``--quiet``. Progress goes to stderr: bars on a terminal, plain lines at most
every few seconds elsewhere (:mod:`lobelight.progress`). Flags share their names across
commands: ``-o/--output``, ``--width/--height``, ``--spp``, ``--sun/--no-sun``, ``--backend``.

Exit codes: 0 success; 1 unexpected error; 2 bad input (one line on stderr naming the input and
the problem); 130 interrupted (Ctrl-C), 143 terminated (SIGTERM, as batch schedulers send it):
one line each, and a bake resumes from its checkpoint when run again.
"""

from __future__ import annotations

import argparse
import importlib
import json
import math
import os
import re
import signal
import sys
import threading

from .. import __version__
from .._process import tune
from ..data import envmap_names
from ..errors import InputError, one_line
from ..studies.gallery import add_arguments as gallery_arguments

#: A bake's interreflection defaults, :data:`lobelight.transport.BOUNCES` and
#: :data:`lobelight.transport.INDIRECT_PATHS`, restated so that building the parser imports no
#: torch (tests/test_cli.py holds them equal).
_BOUNCES = 4
_INDIRECT_PATHS = 16

__all__ = ["main"]


# --------------------------------------------------------------------------------------------
# parser


class _UsageError(Exception):
    """A command line argparse cannot parse: reported as bad input (exit 2)."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # argparse prints usage and exits; we report one line
        # "lobelight: error: bake: ..." names the command; the top level needs no name twice
        command = self.prog.removeprefix("lobelight").strip()
        raise _UsageError(f"{command}: {message}" if command else message)


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
    p.add_argument("--version", action="version", version=f"lobelight {__version__}")
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
        sp.add_argument(
            "--rays",
            default="auto",
            choices=["auto", "embree", "warp"],
            help="ray engine (auto: Warp on a CUDA device, Embree on the CPU)",
        )
        sp.set_defaults(run=fn)
        return sp

    def output(sp, default, what):
        sp.add_argument("-o", "--output", default=default, help=what)

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

    def gaussians(sp):
        sp.add_argument(
            "--gaussians",
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
        sp.add_argument("--spp", type=int, default=default, help="reference samples per pixel")

    def samples(sp, default):
        sp.add_argument(
            "--samples",
            type=int,
            default=default,
            help="anti-aliasing samples per pixel, each a full shading pass (1: none)",
        )

    def env(sp, what, *, repeat: bool = False):
        sp.add_argument(
            "--env",
            action="append" if repeat else "store",
            help=f".hdr/.exr file, a bundled map's name ({_bundled()}) or 'builtin'; {what}",
        )

    d = cmd("demo", "run_demo", "bake the built-in scene, render it, score it, write a report")
    output(d, "lobelight-demo", "output folder")
    d.add_argument("--scene", default="knot", help="scene to bake")
    gaussians(d)
    spp(d, 64)
    size(d, 960, 720)
    sun(d)

    b = cmd("bake", "run_bake", "fit a model of a mesh or scene (resumes if interrupted)")
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
    gaussians(b)
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
    b.add_argument(
        "--checkpoint-every",
        type=float,
        default=30.0,
        metavar="SECONDS",
        help="save the bake's state at most this often (and after each stage) to "
        "MODEL.ckpt, from which an interrupted bake resumes; 0 after every chunk",
    )

    i = cmd("info", "run_info", "describe a model file")
    i.add_argument("model", help="a model file written by bake")

    r = cmd("render", "run_render", "render a model to an image (.png .jpg .exr .hdr)")
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
        "run_view",
        "interactive window: drag to orbit, right-drag to turn the "
        "light, wheel to zoom, d/g/b diffuse/glossy/both, +/- exposure, e next map",
    )
    v.add_argument("model", help="a model file written by bake")
    env(
        v,
        "repeat it for several, which e cycles through (default: the model's, else the "
        "built-in sky)",
        repeat=True,
    )
    sun(v)
    size(v, 1024, 768)

    c = cmd("compare", "run_compare", "score a model against the path tracer and baselines")
    c.add_argument("scene", help="the scene (fitted here unless --model is given)")
    c.add_argument("--model", help="a model file of that scene")
    gaussians(c)
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
        "run_compare_brdf",
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
        "run_gallery",
        "score real scenes against Mitsuba 3 references (DEVELOPERS.md renders them)",
    )
    gallery_arguments(ga)

    f = cmd("figure5", "run_figure5", "the paper's Figure 5: Gaussians vs Haar vs SH")
    output(f, "lobelight-figure5", "output folder")

    ld = cmd(
        "lobes-demo",
        "run_lobes_demo",
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

    be = cmd("bench", "run_bench", "benchmarks with machine-readable output")
    be.add_argument(
        "what",
        choices=[
            "all",
            "prefilter",
            "transport",
            "fit",
            "render",
            "rays",
            "lobe-tables",
            "lobes",
            "brdf-fit",
        ],
        help="which benchmark (all: every benchmark with a goal, on --device, in one run)",
    )
    output(be, None, "bench all: JSON file of the results, rewritten after each benchmark")
    be.add_argument(
        "--budget",
        type=float,
        default=None,
        help="bench all: seconds after which benchmarks not yet started are skipped",
    )
    be.add_argument("--scene", default="knot:2", help="scene of transport/fit (knot:2: 11.5K)")
    gaussians(be)
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
    return ", ".join(envmap_names())


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


def _fail(json_mode: bool, what: str, problem: str, code: int) -> int:
    """Report an error: one line on stderr, and the JSON error object on stdout under --json."""
    what, problem = one_line(what), one_line(problem)  # a usage error quotes the arguments
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
        # the commands (and torch) load once the line is parsed: --help and a mistyped
        # command answer at once
        commands = importlib.import_module("lobelight.cli._commands")
        # the process is ours: its allocator and OpenMP settings (lobelight._process), made
        # once torch is loaded, so that the short spin reaches only the runtimes loaded later
        tune()
        args.device = commands.check_device(args.device)
        commands.use_rays(args.rays)
        summary = getattr(commands, args.run)(args)
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
