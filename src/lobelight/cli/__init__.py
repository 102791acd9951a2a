"""The ``lobelight`` command line: one entry point, ``--help`` everywhere, ``--json`` for machines.

Commands: ``demo``, ``bake``, ``info``, ``render``, ``view``, ``compare``, ``compare-brdf``,
``gallery``, ``figure5``, ``lobes-demo``, ``bench``: their arguments are built in
:mod:`._arguments` (one builder per command, without torch), what each does is in
:mod:`._commands` (``run_NAME(args) -> dict``), the gallery's in :mod:`._gallery`.

Every command takes ``--json`` (stdout carries only the JSON summary, or a JSON error object),
``--device`` and ``--quiet``. Progress goes to stderr: bars on a terminal, plain lines at most
every few seconds elsewhere (:mod:`lobelight.progress`). Flags share their names across
commands: ``-o/--output``, ``--width/--height``, ``--spp``, ``--sun/--no-sun``, ``--backend``.

Exit codes: 0 success; 1 unexpected error; 2 bad input (one line on stderr naming the input and
the problem); 130 interrupted (Ctrl-C), 143 terminated (SIGTERM, as batch schedulers send it):
one line each, and a bake resumes from its checkpoint when run again.
"""

from __future__ import annotations

import importlib
import json
import math
import os
import re
import signal
import sys
import threading

from ..errors import InputError, one_line
from ._arguments import _parser, _UsageError
from ._process import tune

__all__ = ["main", "tune"]


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
        # the process is ours: its allocator and OpenMP settings (:mod:`._process`), made
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
