"""The NVIDIA Warp engine of :mod:`lobelight.geometry.raycast`: a ``wp.Mesh`` BVH and two kernels.

The BVH is built on the mesh's device (CPU or CUDA) from float32 vertices and int32 faces; rays
go in and results come out as torch tensors shared with Warp (``wp.from_torch``, no copy), so on
a GPU the rays never leave it. Only the triangle index of a hit is read from Warp: distance and
barycentrics are recomputed in float64 by :mod:`~lobelight.geometry.raycast` for both engines.

Warp is an optional dependency (the ``gpu`` extra). Its kernels must be defined at module level
(Warp compiles them from their source); they are compiled on first launch and cached on disk by
Warp (``wp.config.kernel_cache_dir``), so only a machine's first run pays the compile.
"""

# no `from __future__ import annotations`: Warp releases before 1.5 read kernel annotations as
# objects, and string annotations make their code generator fail on the kernels below

import sys
from collections.abc import Callable

import torch

try:
    import warp as wp  # optional: the `gpu` extra (pip install warp-lang)
except ImportError:  # optional dependency missing: raycast then offers only Embree
    wp = None

__all__ = ["WarpRays", "available"]

#: Farthest hit a query looks for: any (Warp takes max_t as a float32).
_MAX_T = 3.0e38


def available() -> bool:
    """Whether Warp imported."""
    return wp is not None


def _has_builtin(name: str) -> bool:
    """Whether this Warp's kernel language has the built-in ``name`` (its registry moved from
    ``warp.context`` to ``warp._src.context``; both are loaded by ``import warp``)."""
    ctx = sys.modules.get("warp._src.context") or sys.modules.get("warp.context")
    return name in getattr(ctx, "builtin_functions", {})


if wp is not None:
    # forward launches only: no adjoint code to generate and compile
    wp.set_module_options({"enable_backward": False})

    #: Any-hit traversal stops at the first triangle found (Warp >= 1.9 or so); older Warps
    #: answer occlusion with the closest-hit query, which is right but slower.
    HAS_ANYHIT = _has_builtin("mesh_query_ray_anyhit")

    @wp.kernel
    def _first_face(
        mesh: wp.uint64,
        origins: wp.array(dtype=wp.vec3),
        dirs: wp.array(dtype=wp.vec3),
        max_t: float,
        face: wp.array(dtype=wp.int64),
    ):
        i = wp.tid()
        q = wp.mesh_query_ray(mesh, origins[i], dirs[i], max_t)
        if q.result:
            face[i] = wp.int64(q.face)
        else:
            face[i] = wp.int64(-1)

    if HAS_ANYHIT:

        @wp.kernel
        def _any_hit(
            mesh: wp.uint64,
            origins: wp.array(dtype=wp.vec3),
            dirs: wp.array(dtype=wp.vec3),
            max_t: float,
            hit: wp.array(dtype=wp.bool),
        ):
            i = wp.tid()
            hit[i] = wp.mesh_query_ray_anyhit(mesh, origins[i], dirs[i], max_t)

    else:

        @wp.kernel
        def _any_hit(
            mesh: wp.uint64,
            origins: wp.array(dtype=wp.vec3),
            dirs: wp.array(dtype=wp.vec3),
            max_t: float,
            hit: wp.array(dtype=wp.bool),
        ):
            i = wp.tid()
            hit[i] = wp.mesh_query_ray(mesh, origins[i], dirs[i], max_t).result


def _init() -> None:
    """``wp.init()``, quietly: Warp prints a banner and each module load's time to stdout, and a
    library writes nothing there. Only raises Warp's log threshold, never lowers it."""
    wp.config.quiet = True  # the switch of older Warps (unused, and harmless, in later ones)
    if hasattr(wp, "LOG_WARNING") and hasattr(wp.config, "log_level"):
        wp.config.log_level = max(wp.config.log_level, wp.LOG_WARNING)
    wp.init()


#: ``parts(fn, n)``: calls ``fn(a, b)`` on consecutive pieces ``[a, b)`` of ``range(n)``
#: (in threads where that pays) and waits for all of them.
Parts = Callable[[Callable[[int, int], None], int], None]


class WarpRays:
    """A Warp BVH of one mesh and its any-hit and closest-hit queries.

    Parameters
    ----------
    vertices : (V, 3) float positions, on the device the BVH is built on
    faces : (F, 3) integer vertex indices, same device
    """

    def __init__(self, vertices: torch.Tensor, faces: torch.Tensor):
        _init()
        self.device = vertices.device
        self._wp_device = wp.device_from_torch(self.device)
        # Warp reads these buffers for as long as the BVH lives: kept referenced here
        self._points = vertices.detach().to(torch.float32).contiguous()
        self._indices = faces.detach().to(self.device, torch.int32).reshape(-1).contiguous()
        with wp.ScopedStream(self._stream()):
            self._mesh = wp.Mesh(
                points=wp.from_torch(self._points, dtype=wp.vec3),
                indices=wp.from_torch(self._indices, dtype=wp.int32),
            )

    def _stream(self):
        """Torch's current stream on a GPU (Warp's work queued behind torch's, no sync); None
        on the CPU."""
        if self.device.type != "cuda":
            return None
        return wp.stream_from_torch(torch.cuda.current_stream(self.device))

    def occluded(self, o: torch.Tensor, d: torch.Tensor, parts: Parts | None = None):
        """Whether each ray hits any triangle, ``(R,)`` bool on the BVH's device.

        Parameters
        ----------
        o, d : (R, 3) origins and directions (any float dtype and device)
        parts : how to split the rays over CPU threads (None: one launch)
        """
        return self._launch(_any_hit, o, d, torch.bool, parts)

    def first_face(self, o: torch.Tensor, d: torch.Tensor, parts: Parts | None = None):
        """Index of the nearest triangle each ray hits, -1 on a miss: ``(R,)`` int64 on the
        BVH's device. Parameters as :meth:`occluded`."""
        return self._launch(_first_face, o, d, torch.int64, parts)

    def _launch(self, kernel, o, d, dtype, parts: Parts | None) -> torch.Tensor:
        o = o.detach().to(self.device, torch.float32).contiguous()
        d = d.detach().to(self.device, torch.float32).contiguous()
        out = torch.empty(o.shape[0], dtype=dtype, device=self.device)
        stream = self._stream()

        def run(a: int, b: int) -> None:
            if b > a:
                wp.launch(
                    kernel,
                    dim=b - a,
                    inputs=[
                        self._mesh.id,
                        wp.from_torch(o[a:b], dtype=wp.vec3),
                        wp.from_torch(d[a:b], dtype=wp.vec3),
                        _MAX_T,
                    ],
                    outputs=[wp.from_torch(out[a:b])],
                    device=self._wp_device,
                    stream=stream,
                )

        if parts is None or self.device.type != "cpu":
            run(0, o.shape[0])
        else:  # a CPU launch is one loop on one thread (it releases the GIL: threads add up)
            # compiled (or read from Warp's cache) and loaded here, not by the first of several
            # threads launching at once: Warp does not serialise a module's first load
            wp.load_module(sys.modules[__name__], device=self._wp_device)
            parts(run, o.shape[0])
        return out
