"""The ``lobelight`` command line: one entry point, ``--help`` everywhere, ``--json`` for machines.

Commands: ``demo``, ``bake``, ``info``, ``render``, ``export``, ``view``, ``compare``,
``compare-brdf``, ``gallery``, ``figure5``, ``lobes-demo``, ``bench``: their arguments are built
in :mod:`._arguments` (one builder per command, without torch), what each does is in
:mod:`._commands` (``run_NAME(args) -> dict``), the gallery's in :mod:`._gallery`.

Every command takes ``--json`` (stdout carries only the JSON summary, or a JSON error object)
and ``--quiet`` (offered where a command reports progress); those that do heavy work take
``--device``, and those that cast rays ``--rays``. Progress goes to stderr: bars on a terminal,
plain lines at most every few seconds elsewhere (:mod:`lobelight.progress`). Flags share their
names across commands: ``-o/--output``, ``--width/--height``, ``--spp``, ``--sun/--no-sun``,
``--backend``.

Exit codes: 0 success; 1 unexpected error (one line on stderr naming the log file that holds
the traceback, or the traceback itself with ``--debug``); 2 bad input (one line on stderr naming
the input and the problem); 130 interrupted (Ctrl-C), 143 terminated (SIGTERM, as batch
schedulers send it): one line each, and a bake resumes from its checkpoint when run again. Under
``--json`` every error is also a JSON object ``{"error": {...}}`` on stdout.

Outputs never replace inputs: a file the command read (the same path, a hard link or a symbolic
link to it) is refused as an output before any work (:func:`lobelight._io.check_outputs`), and
no write replaces one (:func:`lobelight._io.protect_inputs`).
"""

from __future__ import annotations

import contextlib
import errno
import importlib
import json
import math
import os
import re
import shlex
import signal
import sys
import tempfile
import threading
import time
import traceback
from pathlib import Path

from .. import __version__
from .._cache import MAX_MB_ENV, cache_dir, cache_max_bytes, check_environment
from .._container import read_ahead
from .._io import protect_inputs
from ..errors import MAX_QUOTED, InputError, Terminated, one_line, os_problem, shorten
from ._arguments import _parser, _UsageError
from ._process import end_process, imports_uncollected, tune

__all__ = ["main", "tune"]


def _plain(x):
    if isinstance(x, float) and not math.isfinite(x):
        return str(x)
    return x


def _cell(v) -> str:
    """A value as text: floats to 4 digits; a string from a file (a scene's name, a provenance
    field) with its control characters escaped (a terminal escape is shown, not obeyed)."""
    return f"{v:.4g}" if isinstance(v, float) else one_line(str(v))


def _print_text(summary: dict) -> None:
    """A summary for people: tables as aligned columns, mappings indented, one line each."""
    for k, v in summary.items():
        if isinstance(v, list) and v and all(isinstance(r, dict) for r in v):
            cols = list(v[0])
            cells = [cols] + [[_cell(r.get(c, "")) for c in cols] for r in v]
            widths = [max(len(row[i]) for row in cells) for i in range(len(cols))]
            print(f"{one_line(str(k))}:")
            for row in cells:
                line = "  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True))
                print("  " + line.rstrip())
        elif isinstance(v, dict):
            print(f"{one_line(str(k))}:")
            for kk, vv in v.items():
                print(f"  {one_line(str(kk))}: {_cell(vv)}")
        else:
            print(f"{one_line(str(k))}: {_cell(v)}")


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


def _fail(json_mode: bool, what: str, problem: str, code: int, **extra) -> int:
    """Report an error: one line on stderr, and the JSON error object on stdout under --json
    (with ``extra`` fields, e.g. the log file of an unexpected error)."""
    # a usage error quotes the arguments: escaped, and a long one shortened
    what, problem = shorten(one_line(what), 4 * MAX_QUOTED), shorten(one_line(problem))
    print(f"lobelight: error: {what}: {problem}" if what else f"lobelight: error: {problem}",
          file=sys.stderr)  # fmt: skip
    if json_mode:
        err = {"error": {"code": code, "input": what, "problem": problem, **extra}}
        print(json.dumps(err, indent=2))
    return code


#: The system's refusals of a path given on the command line, reported as bad input (exit 2).
_PATH_ERRNOS = frozenset(
    getattr(errno, name)
    for name in ("ENAMETOOLONG", "ELOOP", "EACCES", "EPERM", "EROFS", "ENOTDIR", "EISDIR")
)


def _on_sigterm(signum, frame) -> None:
    raise Terminated


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the exit code (0 ok, 1 unexpected error, 2 bad input, 130 Ctrl-C,
    143 SIGTERM).

    Without ``argv`` the command line is the process's own (the ``lobelight`` program,
    ``python -m lobelight.cli``): the process then ends with that code as soon as the command
    is done and its output flushed, without the interpreter's teardown
    (:func:`lobelight.cli._process.end_process`, which says what runs and what is skipped). A
    program that runs the command line inside its own process passes ``argv``
    (``main(sys.argv[1:])``) and gets the code back."""
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGTERM, _on_sigterm)
        try:
            code = _main(argv)
        finally:
            signal.signal(signal.SIGTERM, previous)
    else:
        code = _main(argv)
    if argv is None:
        end_process(code)
    return code


def _main(argv: list[str] | None) -> int:
    own_process = argv is None
    argv = _join_signed(list(sys.argv[1:] if argv is None else argv))
    json_mode = "--json" in argv
    debug = "--debug" in argv
    try:
        args = _parser().parse_args(argv)
    except _UsageError as e:
        # the JSON names the flag argparse names ("argument --width: invalid ...")
        flag = re.search(r"argument ([^:\s]+)", str(e))
        return _fail(json_mode, "", str(e), 2, **({"input": flag[1]} if flag else {}))
    except Exception:  # the parser's own failure: the one door below
        return _unexpected(json_mode, debug)
    try:
        summary = _run(args, own_process)
    except InputError as e:
        return _fail(args.json, e.what, e.problem, 2)
    except (KeyboardInterrupt, Terminated) as e:
        return _stopped(args, e)
    except OSError as e:
        if e.errno not in _PATH_ERRNOS:
            return _unexpected(args.json, args.debug)
        # a path the system refuses (too long a name, a loop of links, no permission) that
        # no check before the work caught: bad input, named as the system names it
        where = e.filename2 if e.filename2 is not None else e.filename
        return _fail(args.json, "" if where is None else str(where), os_problem(e), 2)
    except Exception:
        return _unexpected(args.json, args.debug)
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


def _run(args, own_process: bool = False) -> dict:
    """The command ``args`` name, after the checks every command shares (the environment's
    settings, the device, the ray engine), with its outputs kept off its inputs
    (:func:`lobelight._io.protect_inputs`). In a process of its own (``own_process``) the
    commands' imports run without the garbage collector (:func:`._process.imports_uncollected`);
    a program that embeds the command line keeps its collector as it is."""
    check_environment()
    _no_cap_as_a_number()
    if own_process and isinstance(getattr(args, "model", None), str):
        # the model file's members inflate in a child process while torch loads here
        # (:mod:`lobelight._container`); the reader takes them if the file is still the same
        read_ahead(args.model)
    # the commands (and torch) load once the line is parsed: --help and a mistyped
    # command answer at once
    with imports_uncollected() if own_process else contextlib.nullcontext():
        commands = importlib.import_module("lobelight.cli._commands")
    # the process is ours: its allocator and OpenMP settings (:mod:`._process`), made
    # once torch is loaded, so that the short spin reaches only the runtimes loaded later
    tune()
    args.device = commands.check_device(args.device)
    commands.use_rays(args.rays)
    with protect_inputs():
        return getattr(commands, args.run)(args)


def _no_cap_as_a_number() -> None:
    """``LOBELIGHT_CACHE_MAX_MB=inf`` (no cap, :func:`lobelight._cache.cache_max_bytes`) as the
    largest whole number of megabytes, for every reader of the variable in this process."""
    if cache_max_bytes(0) == sys.maxsize:
        os.environ[MAX_MB_ENV] = str(sys.maxsize >> 20)


def _stopped(args, e: BaseException) -> int:
    """Ctrl-C (130) or SIGTERM (143): one line; a bake says that it resumes (its checkpoint),
    other commands leave no file half-written (every file is written whole)."""
    code, what = (143, "terminated") if isinstance(e, Terminated) else (130, "interrupted")
    note = " (a bake resumes when run again)" if args.command == "bake" else ""
    print(f"lobelight: {what}{note}", file=sys.stderr)
    if args.json:
        print(json.dumps({"error": {"code": code, "input": "", "problem": what}}))
    return code


def _unexpected(json_mode: bool, debug: bool) -> int:
    """An error no check foresaw (a bug, or a library's failure): exit 1 with one line naming
    the log file that holds the traceback, or the traceback itself under ``--debug``."""
    exc = sys.exc_info()[1]
    summary = f"unexpected {type(exc).__name__}: {exc}"
    if debug:
        traceback.print_exc()
        return _fail(json_mode, "", summary, 1)
    log = _write_log(traceback.format_exc())
    where = f"the traceback is in {log}" if log else "no log file could be written"
    return _fail(json_mode, "", f"{summary} ({where}; --debug prints it)", 1, log=log)


def _write_log(text: str) -> str | None:
    """``text`` in a new file under the cache folder's ``logs`` (else the temporary folder);
    its path, or None where neither can be written."""
    for folder in (cache_dir() / "logs", Path(tempfile.gettempdir())):
        try:
            folder.mkdir(parents=True, exist_ok=True)
            stamp = time.strftime("%Y%m%d-%H%M%S")
            fd, path = tempfile.mkstemp(prefix=f"lobelight-{stamp}-", suffix=".log", dir=folder)
            with os.fdopen(fd, "w") as f:
                f.write(f"lobelight {__version__}: {' '.join(map(shlex.quote, sys.argv))}\n")
                f.write(text)
            return path
        except OSError:
            continue
    return None
