"""The child process of ``lobelight bench start``: ``lobelight render`` run in this process, with
timers around the library calls the command makes.

Run as a script, ``python _start_child.py TIMES.json T0 -- render MODEL ...``: ``T0`` is the
parent's ``time.time()`` just before it started this process. The library modules are
imported first and their public functions wrapped (before the command line imports them, so
that it binds the wrapped ones); then the command line runs as ``python -m lobelight.cli``
does (its ``main`` then ends the process itself: :func:`lobelight.cli.main`). At exit the
timings go to ``TIMES.json``, from an ``atexit`` handler registered before the command's own
(so it runs after theirs, whichever way the process ends): per label the summed seconds, the
calls and the first call's start, in seconds after this process began (``time.perf_counter``),
and the wall-clock instants ``start`` (this script's first line) and ``end`` (the record's
writing, after the command and the other exit handlers).
"""

import time

_T_START = time.time()
_P_START = time.perf_counter()

import gc  # noqa: E402 (the clock starts first)

# the command line imports with the collector off (lobelight.cli._process.imports_uncollected),
# and this script imports the same modules before it: the same way, so that they cost the same
gc.disable()

import atexit  # noqa: E402
import json  # noqa: E402
import runpy  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

# a script's folder comes first on sys.path: this package's modules must not shadow others
if sys.path and Path(sys.path[0]).resolve() == Path(__file__).resolve().parent:
    sys.path.pop(0)

# the command line starts inflating the model file in a child process before it imports torch
# (lobelight._container): so here, the model being the render's first argument
from lobelight._container import read_ahead  # noqa: E402

_ARGV = sys.argv[4:] if sys.argv[3:4] == ["--"] else sys.argv[3:]
if _ARGV[:1] == ["render"] and len(_ARGV) > 1:
    read_ahead(_ARGV[1])

import torch  # noqa: E402

_P_TORCH = time.perf_counter()

import lobelight.brdf  # noqa: E402
import lobelight.envmap  # noqa: E402
import lobelight.model  # noqa: E402

_TIMES: dict[str, dict] = {}
#: The labels of the timed calls under way, outermost first.
_ACTIVE: list[str] = []


def _cube_label(*_args, **_kwargs) -> str:
    """A cube-map resampling's label: for the chain's base cube, the SH projection, or else the
    background (the one other cube a render makes)."""
    for outer, label in (("chain", "chain_cube"), ("sh_projection", "sh_cube")):
        if outer in _ACTIVE:
            return label
    return "background"


def _wrap(owner, name: str, label) -> None:
    """Replace ``owner.name`` by a wrapper that adds each call's seconds to ``label`` (a string,
    or a function of the call's arguments that names it)."""
    fn = getattr(owner, name)

    def timed(*args, **kwargs):
        key = label if isinstance(label, str) else label(*args, **kwargs)
        t = time.perf_counter()
        _ACTIVE.append(key)
        try:
            return fn(*args, **kwargs)
        finally:
            _ACTIVE.pop()
            rec = _TIMES.setdefault(key, {"seconds": 0.0, "calls": 0, "first": t - _P_START})
            rec["seconds"] += time.perf_counter() - t
            rec["calls"] += 1

    timed.__wrapped__ = fn
    setattr(owner, name, timed)


# before lobelight.render is imported: it binds these names when it loads
_wrap(lobelight.envmap, "prefilter", "chain")
_wrap(lobelight.envmap, "extract_sun", "sun")
_wrap(lobelight.envmap, "load", "map_read")
_wrap(lobelight.envmap, "builtin", "map_read")
_wrap(lobelight.envmap.EnvMap, "to_cubemap", _cube_label)
_wrap(lobelight.model, "load", "model_read")
_wrap(lobelight.brdf, "sharp_lobe", "sharp_lobe")

import lobelight.lobes.sh  # noqa: E402
import lobelight.render  # noqa: E402
from lobelight.geometry import sphere  # noqa: E402

_wrap(lobelight.lobes.sh, "project_envmap", "sh_projection")
_wrap(sphere, "triangle_candidates", "candidates")
_wrap(lobelight.render.Lighting, "__init__", "lighting")
_wrap(lobelight.render.Renderer, "__init__", "renderer_setup")
_wrap(lobelight.render.Renderer, "render", "frame")
_wrap(lobelight.render, "save_image", "save")
_wrap(lobelight.render, "auto_exposure", "exposure")
_P_IMPORTS = time.perf_counter()
# ... and then, as the command line does, freezes what they made and collects again
gc.freeze()
gc.enable()


def _gl_hooks() -> None:
    """Time the GL context's creation and its programs' compilation (the gl extra)."""
    try:
        import moderngl  # optional (the gl extra)
    except ImportError:
        return
    _wrap(moderngl, "create_standalone_context", "gl_context")
    _wrap(moderngl.Context, "program", "gl_programs")


def _write_record(out: str, t0: float) -> None:
    """The timings (module docstring) as JSON in ``out``; ``t0`` the parent's start."""
    record = {
        "parent_t0": t0,
        "start": _T_START,
        "end": time.time(),
        "torch_imported": _P_TORCH - _P_START,
        "library_imported": _P_IMPORTS - _P_START,
        "finished": time.perf_counter() - _P_START,
        "torch_threads": torch.get_num_threads(),
        "timers": _TIMES,
    }
    Path(out).write_text(json.dumps(record))


def main() -> int:
    out, t0 = sys.argv[1], float(sys.argv[2])
    argv = _ARGV
    _gl_hooks()
    atexit.register(_write_record, out, t0)
    sys.argv = ["lobelight", *argv]
    try:
        runpy.run_module("lobelight.cli", run_name="__main__", alter_sys=True)
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
