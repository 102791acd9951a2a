"""The ``lobelight`` command line: one entry point, ``--help`` everywhere, ``--json`` for machines.

Commands: ``demo``, ``bake``, ``info``, ``render``, ``view``, ``compare``, ``compare-brdf``,
``figure5``, ``lobes-demo``, ``bench``.

Exit codes: 0 success; 1 unexpected error; 2 bad input (one line naming the input and the
problem); 130 interrupted (Ctrl-C; a bake resumes from its checkpoint when run again).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
import time
from pathlib import Path
from typing import ClassVar

__all__ = ["main"]


# --------------------------------------------------------------------------------------------
# feedback


class _Progress:
    """``progress(stage, done, total)`` callbacks drawn as tqdm bars on stderr (rates, ETA);
    silent with ``--json`` or when stderr is not a terminal."""

    # what a stage counts (else chunks)
    UNITS: ClassVar[dict[str, str]] = {
        "frames": "frame", "lobe tables": "fit", "reference": "spp", "reference, glossy": "spp",
    }  # fmt: skip

    def __init__(self, enabled: bool):
        self.enabled = enabled and sys.stderr.isatty()
        self.bars: dict[str, object] = {}

    def __call__(self, stage: str, done: int, total: int) -> None:
        if not self.enabled:
            return
        from tqdm import tqdm

        bar = self.bars.get(stage)
        if bar is None:
            unit = self.UNITS.get(stage, "chunk")
            bar = self.bars[stage] = tqdm(total=total, desc=stage, unit=unit, leave=False)
        bar.n = done
        bar.refresh()
        if done >= total:
            bar.close()

    def note(self, text: str) -> None:
        if self.enabled:
            print(text, file=sys.stderr)


def _device(args) -> str:
    return args.device


def _camera_from(text: str | None, provenance: dict, mesh):
    from .camera import Camera
    from .errors import InputError

    if text:
        try:
            parts = [[float(x) for x in p.split(",")] for p in text.split(":")]
            origin, target = parts[0], parts[1]
            fov = parts[2][0] if len(parts) > 2 else 40.0
            assert len(origin) == 3 and len(target) == 3
        except (ValueError, IndexError, AssertionError):
            raise InputError(
                "--camera", f"expected 'ox,oy,oz:tx,ty,tz[:fov]', got {text!r}"
            ) from None
        return Camera.look_at(origin, target, fov=fov)
    cam = provenance.get("camera")
    if isinstance(cam, dict):
        try:
            return Camera(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in cam.items()})
        except (TypeError, InputError):
            pass
    from .scene._scene import _default_camera

    return _default_camera(mesh)


def _env_source(path: str | None, provenance: dict | None = None) -> str:
    """The environment a command uses: ``--env``, else the model's stored one (a scene file's
    or ``bake --env``'s) while its file exists, else ``"builtin"``."""
    if path:
        return str(path)
    stored = (provenance or {}).get("environment", "builtin")
    if isinstance(stored, str) and stored != "builtin" and Path(stored).is_file():
        return stored
    return "builtin"


def _env(path: str | None, provenance: dict | None = None):
    from .envmap import builtin, load

    source = _env_source(path, provenance)
    return builtin() if source == "builtin" else load(source)


# --------------------------------------------------------------------------------------------
# commands


def _cmd_bake(args) -> dict:
    from .fit import fit_model
    from .scene import load

    prog = _Progress(not args.json)
    sc = load(args.scene, device=args.device)
    if args.env:  # the model's default lighting (render, view, compare), as a scene file's
        from .envmap import load as load_env

        load_env(args.env)  # checked at the door: missing, unreadable, NaN/Inf, bad shape
        sc = dataclasses.replace(sc, environment=str(Path(args.env).resolve()))
    out = Path(args.output) if args.output else Path(f"{Path(str(args.scene)).stem}.lobelight.npz")
    out = Path(str(out).replace(":", "-"))
    ckpt = out.with_name(out.name + ".ckpt")
    if ckpt.exists():
        prog.note(f"resuming from {ckpt}")
    t0 = time.perf_counter()
    m = fit_model(
        sc,
        args.lobes,
        device=args.device,
        indirect_paths=args.indirect_paths,
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
        "vertices": sc.mesh.n_vertices,
        "n_lobes": args.lobes,
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
        "n_lobes": m.n_lobes,
        "sh_coefficients": int(m.diffuse.shape[1]),
        "records_with_weight": int(live.sum()),
        "material": m.materials.model,
        "provenance": m.provenance,
    }


def _cmd_render(args) -> dict:
    from .model import load
    from .render import Renderer, auto_exposure, save_image
    from .render._gl import gl_available

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
        args.width,
        args.height,
        backend=backend,
        base_res=args.base_res,
        sun=not args.no_sun,
    ) as ren:
        t1 = time.perf_counter()
        img, mask = ren.render(
            cam,
            args.rotate,
            diffuse=args.parts in ("both", "diffuse"),
            glossy=args.parts in ("both", "glossy"),
            background=not args.no_background,
            return_mask=True,
        )
        t2 = time.perf_counter()
    exposure = auto_exposure(img, mask) if args.exposure == "auto" else float(args.exposure)
    out = save_image(args.output, img, exposure=exposure, curve=args.tonemap)
    return {
        "command": "render",
        "output": str(out),
        "environment": _env_source(args.env, m.provenance),
        "backend": backend,
        "size": [args.width, args.height],
        "exposure": exposure,
        "seconds_setup": t1 - t0,
        "seconds_render": t2 - t1,
    }


def _cmd_view(args) -> dict:
    from .model import load
    from .render._window import require_display, view

    require_display()  # no model is loaded where no window can open
    m = load(args.model)  # checked before a window opens; its stored environment is the default
    return view(
        m, env=_env(args.env, m.provenance), width=args.width, height=args.height,
        sun=not args.no_sun,
    )  # fmt: skip


def _cmd_compare(args) -> dict:
    from .compare import compare
    from .model import load as load_model
    from .scene import load

    sc = load(args.scene, device=args.device)
    model = load_model(args.model, device=args.device) if args.model else None
    if model is not None and model.mesh.n_vertices != sc.mesh.n_vertices:
        from .errors import InputError

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
            width=args.width,
            height=args.height,
            spp=args.spp,
            light_rotation=args.rotate,
            backend=args.backend,
            baselines=tuple(args.baselines),
            base_res=args.base_res,
            out=args.out,
            device=args.device,
            sun=not args.no_sun,
            progress=_Progress(not args.json),
        ),
    }


def _cmd_compare_brdf(args) -> dict:
    from .sgbrdf import compare_brdf

    return {
        "command": "compare-brdf",
        **compare_brdf(
            args.out,
            env=args.env,
            size=args.size,
            ref_spp=args.ref_spp,
            device=args.device,
            backend=args.backend,
        ),
    }


def _cmd_figure5(args) -> dict:
    from .figure5 import figure5

    return {"command": "figure5", **figure5(args.out, device=args.device)}


def _cmd_lobes_demo(args) -> dict:
    from .cosine import lobes_demo

    return {
        "command": "lobes-demo",
        **lobes_demo(
            args.out,
            frames=args.frames,
            size=args.size,
            device=args.device,
            fused=args.fused,
            progress=_Progress(not args.json),
        ),
    }


def _cmd_bench(args) -> dict:
    from . import bench

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
            backend=args.backend if args.backend != "auto" else "gl", sun=args.sun
        )
    if w == "lobe-tables":
        from .cosine import bench_tables

        return bench_tables(device=args.device)
    if w == "lobes":
        from .cosine import bench_lobes

        return bench_lobes(device=args.device, **reps)
    if w == "brdf-fit":
        from .sgbrdf import bench_fit

        return bench_fit(material=args.material, device=args.device)
    raise AssertionError(w)


def _cmd_demo(args) -> dict:
    """Bake the built-in scene, render it under the sky and a turned sky, score it against the
    path tracer, and write a Markdown report."""
    import torch

    from .compare import compare
    from .envmap import builtin
    from .fit import fit_model
    from .render import Renderer, auto_exposure, save_image
    from .render._gl import gl_available
    from .scene import load

    prog = _Progress(not args.json)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    sc = load(args.scene, device=args.device)
    env = builtin()
    prog.note(f"baking {sc.name} ({sc.mesh.n_vertices} vertices, {args.lobes} Gaussian(s)/view)")
    model = fit_model(
        sc, args.lobes, device=args.device, progress=prog, checkpoint=out / "model.ckpt"
    )
    info = model.save(out / "model.lobelight.npz")
    (out / "model.ckpt").unlink(missing_ok=True)
    t_bake = time.perf_counter() - t0
    backend = "gl" if gl_available() else "torch"
    stills = {}
    t1 = time.perf_counter()
    with Renderer(model, env, args.width, args.height, backend=backend, sun=not args.no_sun) as ren:
        for label, rot in (("sky", None), ("sky-turned-120", 120.0)):
            img, mask = ren.render(sc.camera, rot, return_mask=True)
            stills[label] = str(
                save_image(out / f"{label}.png", img, exposure=auto_exposure(img, mask))
            )
        t_frame = time.perf_counter()
        ren.render(sc.camera, 30.0)
        t_frame = time.perf_counter() - t_frame
    t_render = time.perf_counter() - t1
    prog.note("path tracing the reference")
    cmp = compare(
        sc,
        model=model,
        env=env,
        width=args.width // 2,
        height=args.height // 2,
        spp=args.spp,
        backend=backend,
        baselines=("linear",),
        out=out / "compare",
        sun=not args.no_sun,
        progress=prog,
    )
    total = time.perf_counter() - t0
    rows = "\n".join(
        f"| {r['method']} | {r['component']} | {r['psnr']:.2f} | {r['psnr_display']:.2f} "
        f"| {r['rel_l2']:.4f} |"
        for r in cmp["table"]
    )
    sky, turned = Path(stills["sky"]).name, Path(stills["sky-turned-120"]).name
    frame = f"{t_render:.2f} (one frame {t_frame * 1e3:.1f} ms)"
    report = f"""# lobelight demo: {sc.name}

{sc.mesh.n_vertices} vertices, {model.n_lobes} Gaussian(s) per view, 92 views, built-in sky.

![under the sky]({sky}) ![the sky turned 120 degrees]({turned})

| step | seconds |
|---|---|
| bake (transport + fit) | {t_bake:.1f} |
| renders ({backend}, {args.width}x{args.height}) | {frame} |
| reference path tracing ({args.spp} spp) | {cmp["seconds"]["reference"]:.1f} |
| total | {total:.1f} |

Model file: `model.lobelight.npz`, {info["bytes"] / 1e6:.2f} MB.

Against the Monte Carlo reference (direct lighting, pixel centres, object pixels;
`compare/` holds the images and `compare.json`):

| method | component | PSNR, linear (dB) | PSNR, displayed (dB) | relative L2 |
|---|---|---|---|---|
{rows}

Reference noise (mean standard error / mean): {cmp["reference_noise"]["full"]:.3f}.
`linear` is the cross-fading baseline (radiance blended across views and vertices).
`ours_sh_diffuse` is ours with the paper's diffuse term alone (the whole sky, sun included, in
order-5 SH per vertex, and in the Gaussians' lighting); `ours` takes the sun out of the
lighting and shades its diffuse and glossy light per pixel with a shadow map and the material's
BRDF (`--no-sun` turns that off).
"""
    tmp = out / "report.md.tmp"
    tmp.write_text(report)
    tmp.replace(out / "report.md")
    gpu = torch.cuda.is_available()
    return {
        "command": "demo",
        "out": str(out),
        "report": str(out / "report.md"),
        "model": str(out / "model.lobelight.npz"),
        "stills": stills,
        "backend": backend,
        "table": cmp["table"],
        "seconds": {
            "bake": t_bake,
            "render": t_render,
            "frame": t_frame,
            "reference": cmp["seconds"]["reference"],
            "total": total,
        },
        "gpu": "a CUDA GPU is available: add --device cuda"
        if gpu
        else "CPU only; on a GPU (--device cuda) the bake is ~10x faster or more (one H100: "
        "20.6 s for the benchmark bake this kind of 2-core CPU does in 204 s, docs/benchmarks.md)",
    }


# --------------------------------------------------------------------------------------------
# parser


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="lobelight",
        description="Relight 3D objects under HDR environment lighting with spherical lobes.",
        epilog="Exit codes: 0 ok, 1 unexpected error, 2 bad input, 130 interrupted.",
    )
    p.add_argument("--version", action="version", version=f"lobelight {_version()}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def cmd(name, fn, help):
        sp = sub.add_parser(name, help=help, description=help)
        sp.add_argument("--json", action="store_true", help="print a machine-readable summary")
        sp.add_argument("--device", default="cpu", help="torch device (cpu, cuda, cuda:1, ...)")
        sp.set_defaults(run=fn)
        return sp

    def size(sp, w=512, h=512):
        sp.add_argument("--width", type=int, default=w)
        sp.add_argument("--height", type=int, default=h)

    def no_sun(sp):
        sp.add_argument(
            "--no-sun",
            action="store_true",
            help="keep the sun in the SH diffuse and the Gaussians' lighting (the paper's terms) "
            "instead of a per-pixel shadow-mapped light",
        )

    d = cmd("demo", _cmd_demo, "bake the built-in scene, render it, score it, write a report")
    d.add_argument("--out", default="lobelight-demo", help="output folder")
    d.add_argument("--scene", default="knot", help="scene to bake (default: the built-in knot)")
    d.add_argument("--lobes", type=int, default=1, choices=[1, 2, 3])
    d.add_argument("--spp", type=int, default=64, help="reference samples per pixel")
    size(d, 320, 240)
    no_sun(d)

    b = cmd("bake", _cmd_bake, "fit a model of a mesh or scene (resumes if interrupted)")
    b.add_argument(
        "scene",
        help="mesh (.ply .obj .stl .glb .off), scene (.toml .json) or a "
        "built-in name (knot, knot:2, sphere:3)",
    )
    b.add_argument("-o", "--output", help="model file (default: NAME.lobelight.npz)")
    b.add_argument(
        "--env",
        help=".hdr/.exr environment that render, view and compare use by default (the model "
        "itself relights under any; default: the scene file's, else the built-in sky)",
    )
    b.add_argument("--lobes", type=int, default=1, choices=[1, 2, 3], help="Gaussians per view")
    b.add_argument(
        "--indirect-paths",
        type=int,
        default=0,
        help="paths per vertex and view for indirect glossy (0: direct only)",
    )
    b.add_argument("--float16", action="store_true", help="store half floats (half the size)")
    b.add_argument("--seed", type=int, default=0)

    i = cmd("info", _cmd_info, "describe a model file")
    i.add_argument("model")

    r = cmd("render", _cmd_render, "render a model to an image (.png, .exr, .hdr)")
    r.add_argument("model")
    r.add_argument("-o", "--output", default="render.png")
    r.add_argument("--env", help=".hdr/.exr environment (default: the model's, else the sky)")
    r.add_argument("--camera", help="'ox,oy,oz:tx,ty,tz[:fov]' (default: the scene's)")
    r.add_argument("--rotate", type=float, default=None, help="turn the lighting (degrees)")
    r.add_argument("--parts", choices=["both", "diffuse", "glossy"], default="both")
    r.add_argument("--no-background", action="store_true")
    no_sun(r)
    r.add_argument("--exposure", default="auto", help="stops, or 'auto'")
    r.add_argument("--tonemap", choices=["srgb", "aces"], default="srgb")
    r.add_argument("--backend", choices=["auto", "gl", "torch"], default="auto")
    r.add_argument("--base-res", type=int, default=256, help="sharpest prefiltered level")
    size(r)

    v = cmd(
        "view",
        _cmd_view,
        "interactive window: drag to orbit, right-drag to turn the "
        "light, wheel to zoom, d/g/b diffuse/glossy/both, +/- exposure",
    )
    v.add_argument("model")
    v.add_argument("--env")
    no_sun(v)
    size(v, 1024, 768)

    c = cmd("compare", _cmd_compare, "score a model against the path tracer and baselines")
    c.add_argument("scene", help="the scene (fitted here unless --model is given)")
    c.add_argument("--model", help="a model file of that scene")
    c.add_argument("--lobes", type=int, default=1, choices=[1, 2, 3])
    c.add_argument("--env")
    c.add_argument("--out", default="lobelight-compare")
    c.add_argument("--spp", type=int, default=1024, help="reference samples per pixel")
    c.add_argument("--rotate", type=float, default=None)
    c.add_argument("--backend", choices=["auto", "gl", "torch"], default="auto")
    c.add_argument(
        "--baselines",
        nargs="*",
        default=["linear", "no_visibility", "sh10"],
        choices=["linear", "no_visibility", "sh10"],
    )
    c.add_argument("--base-res", type=int, default=256, help="sharpest prefiltered level")
    no_sun(c)
    size(c, 192, 144)

    cb = cmd(
        "compare-brdf",
        _cmd_compare_brdf,
        "SG-mixture BRDFs vs filtered importance sampling, Wang 2009 and the reference",
    )
    cb.add_argument("--out", default="lobelight-compare-brdf")
    cb.add_argument("--env", help=".hdr/.exr environment")
    cb.add_argument("--size", type=int, default=128, help="image size (the sphere fills it)")
    cb.add_argument("--ref-spp", type=int, default=4096, help="reference samples per pixel")
    cb.add_argument(
        "--backend",
        choices=["torch", "both"],
        default="torch",
        help="'both' also renders ours and FIS-40 with the GLSL shaders (PSNR and fps rows)",
    )

    f = cmd("figure5", _cmd_figure5, "the paper's Figure 5: Gaussians vs Haar vs SH")
    f.add_argument("--out", default="lobelight-figure5")

    ld = cmd(
        "lobes-demo",
        _cmd_lobes_demo,
        "cosine lobes: a moving light and occluder with soft shadows, to PNGs and a GIF",
    )
    ld.add_argument("--out", default="lobelight-lobes")
    ld.add_argument("--frames", type=int, default=24)
    ld.add_argument("--size", type=int, default=256)
    ld.add_argument(
        "--fused",
        action="store_true",
        help="shade with torch.compile'd kernels (faster frames after a compile of up to a minute)",
    )

    be = cmd("bench", _cmd_bench, "benchmarks with machine-readable output")
    be.add_argument(
        "what",
        choices=["prefilter", "transport", "fit", "render", "lobe-tables", "lobes", "brdf-fit"],
    )
    be.add_argument("--scene", default="knot:2", help="scene of transport/fit (knot:2: 11.5K)")
    be.add_argument("--lobes", type=int, default=1)
    be.add_argument("--material", default="ward", help="brdf-fit material (ward, ward_aniso)")
    be.add_argument("--base-res", type=int, default=512)
    be.add_argument("--backend", choices=["auto", "gl", "torch"], default="auto")
    be.add_argument(
        "--repeats",
        type=int,
        default=None,
        help="timed repeats (default: prefilter 3 builds, lobes 20 frames: on a shared "
        "machine the best of a few frames is mostly noise)",
    )
    be.add_argument(
        "--sun",
        action="store_true",
        help="render: shade the sky's sun per pixel; the light turns every frame, so its "
        "shadow map is redrawn every frame (the worst case)",
    )
    return p


def _version() -> str:
    from . import __version__

    return __version__


def _plain(x):
    if isinstance(x, float) and not math.isfinite(x):
        return str(x)
    return x


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the exit code (0 ok, 1 unexpected error, 2 bad input, 130 Ctrl-C)."""
    from .errors import InputError

    args = _parser().parse_args(argv)
    try:
        summary = args.run(args)
    except InputError as e:
        print(f"lobelight: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("lobelight: interrupted (a bake resumes when run again)", file=sys.stderr)
        return 130
    try:
        if args.json:
            print(json.dumps(summary, indent=2, default=_plain))
        else:
            for k, v in summary.items():
                print(f"{k}: {v}")
        sys.stdout.flush()
    except BrokenPipeError:
        # the reader went away (`lobelight info m.npz | head -1`): its choice, not an error;
        # point stdout at devnull so that the interpreter's final flush does not fail again
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return 0


if __name__ == "__main__":
    sys.exit(main())
