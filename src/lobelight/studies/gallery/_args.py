"""The gallery's arguments for any parser (:func:`add_arguments`), importable without torch, so
that building ``lobelight``'s parser stays fast."""

from __future__ import annotations

import argparse
from typing import Any

from ._settings import DATA_ENV, VARIANTS, ReferenceSettings

__all__ = ["ACTIONS", "DEFAULT_REFS", "REFS_ENV", "add_arguments"]

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
        "-o",
        "--output",
        default="lobelight-gallery",
        help="output folder (models, strips, JSON)",
    )
    g.add_argument(
        "--gaussians",
        type=int,
        default=None,
        choices=[1, 2, 3],
        help="Gaussians per view of every bake (default: each bake's own, 2 for the metals)",
    )
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
