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
from ._args import ACTIONS, DEFAULT_REFS, REFS_ENV, add_arguments
from ._references import render_references
from ._run import run
from ._scenes import select
from ._settings import ReferenceSettings

__all__ = ["main", "main_from_args"]


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
