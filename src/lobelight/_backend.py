"""numpy/torch dispatch for array functions.

All math in lobelight is written once, in torch. Public array functions accept numpy arrays or
torch tensors; :func:`dispatch` converts numpy inputs to torch on the CPU and converts the results
back, so a numpy caller gets numpy out and a torch caller keeps its device and dtype.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np
import torch

__all__ = ["as_float", "as_tensor", "dispatch", "to_numpy"]

F = TypeVar("F", bound=Callable[..., Any])


def as_tensor(x: Any, *, dtype: torch.dtype | None = None, device: Any = None) -> torch.Tensor:
    """Return ``x`` as a torch tensor (no copy when it already is one of that dtype/device).

    Floating numpy arrays keep their precision (float64 stays float64); Python scalars and
    lists become float32 unless ``dtype`` says otherwise.
    """
    if isinstance(x, torch.Tensor):
        return x.to(dtype=dtype or x.dtype, device=device or x.device)
    if isinstance(x, np.ndarray):
        t = torch.from_numpy(np.ascontiguousarray(x).reshape(x.shape))
        return t.to(dtype=dtype or t.dtype, device=device or "cpu")
    return torch.as_tensor(x, dtype=dtype or torch.float32, device=device)


def as_float(x: Any, *, like: torch.Tensor | None = None) -> torch.Tensor:
    """A floating tensor: follows ``like`` (dtype, device) for scalars, float32 for integers."""
    if like is not None and not isinstance(x, torch.Tensor):
        return as_tensor(x, dtype=like.dtype, device=like.device)
    t = as_tensor(x)
    if like is not None:
        t = t.to(device=like.device)
    return t if t.is_floating_point() else t.to(torch.float32)


def to_numpy(x: Any) -> Any:
    """Convert tensors (also inside tuples, lists and dicts) to numpy arrays."""
    if isinstance(x, torch.Tensor):
        return x.detach().cpu().numpy()
    if isinstance(x, tuple):
        return tuple(to_numpy(v) for v in x)
    if isinstance(x, list):
        return [to_numpy(v) for v in x]
    if isinstance(x, dict):
        return {k: to_numpy(v) for k, v in x.items()}
    return x


def dispatch(fn: F) -> F:
    """Decorate a torch function so that numpy array arguments give numpy results.

    Positional and keyword arguments that are numpy arrays are converted with
    :func:`as_tensor`. If any argument was a numpy array (and none was a tensor), the result
    is converted back with :func:`to_numpy`.
    """

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        saw_numpy = False
        saw_torch = False

        def conv(v: Any) -> Any:
            nonlocal saw_numpy, saw_torch
            if isinstance(v, np.ndarray):
                saw_numpy = True
                return as_tensor(v)
            if isinstance(v, torch.Tensor):
                saw_torch = True
            return v

        args = tuple(conv(a) for a in args)
        kwargs = {k: conv(v) for k, v in kwargs.items()}
        out = fn(*args, **kwargs)
        return to_numpy(out) if saw_numpy and not saw_torch else out

    return wrapper  # type: ignore[return-value]
