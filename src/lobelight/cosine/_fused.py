"""Optional kernel fusion of the shading hot path with ``torch.compile``.

Shading a frame is a few hundred short element-wise steps over flat lists (points, lobe pairs,
quad-tree cells, shadow leaves). In eager torch each step reads and writes its whole list, so a
frame is bound by memory traffic and per-operator overhead, not arithmetic. The functions
decorated with :func:`kernel` are pure tensor code (no data-dependent shapes, no tensor-to-Python
conversions), so TorchInductor can fuse each into a few loops (C++/OpenMP on the CPU, Triton on
CUDA). The eager code is the same function: fusion changes speed, not the arithmetic (up to
float rounding, tested).

On the CPU a compiled kernel keeps the number of threads of the call that compiled it (TorchInductor
writes it into the generated OpenMP loops), so set ``torch.set_num_threads`` before the first
fused call of a process.

Fusion is off by default: compiling takes a while per process the first time (the inductor's
on-disk cache shortens later runs), which only pays off over many frames. Turn it on
around a loop of frames with :func:`fusion` or ``shade_points(..., fused=True)``. Where
compiling fails (no C++ compiler, an unsupported device), a warning says so once and the eager
code runs instead.
"""

from __future__ import annotations

import contextlib
import functools
import subprocess
import threading
import warnings
from collections.abc import Callable, Iterator
from typing import TypeVar

import torch

__all__ = ["fusion", "fusion_enabled", "kernel"]

_F = TypeVar("_F", bound=Callable)
_state = threading.local()
_broken: list[str] = []  # why compiling failed, once per process


def fusion_enabled() -> bool:
    """Whether :func:`kernel` functions run compiled in this thread."""
    return bool(getattr(_state, "on", False)) and not _broken


@contextlib.contextmanager
def fusion(enabled: bool = True) -> Iterator[None]:
    """Run :func:`kernel` functions compiled (``enabled``) or eager inside the block."""
    old = getattr(_state, "on", False)
    _state.on = bool(enabled)
    try:
        yield
    finally:
        _state.on = old


def _compiler_failure(exc: BaseException) -> bool:
    """Whether ``exc`` comes from torch.compile's machinery (not from the function itself)."""
    return isinstance(exc, (OSError, subprocess.CalledProcessError)) or type(
        exc
    ).__module__.startswith(("torch._dynamo", "torch._inductor"))


def kernel(fn: _F) -> _F:
    """Decorate a pure tensor function: compiled (dynamic shapes) when fusion is on.

    Inside another kernel being compiled the plain function is called, so that nested kernels
    are traced into one graph rather than compiled separately.
    """
    compiled: list[Callable] = []

    @functools.wraps(fn)
    def call(*args, **kwargs):
        if torch.compiler.is_compiling() or not fusion_enabled():
            return fn(*args, **kwargs)
        if not compiled:
            compiled.append(torch.compile(fn, dynamic=True))
        try:
            return compiled[0](*args, **kwargs)
        except Exception as exc:
            if not _compiler_failure(exc):
                raise
            _broken.append(f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}")
            warnings.warn(
                f"lobelight: kernel fusion (torch.compile) failed, shading runs eager: "
                f"{_broken[0]}",
                RuntimeWarning,
                stacklevel=2,
            )
            return fn(*args, **kwargs)

    call.eager = fn  # type: ignore[attr-defined]
    return call  # type: ignore[return-value]
