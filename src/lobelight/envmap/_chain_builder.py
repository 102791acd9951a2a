"""Prefiltering one environment after another: a dynamic environment, a new chain each frame.

:func:`lobelight.envmap.prefilter` suits a map that stays: it caches the chain on disk and
returns a new :class:`Prefiltered` each time. A :class:`ChainBuilder` suits lighting that
changes every frame (a captured or simulated sky): it keeps one chain at fixed settings and
rebuilds it from each map it is given, with no cache.

On CUDA the build is a CUDA graph. The first call builds the chain twice eagerly on a side
stream (which makes the index plans of :mod:`._convolve` and the libraries' workspaces) and then
captures a third build; every later call is one device-to-device copy of the map into the
graph's input and one graph launch. The build reads no values back to the host and makes no
tensor from host data (:func:`._prefilter._build`), which is what lets a graph capture it; the
hundreds of kernels of a chain then cost no launch overhead on the host. Elsewhere each call
runs the same build eagerly.
"""

from __future__ import annotations

import torch

from .._backend import as_tensor
from ..errors import InputError
from ._prefilter import Prefiltered, _build, _check_source_cube, _lambdas, base_cube, check_settings

__all__ = ["ChainBuilder"]

#: Eager builds on the side stream before the capture: the first makes the plans, the second
#: runs with every plan in memory, as the capture will.
_WARMUP_BUILDS = 2


class ChainBuilder:
    """Builds the Gaussian-prefiltered chain of one environment after another.

    ``builder(env)`` gives the levels ``prefilter(env, cache=False)`` gives, at the settings
    fixed here, and returns the builder's one :class:`Prefiltered`, whose levels the next call
    overwrites (clone them to keep a chain).

    Parameters
    ----------
    base_res, phases, blend : as for :func:`lobelight.envmap.prefilter`.
    device : where the chain is built and kept (default: the CPU).
    graph : capture the build as a CUDA graph; None (the default) does on a CUDA device. True on
        another device is refused.
    check_finite : refuse a map with NaN or Inf values (one read back to the host per call;
        False skips it, and such a map then gives NaN levels).
    """

    def __init__(
        self,
        *,
        base_res: int = 512,
        phases: int = 4,
        blend: str = "l2",
        device=None,
        graph: bool | None = None,
        check_finite: bool = True,
    ) -> None:
        check_settings(base_res, phases, blend)
        try:
            self.device = torch.device("cpu" if device is None else device)
        except (RuntimeError, TypeError) as exc:
            raise InputError("device", f"is not a torch device: {device!r}") from exc
        if self.device.type == "cuda" and self.device.index is None and torch.cuda.is_available():
            # the device the tensors it makes report (a bare "cuda" is the current one)
            self.device = torch.device("cuda", torch.cuda.current_device())
        if graph is None:
            graph = self.device.type == "cuda"
        if graph and self.device.type != "cuda":
            raise InputError("graph", f"CUDA graphs need a CUDA device, got {self.device}")
        self.base_res, self.phases, self.blend = base_res, phases, blend
        self.graph, self.check_finite = graph, check_finite
        self._lambdas = _lambdas(base_res, phases).to(self.device)
        self._input: torch.Tensor | None = None  # the graph's input, (6, R, R, 3)
        self._cuda_graph = None
        self._chain: Prefiltered | None = None

    def __call__(self, env) -> Prefiltered:
        """Rebuild the chain from ``env`` and return it.

        Parameters
        ----------
        env : EnvMap, or a (6, R, R, 3) cube map with ``R >= base_res`` (tensor or array; a finer
            one is box-downsampled), on any device.
        """
        cube = self._base(env)
        name = getattr(env, "name", "envmap")
        if not self.graph:
            levels, padded = _build(cube, self.base_res, self.phases)
            return self._chain_of(levels, padded, name)
        with torch.cuda.device(self.device):  # the graph's streams are the current device's
            if self._cuda_graph is None:
                self._capture(cube)
            else:
                self._input.copy_(cube)
                self._cuda_graph.replay()
        self._chain.name = name
        return self._chain

    def _base(self, env) -> torch.Tensor:
        """The map as a ``(6, base_res, base_res, 3)`` float32 cube on the builder's device."""
        if hasattr(env, "to_cubemap"):
            env = env.to(self.device)
        else:
            env = as_tensor(env, device=self.device, dtype=torch.float32)
            _check_source_cube(env, self.base_res)
        return base_cube(env, self.base_res, check_finite=self.check_finite)

    def _chain_of(self, levels, padded, name: str) -> Prefiltered:
        """The builder's chain holding these levels (made on the first call)."""
        if self._chain is None:
            self._chain = Prefiltered(
                levels=levels,
                lambdas=self._lambdas,
                phases=self.phases,
                blend=self.blend,
                name=name,
                _padded=padded,
            )
        else:
            self._chain.levels, self._chain._padded = levels, padded
            self._chain.name = name
        return self._chain

    def _capture(self, cube: torch.Tensor) -> None:
        """Warm up on a side stream, then capture the build with ``cube`` as its input."""
        self._input = cube.clone()
        side = torch.cuda.Stream(self.device)
        side.wait_stream(torch.cuda.current_stream(self.device))
        with torch.cuda.stream(side):
            for _ in range(_WARMUP_BUILDS):
                _build(self._input, self.base_res, self.phases)
        torch.cuda.current_stream(self.device).wait_stream(side)
        graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(graph):
            levels, padded = _build(self._input, self.base_res, self.phases)
        graph.replay()  # capturing records the kernels without running them
        self._cuda_graph = graph
        self._chain_of(levels, padded, "envmap")
