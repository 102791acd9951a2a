"""The gallery's command line: ``python -m lobelight.gallery {list,references,run}``.

:func:`add_arguments` puts the gallery's arguments on any parser (a ``lobelight gallery``
sub-command among them) and :func:`main_from_args` runs what they ask for, returning the
summary; :func:`main` is the stand-alone entry point behind ``python -m lobelight.gallery``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Any

from ..errors import InputError
from ._references import VARIANTS, ReferenceSettings, render_references
from ._run import run
from ._scenes import DATA_ENV, select

__all__ = ["ACTIONS", "REFS_ENV", "add_arguments", "main", "main_from_args"]

#: The environment variable that names the references folder when ``--refs`` is not given.
REFS_ENV = "LOBELIGHT_GALLERY_REFS"
#: The references folder when neither ``--refs`` nor ``$LOBELIGHT_GALLERY_REFS`` is given.
DEFAULT_REFS = "gallery-refs"
ACTIONS = ("list", "references", "run")


def _optional(parser: argparse.ArgumentParser, *flags: str, **kw: Any) -> None:
    """Add an argument unless the parser has one of that name (a caller's common flags)."""
    try:
        parser.add_argument(*flags, **kw)
    except argparse.ArgumentError:
        pass


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The gallery's arguments: the action (``list``, ``references`` or ``run``), the folders,
    the reference settings, the bake and render settings, and ``--json``, ``--device`` and
    ``-q/--quiet`` unless the parser has them already."""
    parser.add_argument(
        "action",
        choices=ACTIONS,
        help="list: the scenes; references: render the missing or stale Mitsuba references; "
        "run: bake, render and score the scenes against their references",
    )
    parser.add_argument(
        "--data",
        default=None,
        help=f"data folder with meshes/ and envmaps/ (default ${DATA_ENV})",
    )
    parser.add_argument(
        "--refs",
        default=None,
        help=f"references folder (default ${REFS_ENV}, else ./{DEFAULT_REFS})",
    )
    parser.add_argument(
        "--scenes", nargs="+", default=None, help="scene or bake names (default: all of them)"
    )
    r = parser.add_argument_group("references")
    d = ReferenceSettings()
    r.add_argument("--spp", type=int, default=d.spp, help="samples per pixel")
    r.add_argument("--pass-spp", type=int, default=d.pass_spp, help="samples per render pass")
    r.add_argument("--max-depth", type=int, default=d.max_depth, help="Mitsuba's path depth")
    r.add_argument("--size", default=f"{d.width}", help="image size: N or WxH")
    r.add_argument("--seed", type=int, default=d.seed, help="the passes' base seed")
    r.add_argument(
        "--variant",
        default=None,
        help=f"Mitsuba variant (default: the first of {', '.join(VARIANTS)} that runs)",
    )
    r.add_argument("--force", action="store_true", help="render every reference again")
    g = parser.add_argument_group("run")
    g.add_argument(
        "-o", "--output", default="lobelight-gallery", help="output folder (models, strips, JSON)"
    )
    g.add_argument("--lobes", type=int, default=1, choices=[1, 2, 3], help="Gaussians per view")
    g.add_argument(
        "--samples", type=int, default=16, help="our samples per pixel (box filter, 1..256)"
    )
    g.add_argument(
        "--backend", choices=["auto", "gl", "torch"], default="auto", help="our renderer"
    )
    g.add_argument(
        "--base-res",
        type=int,
        default=256,
        help="face resolution of the sharpest prefiltered level",
    )
    g.add_argument(
        "--sun",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="shade the map's sun per pixel with a shadow map",
    )
    g.add_argument(
        "--fit-option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="another fit_model argument (VALUE read as JSON, else a string); repeatable",
    )
    _optional(parser, "--json", action="store_true", help="print the summary as JSON on stdout")
    _optional(parser, "--device", default="cpu", help="torch device (cpu, cuda, cuda:1)")
    _optional(parser, "-q", "--quiet", action="store_true", help="no progress on stderr")


def _size(text: str) -> tuple[int, int]:
    w, _, h = str(text).lower().partition("x")
    try:
        width, height = int(w), int(h or w)
    except ValueError:
        raise InputError("--size", f"expected N or WxH, got {text!r}") from None
    if not (1 <= width <= 16384 and 1 <= height <= 16384):
        raise InputError("--size", f"must be 1..16384 pixels, got {text!r}")
    return width, height


def _fit_options(items: list[str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for item in items:
        key, eq, value = item.partition("=")
        if not eq or not key:
            raise InputError("--fit-option", f"expected KEY=VALUE, got {item!r}")
        try:
            out[key] = json.loads(value)
        except ValueError:
            out[key] = value
    return out


def main_from_args(args: argparse.Namespace) -> dict[str, Any]:
    """Run the action ``args`` ask for (:func:`add_arguments`); returns its summary. Bad input
    raises :class:`lobelight.errors.InputError` naming it."""
    progress = not getattr(args, "quiet", False)
    device = getattr(args, "device", None)
    refs = args.refs or os.environ.get(REFS_ENV) or DEFAULT_REFS
    if args.action == "list":
        return {"scenes": [s.to_dict() for s in select(args.scenes)]}
    if args.action == "references":
        w, h = _size(args.size)
        settings = ReferenceSettings(
            spp=args.spp,
            max_depth=args.max_depth,
            width=w,
            height=h,
            pass_spp=args.pass_spp,
            seed=args.seed,
        )
        return render_references(
            args.scenes,
            data=args.data,
            refs=refs,
            settings=settings,
            variant=args.variant,
            force=args.force,
            progress=progress,
        )
    if args.action == "run":
        if not 1 <= args.samples <= 256:
            raise InputError("--samples", f"must be 1..256, got {args.samples}")
        return run(
            args.scenes,
            data=args.data,
            refs=refs,
            out=args.output,
            n_lobes=args.lobes,
            samples=args.samples,
            backend=args.backend,
            base_res=args.base_res,
            sun=args.sun,
            device=device,
            fit_options=_fit_options(args.fit_option),
            progress=progress,
        )
    raise InputError("action", f"must be one of {ACTIONS}, got {args.action!r}")


def _print_text(action: str, summary: dict[str, Any]) -> None:
    if action == "list":
        for s in summary["scenes"]:
            print(f"{s['name']:32s} {s['mesh']:14s} {s['envmap']:30s} {s['material']}")
    elif action == "references":
        if summary.get("note"):
            print(f"note: {summary['note']}")
        for n, t in summary["seconds"].items():
            print(f"rendered {n} in {t:.1f} s ({summary['variant']}, Mitsuba {summary['mitsuba']})")
        print(
            f"{len(summary['kept'])} kept, {len(summary['rendered'])} rendered: {summary['refs']}"
        )
    else:

        def cell(v, fmt):
            return "-" if v is None else format(v, fmt)

        print(f"{'scene':32s} {'PSNR obj':>8s} {'full':>6s} {'rel L2':>7s} {'energy':>7s}")
        for n, s in summary["scenes"].items():
            print(
                f"{n:32s} {cell(s['psnr_display'], '8.2f')} {cell(s['psnr_display_full'], '6.2f')}"
                f" {cell(s['rel_l2'], '7.4f')} {cell(s['energy_ratio'], '7.4f')}"
            )
        med = summary.get("summary", {}).get("median", {})
        print(f"median: {json.dumps(med)}")


def main(argv: list[str] | None = None) -> int:
    """``python -m lobelight.gallery``; returns the exit code (0 ok, 2 bad input, 130
    interrupted)."""
    parser = argparse.ArgumentParser(
        prog="python -m lobelight.gallery",
        description="A scored gallery of real scenes against Mitsuba 3 references.",
    )
    add_arguments(parser)
    args = parser.parse_args(argv)
    try:
        summary = main_from_args(args)
    except InputError as e:
        print(f"lobelight: error: {e.what}: {e.problem}", file=sys.stderr)
        if args.json:
            print(json.dumps({"error": {"code": 2, "input": e.what, "problem": e.problem}}))
        return 2
    except KeyboardInterrupt:
        print("lobelight: interrupted (a bake resumes when run again)", file=sys.stderr)
        return 130
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        _print_text(args.action, summary)
    return 0
