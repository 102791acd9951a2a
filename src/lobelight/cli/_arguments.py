"""The command line's parser: one builder per command (``_add_bake``, ``_add_render``, ...) and
the options commands share, each defined once (``--output``, ``--width/--height/--size``,
``--sun``, ``--gaussians``, ``--backend``, ``--base-res``, ``--spp``, ``--samples``, ``--env``).

Building it imports no torch, so that ``--help`` and a usage error answer at once.
"""

from __future__ import annotations

import argparse
import math

from .. import __version__
from ..data import envmap_names
from ._gallery import add_arguments as add_gallery_arguments
from ._gallery import gaussian_count
from ._limits import (
    MAX_BASE_RES,
    MAX_BOUNCES,
    MAX_EXPOSURE,
    MAX_FRAMES,
    MAX_INDIRECT_PATHS,
    MAX_REFINE_ROUNDS,
    MAX_REPEATS,
    MAX_SAMPLES,
    MAX_SEED,
    MAX_SIDE,
    MAX_SPP,
    base_res_type,
    bounded_float,
    bounded_int,
    memory_bytes,
    pixels_help,
)

#: A bake's memory budget in GB, :data:`lobelight.fit.MEMORY_GB` restated likewise.
_MEMORY_GB = 4.0
#: A bake's interreflection defaults, :data:`lobelight.transport.BOUNCES` and
#: :data:`lobelight.transport.INDIRECT_PATHS`, restated so that building the parser imports no
#: torch (tests/test_cli.py holds them equal).
_BOUNCES = 4
_INDIRECT_PATHS = 16
#: A bake's rounds of mesh refinement, :data:`lobelight.fit.REFINE_ROUNDS` restated likewise.
_REFINE_ROUNDS = 3
#: ``--base-res auto``'s range, :data:`lobelight.render.AUTO_BASE_RES_MIN` and ``_MAX``
#: restated likewise.
AUTO_BASE_RES_RANGE = (256, 1024)


class _UsageError(Exception):
    """A command line argparse cannot parse: reported as bad input (exit 2)."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # argparse prints usage and exits; we report one line
        # "lobelight: error: bake: ..." names the command; the top level needs no name twice
        command = self.prog.removeprefix("lobelight").strip()
        raise _UsageError(f"{command}: {message}" if command else message)


class _Help(argparse.ArgumentDefaultsHelpFormatter):
    """Shows each flag's default (where it has one) after its help; a switch's is off."""

    def _get_help_string(self, action):
        if isinstance(action, argparse.BooleanOptionalAction) and isinstance(action.default, bool):
            on, off = action.option_strings[:2]
            return f"{action.help} (default: {on if action.default else off})"
        if isinstance(action, argparse._StoreTrueAction) and "default" not in (action.help or ""):
            return f"{action.help} (default: off)"
        if action.default is None or action.default is False:
            return action.help
        if action.default is argparse.SUPPRESS or "%(default)" in (action.help or ""):
            return action.help
        return super()._get_help_string(action)


def _parser() -> argparse.ArgumentParser:
    """The ``lobelight`` parser: every command, in the order ``--help`` lists them."""
    p = _Parser(
        prog="lobelight",
        description="Relight 3D objects under HDR environment lighting with spherical lobes.",
        epilog="Exit codes: 0 ok, 1 unexpected error (its traceback in a log file the error line "
        "names; --debug prints it), 2 bad input, 130 interrupted (Ctrl-C), 143 terminated "
        "(SIGTERM).",
    )
    p.add_argument("--version", action="version", version=f"lobelight {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND", parser_class=_Parser)
    for add in (
        _add_demo,
        _add_bake,
        _add_info,
        _add_render,
        _add_export,
        _add_view,
        _add_compare,
        _add_compare_brdf,
        _add_gallery,
        _add_figure5,
        _add_lobes_demo,
        _add_bench,
    ):
        add(sub)
    return p


# --------------------------------------------------------------------------------------------
# options the commands share


def _command(
    sub,
    name: str,
    run: str,
    help: str,
    *,
    heavy: bool = True,
    rays: bool = True,
    progress: bool = True,
) -> argparse.ArgumentParser:
    """A command's parser with every command's options: ``--json`` and ``-q``, and for a
    command that does heavy work (``heavy``) ``--device`` and, where it casts rays (``rays``),
    ``--rays`` (the others run on the CPU with the default ray engine). A
    command without progress (``progress`` False) accepts ``-q`` without offering it, so that
    a script may pass it to every command; ``run`` names its function in
    :mod:`lobelight.cli._commands`."""
    sp = sub.add_parser(name, help=help, description=help, formatter_class=_Help)
    sp.add_argument(
        "--json",
        action="store_true",
        help="print a machine-readable summary on stdout (errors too, as JSON)",
    )
    sp.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        help="no progress on stderr" if progress else argparse.SUPPRESS,
    )
    sp.add_argument(
        "--debug",
        action="store_true",
        help="on an unexpected error (exit 1), print its traceback on stderr (default: write it "
        "to a log file, whose path the error line names)",
    )
    if heavy:
        sp.add_argument(
            "--device", default="cpu", help="torch device of the heavy work (cpu, cuda, cuda:1)"
        )
    else:
        sp.set_defaults(device="cpu")
    if heavy and rays:
        sp.add_argument(
            "--rays",
            default="auto",
            choices=["auto", "embree", "warp"],
            help="ray engine (auto: Warp on a CUDA device, Embree on the CPU)",
        )
    else:
        sp.set_defaults(rays="auto")
    sp.set_defaults(run=run)
    return sp


def _percent(text: str) -> str:
    """``text`` for an argparse help string (which formats ``%``)."""
    return text.replace("%", "%%")


def _output(sp, default, what: str) -> None:
    sp.add_argument("-o", "--output", default=default, help=what)


def _size(sp, w: int = 512, h: int = 512, what: str = "image") -> None:
    side = bounded_int(1, MAX_SIDE)
    sp.add_argument("--width", type=side, default=w, help=f"{what} width in pixels")
    sp.add_argument("--height", type=side, default=h, help=f"{what} height in pixels")
    sp.add_argument(
        "--size",
        help="N or WxH: sets --width and --height together (default: theirs); "
        + _percent(pixels_help()),
    )


def _square(sp, n: int) -> None:
    sp.set_defaults(width=n, height=n)
    sp.add_argument(
        "--size", default=str(n), help=f"image size in pixels (square); {_percent(pixels_help())}"
    )


def _sun(sp, default: bool = True, where: str = "") -> None:
    sp.add_argument(
        "--sun",
        action=argparse.BooleanOptionalAction,
        default=default,
        help=f"{where}shade the map's sun per pixel with a shadow map (--no-sun: the paper's "
        "terms, the sun in the SH diffuse and the Gaussians' lighting)",
    )


def _gaussians(sp, *, auto: bool = False, where: str = "") -> None:
    if not auto:
        sp.add_argument(
            "--gaussians",
            type=int,
            default=1,
            choices=[1, 2, 3],
            help="Gaussians per view fitted to the direct glossy transport (indirect glossy "
            "has one more of its own)",
        )
        return
    sp.add_argument(
        "--gaussians",
        type=gaussian_count,
        default="auto",
        choices=["auto", 1, 2, 3],
        help=f"{where}Gaussians per view fitted to the direct glossy transport (indirect glossy "
        "has one more of its own); auto: chosen from the material (two for GGX-like metals of "
        "moderate roughness, one otherwise; the reason is in the model's provenance, "
        "lobelight info)",
    )


def _memory_gb(sp, where: str = "") -> None:
    gb = memory_bytes() / 2**30
    sp.add_argument(
        "--memory-gb",
        type=bounded_float(0.0, round(gb, 1), lo_open=True),
        default=_MEMORY_GB,
        metavar="GB",
        help=f"{where}the bake's memory budget (resident, GB): every stage's batches are sized "
        "to it, "
        f"so a mesh of any size bakes within it (at most this machine's {gb:.1f} GB)",
    )


def _backend(sp, where: str = "") -> None:
    sp.add_argument(
        "--backend",
        choices=["auto", "gl", "torch"],
        default="auto",
        help=f"{where}renderer: GLSL through EGL, or the torch path (auto: gl where a context "
        "opens, else torch)",
    )


def _base_res(sp, default: int | str = "auto", where: str = "") -> None:
    lo, hi = AUTO_BASE_RES_RANGE
    auto = (
        f"auto: the one the model's sharpest lobes need under the map, {lo} to {hi}; "
        if default == "auto"
        else ""
    )
    sp.add_argument(
        "--base-res",
        type=base_res_type if default == "auto" else bounded_int(1, MAX_BASE_RES),
        default=default,
        help=f"{where}face resolution of the sharpest prefiltered level ({auto}a power of two, at "
        f"most {MAX_BASE_RES}: the largest whose chain fits half of this machine's memory)",
    )


def _spp(sp, default: int) -> None:
    sp.add_argument(
        "--spp",
        type=bounded_int(1, MAX_SPP),
        default=default,
        help=f"reference samples per pixel (1..{MAX_SPP})",
    )


def _samples(sp, default: int, where: str = "") -> None:
    sp.add_argument(
        "--samples",
        type=bounded_int(1, MAX_SAMPLES),
        default=default,
        help=f"{where}anti-aliasing samples per pixel, each a full shading pass (1: none; at most "
        f"{MAX_SAMPLES})",
    )


def _rotate(sp) -> None:
    sp.add_argument(
        "--rotate",
        type=bounded_float(-1e9, 1e9),
        default=0.0,
        metavar="DEGREES",
        help="turn the lighting about the vertical axis (+y, the lat-long map's up; "
        "-1e9..1e9, taken modulo 360)",
    )


def _env(sp, what: str, *, repeat: bool = False) -> None:
    sp.add_argument(
        "--env",
        action="append" if repeat else "store",
        help=f".hdr/.exr file, a bundled map's name ({_bundled()}) or 'builtin'; {what}",
    )


def _bundled() -> str:
    return ", ".join(envmap_names())


# --------------------------------------------------------------------------------------------
# the commands


def _add_demo(sub) -> None:
    d = _command(
        sub, "demo", "run_demo", "bake the built-in scene, render it, score it, write a report"
    )
    _output(d, "lobelight-demo", "output folder")
    d.add_argument("--scene", default="knot", help="scene to bake")
    _gaussians(d)
    _spp(d, 64)
    _size(d, 960, 720)
    _sun(d)


def _add_bake(sub) -> None:
    b = _command(sub, "bake", "run_bake", "fit a model of a mesh or scene (resumes if interrupted)")
    b.add_argument(
        "scene",
        help="mesh (.ply .obj .stl .off; .glb .gltf with their materials), scene (.toml "
        ".json; docs/scene-format.md) or a built-in name (knot, knot:2, sphere:3)",
    )
    _output(b, None, "model file (default: NAME.lobelight.npz)")
    _env(b, "the lighting render, view and compare use by default (default: the scene file's, "
         "else the built-in sky; the model relights under any)")  # fmt: skip
    b.add_argument(
        "--material",
        help="one material on every vertex, in place of the scene's own (a bare mesh's "
        "default, a glTF file's materials, a scene file's), e.g. "
        "'ggx:alpha=0.05,specular=0.9,0.8,0.6' or 'diffuse:color=0.7' (the keys of a scene "
        "file's [material]; docs/scene-format.md)",
    )
    _gaussians(b, auto=True)
    _memory_gb(b)
    b.add_argument(
        "--bounces",
        type=bounded_int(0, MAX_BOUNCES),
        default=_BOUNCES,
        help="bounces of diffuse interreflection in the SH transfer, carrying the diffuse and "
        f"glossy light of the points a vertex sees (0: self-shadowed only; at most {MAX_BOUNCES})",
    )
    b.add_argument(
        "--indirect-paths",
        type=bounded_int(0, MAX_INDIRECT_PATHS),
        default=_INDIRECT_PATHS,
        help="paths per vertex and view for indirect glossy, the light glossy surfaces reflect "
        f"off the object (0: direct glossy only; at most {MAX_INDIRECT_PATHS})",
    )
    b.add_argument(
        "--refine",
        type=bounded_int(0, MAX_REFINE_ROUNDS),
        default=_REFINE_ROUNDS,
        metavar="ROUNDS",
        help="rounds of splitting the mesh's long edges whose ends see the environment "
        "differently, so that per-vertex transport resolves a shadow's edge across a long "
        f"triangle (0: the mesh as it is; at most {MAX_REFINE_ROUNDS})",
    )
    b.add_argument("--float16", action="store_true", help="store half floats (half the size)")
    b.add_argument(
        "--seed",
        type=bounded_int(0, MAX_SEED),
        default=0,
        help="seed of the fit's random starts (0..2^63-1)",
    )
    b.add_argument(
        "--checkpoint-every",
        type=bounded_float(0.0, math.inf),
        default=30.0,
        metavar="SECONDS",
        help="save the bake's state at most this often (and after each stage) to "
        "MODEL.ckpt, from which an interrupted bake resumes; 0 after every chunk, inf after "
        "each stage only",
    )
    where = b.add_mutually_exclusive_group()
    where.add_argument(
        "--cluster",
        metavar="ADDRESS",
        help="run the bake's chunks on the Dask cluster whose scheduler is at ADDRESS "
        "(tcp://HOST:8786, as `dask scheduler` prints it; workers started with `dask worker "
        "ADDRESS`; docs/cluster.md); needs lobelight[cluster]. The model is the same as without "
        "it (default: the bake runs in this process, as many chunks at once as torch has "
        "threads, OMP_NUM_THREADS)",
    )
    where.add_argument(
        "--workers",
        type=bounded_int(1, 1024),
        metavar="N",
        help="run the bake's chunks on N worker processes started on this machine (a local "
        "Dask cluster of one thread each); needs lobelight[cluster] (default: none, the bake "
        "runs in this process, as many chunks at once as torch has threads)",
    )


def _add_info(sub) -> None:
    i = _command(sub, "info", "run_info", "describe a model file", heavy=False, progress=False)
    i.add_argument("model", help="a model file written by bake")


def _add_export(sub) -> None:
    ex = _command(
        sub,
        "export",
        "run_export",
        "write a model for other programs (--gltf OUT.glb, --web DIR)",
        progress=False,
    )
    ex.add_argument("model", help="a model file written by bake")
    out = ex.add_mutually_exclusive_group(required=True)
    out.add_argument(
        "--gltf",
        metavar="OUT.glb",
        help="glTF 2.0 binary: the mesh with a fallback material, and the model's lobe data "
        "as LOBELIGHT_prt accessors (docs/gltf-export.md); default: none, one of --gltf and "
        "--web is required",
    )
    out.add_argument(
        "--web",
        metavar="DIR",
        help="the self-contained WebGL 2 viewer: a folder that opens from file:// or any "
        "static server, no network (docs/web-viewer.md); default: none, one of --gltf and "
        "--web is required",
    )
    _env(
        ex,
        "--gltf: written as the file's image-based light (EXT_lights_image_based; default: "
        "none); --web: a map the page offers, repeat it for several (default: the model's, "
        "else the built-in sky)",
        repeat=True,
    )
    _sun(ex, where="--web: ")
    ex.add_argument(
        "--float16",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="the lobe data (--web: the records and transfers) as half floats (--no-float16: "
        "float32, twice the size)",
    )
    _base_res(ex, 128)


def _add_render(sub) -> None:
    r = _command(sub, "render", "run_render", "render a model to an image (.png .jpg .exr .hdr)")
    r.add_argument("model", help="a model file written by bake")
    _output(r, None, "image (.png/.jpg tone-mapped, .exr/.hdr linear), or a folder with "
            "--turntable (default: render.png; with --turntable the folder turntable)")  # fmt: skip
    _env(r, "default: the model's, else the built-in sky")
    r.add_argument(
        "--camera",
        help="'ox,oy,oz:tx,ty,tz[:fov]', coordinates within +-1e15, fov in (0, 180) degrees "
        "(default: the scene's)",
    )
    _rotate(r)
    r.add_argument(
        "--parts", choices=["both", "diffuse", "glossy"], default="both", help="what to shade"
    )
    r.add_argument(
        "--background",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="draw the environment behind the object",
    )
    _sun(r)
    r.add_argument(
        "--exposure",
        default="auto",
        help=f"stops (-{MAX_EXPOSURE:g}..{MAX_EXPOSURE:g}), or 'auto' (the object's pixels)",
    )
    r.add_argument(
        "--tonemap",
        choices=["neutral", "srgb", "aces"],
        default="neutral",
        help="display curve (.png, .jpg): neutral keeps saturated colours (Khronos PBR Neutral), "
        "srgb clips, aces is filmic (default: %(default)s)",
    )
    _backend(r)
    _base_res(r)
    _samples(r, 4)
    r.add_argument(
        "--turntable",
        type=bounded_int(1, MAX_FRAMES),
        metavar="N",
        help="render N frames around the object into the folder -o, and an animated GIF "
        f"(default: one still image; at most {MAX_FRAMES}, and their images together within "
        "half of this machine's memory)",
    )
    r.add_argument(
        "--spin",
        choices=["camera", "light"],
        default=None,
        help="what --turntable turns (default: camera)",
    )
    _size(r)


def _add_view(sub) -> None:
    v = _command(
        sub,
        "view",
        "run_view",
        "interactive window: drag to orbit, right-drag to turn the light, wheel to zoom, "
        "d/g/b diffuse/glossy/both, +/- exposure, t display curve, e next map",
        heavy=False,
        progress=False,
    )
    v.add_argument("model", help="a model file written by bake")
    _env(
        v,
        "repeat it for several, which e cycles through (default: the model's, else the "
        "built-in sky)",
        repeat=True,
    )
    _sun(v)
    _size(v, 1024, 768, "the window's")
    v.add_argument(
        "--web",
        action="store_true",
        help="no window: write the WebGL 2 viewer to a temporary folder and serve it on "
        "localhost (for a machine without a display: reach it through an SSH tunnel; "
        "default: a window); the page takes the browser window's size",
    )
    v.add_argument(
        "--port",
        type=bounded_int(0, 65535),
        default=8000,
        help="--web: the local port (default: %(default)s; 0 picks a free one)",
    )


def _add_compare(sub) -> None:
    c = _command(
        sub, "compare", "run_compare", "score a model against the path tracer and baselines"
    )
    c.add_argument(
        "scene",
        nargs="?",
        help="the scene (fitted here unless --model is given); with --model it may be left "
        "out: the model's own mesh, material, map and camera are scored",
    )
    c.add_argument(
        "--model",
        help="a model file: its material, map and camera are used, and a scene whose mesh, "
        "material or map differs from them is refused (see --allow-mismatch); default: none, "
        "the scene is fitted here",
    )
    c.add_argument(
        "--allow-mismatch",
        action="store_true",
        help="score the given scene's own material and map although the model was baked "
        "with others (the mesh must still match)",
    )
    c.add_argument(
        "--gaussians",
        type=int,
        default=None,
        choices=[1, 2, 3],
        help="Gaussians per view of the model fitted here (default: 1); not with --model, "
        "whose own are scored",
    )
    _env(c, "default: the model's with --model, else the scene's")
    _output(c, "lobelight-compare", "output folder (images, compare.json)")
    _spp(c, 1024)
    _rotate(c)
    _backend(c)
    c.add_argument(
        "--baselines",
        nargs="*",
        default=["linear"],
        choices=["linear", "no_visibility", "sh10"],
        help="the paper's baselines to score as well: linear reuses the model (seconds); "
        "no_visibility fits a model without visibility and sh10 gathers the transport "
        "again (each at least as long as the bake's fit stage, said before the comparison "
        "starts); none: --baselines with no name",
    )
    _base_res(c)
    _sun(c)
    _size(c, 192, 144)


def _add_compare_brdf(sub) -> None:
    cb = _command(
        sub,
        "compare-brdf",
        "run_compare_brdf",
        "SG-mixture BRDFs vs filtered importance sampling, Wang 2009 and the reference",
        rays=False,  # its sphere is intersected in closed form
        progress=False,
    )
    _output(cb, "lobelight-compare-brdf", "output folder")
    _env(cb, "default: the built-in sky")
    _square(cb, 128)
    _spp(cb, 4096)
    cb.add_argument(
        "--backend",
        choices=["auto", "gl", "torch", "both"],
        default="auto",
        help="gl (or both) also renders ours and FIS-40 with the GLSL shaders (PSNR and fps "
        "rows); auto: where a context opens",
    )


def _add_gallery(sub) -> None:
    ga = _command(
        sub,
        "gallery",
        "run_gallery",
        "score real scenes against Mitsuba 3 references (DEVELOPERS.md renders them)",
    )
    add_gallery_arguments(ga)


def _add_figure5(sub) -> None:
    f = _command(
        sub,
        "figure5",
        "run_figure5",
        "the paper's Figure 5: Gaussians vs Haar vs SH",
        heavy=False,
        progress=False,
    )
    _output(f, "lobelight-figure5", "output folder")


def _add_lobes_demo(sub) -> None:
    ld = _command(
        sub,
        "lobes-demo",
        "run_lobes_demo",
        "cosine lobes: a moving light and occluder with soft shadows, to PNGs and a GIF",
    )
    _output(ld, "lobelight-lobes", "output folder")
    ld.add_argument(
        "--frames",
        type=bounded_int(1, MAX_FRAMES),
        default=24,
        help=f"frames of the animation (at most {MAX_FRAMES})",
    )
    _square(ld, 256)
    ld.add_argument(
        "--fused",
        action="store_true",
        help="shade with torch.compile'd kernels (faster frames after a compile of up to a minute)",
    )


def _add_bench(sub) -> None:
    be = _command(sub, "bench", "run_bench", "benchmarks with machine-readable output")
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
            "start",
            "cluster",
            "web",
        ],
        help="which benchmark (all: every benchmark with a goal, on --device, in one run; "
        "start: a render's start in a new process, cold and warm; cluster: a bake on 1 and 2 "
        "local Dask workers against one process, --scene, lobelight[cluster]; web: the WebGL 2 "
        "viewer's frames per second in headless chromium, lobelight[web]; --device is "
        "used by all, prefilter, transport, fit, rays, lobe-tables, lobes and brdf-fit)",
    )
    _output(be, None, "bench all: JSON file of the results, rewritten after each benchmark "
            "(default: none, the summary on stdout only)")  # fmt: skip
    be.add_argument(
        "--budget",
        type=bounded_float(0.0, 1e9, lo_open=True),
        default=None,
        help="bench all: seconds after which benchmarks not yet started are skipped (at most "
        "1e9; default: none, every benchmark runs)",
    )
    be.add_argument(
        "--scene",
        default="knot:2",
        help="scene of transport, fit and cluster (knot:2: 11.5K vertices)",
    )
    be.add_argument(
        "--fit-material",
        default=None,
        metavar="SPEC",
        help="fit: a bare mesh's material (as bake's --material), e.g. 'ggx:alpha=0.04,"
        "specular=0.9' for a metal (default: the scene's own)",
    )
    _gaussians(be, auto=True, where="fit: ")
    _memory_gb(be, where="fit: ")
    be.add_argument("--material", default="ward", help="brdf-fit: the material (ward, ward_aniso)")
    _base_res(be, 512, where="prefilter: ")
    _backend(be, where="render: ")
    be.add_argument(
        "--repeats",
        type=bounded_int(1, MAX_REPEATS),
        default=None,
        help="timed repeats (default: prefilter 3 builds, lobes 20 frames, start 3 warm "
        "runs: on a shared machine the best of a few frames is mostly noise; at most "
        f"{MAX_REPEATS})",
    )
    _sun(be, default=False, where="render: ")
    _samples(be, 1, where="render: ")
