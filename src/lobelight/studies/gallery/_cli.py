"""What ``lobelight gallery {list,references,run}`` does: :func:`main_from_args` runs the action
the arguments of :func:`lobelight.studies.gallery._args.add_arguments` ask for and returns its
summary (``python -m lobelight.studies.gallery`` is the same command)."""

from __future__ import annotations

import argparse
import json
import os
from typing import Any

from ..._size import check_pixels, parse_size
from ...errors import InputError
from ._args import ACTIONS, DEFAULT_REFS, REFS_ENV
from ._references import render_references
from ._run import run
from ._scenes import select
from ._settings import ReferenceSettings

__all__ = ["main_from_args"]


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
        w, h = (check_pixels("--size", v) for v in parse_size(args.size))
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
            n_gaussians=args.gaussians,
            samples=args.samples,
            backend=args.backend,
            base_res=args.base_res,
            sun=args.sun,
            device=device,
            fit_options=_fit_options(args.fit_option),
            progress=progress,
        )
    raise InputError("action", f"must be one of {ACTIONS}, got {args.action!r}")
