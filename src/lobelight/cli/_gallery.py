"""``lobelight gallery {list,references,run}``: its arguments (:func:`add_arguments`, built
without importing torch) and what each action does (:func:`gallery_main`).

The gallery itself, its scenes, references, run and scores, is :mod:`lobelight.studies.gallery`;
its submodules load when first used, so the parser reads the reference settings' defaults
without loading the rest.
"""

from __future__ import annotations

import argparse
import json
import os
from typing import Any

from ..data import DATA_ENV
from ..errors import InputError
from ..studies import gallery
from ._limits import (
    MAX_BASE_RES,
    MAX_DEPTH,
    MAX_SAMPLES,
    MAX_SPP,
    base_res_type,
    bounded_int,
)
from ._size import check_image, parse_size

__all__ = ["ACTIONS", "DEFAULT_REFS", "REFS_ENV", "add_arguments", "gallery_main"]

#: The environment variable that names the references folder when ``--refs`` is not given.
REFS_ENV = "LOBELIGHT_GALLERY_REFS"
#: The largest base seed: the passes' seeds (base x passes + pass) stay within 32 bits.
MAX_MITSUBA_SEED = 2**24
#: The references folder when neither ``--refs`` nor ``$LOBELIGHT_GALLERY_REFS`` is given.
DEFAULT_REFS = "gallery-refs"
ACTIONS = ("list", "references", "run")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The gallery's own arguments: the action (``list``, ``references`` or ``run``), the
    folders, the reference settings, and the bake and render settings (``--json``, ``--device``,
    ``--rays`` and ``-q/--quiet`` come with the command's parser)."""
    parser.add_argument(
        "action",
        choices=ACTIONS,
        help="list: the scenes; references: render the missing or stale Mitsuba references; "
        "run: bake, render and score the scenes against their references",
    )
    parser.add_argument(
        "--data",
        default=None,
        help=f"data folder with meshes/ and envmaps/ (default ${DATA_ENV}); files it lacks "
        "are read from the repository's gallery-data/",
    )
    parser.add_argument(
        "--refs",
        default=None,
        help=f"references folder (default ${REFS_ENV}, else ./{DEFAULT_REFS})",
    )
    parser.add_argument(
        "--scenes", nargs="+", default=None, help="scene or bake names (default: all of them)"
    )
    _add_reference_settings(parser.add_argument_group("references"))
    _add_run_settings(parser.add_argument_group("run"))


def _add_reference_settings(r) -> None:
    d = gallery.ReferenceSettings()
    spp = bounded_int(1, MAX_SPP)
    r.add_argument(
        "--spp",
        type=spp,
        default=d.spp,
        help=f"samples per pixel (1..{MAX_SPP}); the sharp metals' references take "
        f"{gallery.SHARP_REFERENCE_SAMPLES} times as many",
    )
    r.add_argument(
        "--pass-spp", type=spp, default=d.pass_spp, help=f"samples per render pass (1..{MAX_SPP})"
    )
    r.add_argument(
        "--max-depth",
        type=bounded_int(-1, MAX_DEPTH),
        default=d.max_depth,
        help=f"Mitsuba's path depth (-1: unbounded; at most {MAX_DEPTH})",
    )
    r.add_argument("--size", default=f"{d.width}", help="image size: N or WxH (as render's --size)")
    r.add_argument(
        "--seed",
        type=bounded_int(0, MAX_MITSUBA_SEED),
        default=d.seed,
        help=f"the passes' base seed (0..{MAX_MITSUBA_SEED}, Mitsuba's seeds are 32-bit)",
    )
    r.add_argument(
        "--variant",
        default=None,
        help=f"Mitsuba variant (default: the first of {', '.join(gallery.VARIANTS)} that runs)",
    )
    r.add_argument("--force", action="store_true", help="render every reference again")


def _add_run_settings(g) -> None:
    g.add_argument(
        "-o",
        "--output",
        default="lobelight-gallery",
        help="output folder (models, strips, JSON)",
    )
    g.add_argument(
        "--gaussians",
        type=gaussian_count,
        default=None,
        choices=["auto", 1, 2, 3],
        help="Gaussians per view of every bake (default: each bake's own, else fit_model's "
        "default, auto: chosen from the material)",
    )
    g.add_argument(
        "--samples",
        type=bounded_int(1, MAX_SAMPLES),
        default=16,
        help=f"our samples per pixel (box filter, 1..{MAX_SAMPLES})",
    )
    g.add_argument(
        "--backend", choices=["auto", "gl", "torch"], default="auto", help="our renderer"
    )
    g.add_argument(
        "--base-res",
        type=base_res_type,
        default="auto",
        help="face resolution of the sharpest prefiltered level (auto: the one each bake's "
        f"sharpest lobes need under its map; a power of two, at most {MAX_BASE_RES}: the "
        "largest whose chain fits half of this machine's memory)",
    )
    g.add_argument(
        "--sun",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="shade the map's sun per pixel with a shadow map",
    )
    g.add_argument(
        "--sweep",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="time Mitsuba at equal quality: an spp sweep per scene, scored as ours",
    )
    g.add_argument(
        "--sweep-max-spp",
        type=bounded_int(1, MAX_SPP),
        default=gallery.SWEEP_MAX_SPP,
        help="the sweep's largest samples per pixel (1, 2, 4, ... up to it)",
    )
    g.add_argument(
        "--fit-option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="another fit_model argument (VALUE read as JSON, else a string); repeatable",
    )


def gaussian_count(text: str) -> str | int:
    """``--gaussians``: ``auto`` or a whole number (argparse checks it against the choices)."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be auto, 1, 2 or 3, got {text!r}") from None


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


#: The columns of ``gallery list``'s table (``--json`` gives every field of every scene).
_LIST_COLUMNS = ("name", "mesh", "envmap", "material")


def _short(key: str, value) -> str:
    """A table cell: a mesh's file name without its folder, a map file's stem, ``-`` for
    nothing."""
    text = "-" if value is None else str(value)
    if key == "mesh":
        return text.rsplit("/", 1)[-1]
    return text.removesuffix(".hdr").removesuffix(".exr")


def gallery_main(args: argparse.Namespace) -> dict[str, Any]:
    """Run the action ``args`` ask for (:func:`add_arguments`); returns its summary. Bad input
    raises :class:`lobelight.errors.InputError` naming it."""
    progress = not getattr(args, "quiet", False)
    device = getattr(args, "device", None)
    refs = args.refs or os.environ.get(REFS_ENV) or DEFAULT_REFS
    if args.action == "list":
        scenes = [s.to_dict() for s in gallery.select(args.scenes)]
        if not getattr(args, "json", False):  # a table that fits a terminal; --json: every field
            scenes = [{k: _short(k, s.get(k)) for k in _LIST_COLUMNS} for s in scenes]
        return {"scenes": scenes}
    if args.action == "references":
        w, h = check_image("--size", *parse_size(args.size))
        settings = gallery.ReferenceSettings(
            spp=args.spp,
            max_depth=args.max_depth,
            width=w,
            height=h,
            pass_spp=args.pass_spp,
            seed=args.seed,
        )
        return gallery.render_references(
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
        return gallery.run(
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
            sweep=args.sweep,
            sweep_max_spp=args.sweep_max_spp,
            progress=progress,
        )
    raise InputError("action", f"must be one of {ACTIONS}, got {args.action!r}")
