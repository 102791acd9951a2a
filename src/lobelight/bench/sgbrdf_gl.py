"""Benchmark: the SG-BRDF method against 40-sample filtered importance sampling, both in GLSL.

:func:`time_frames` times one renderer; :func:`bench_sgbrdf_gl` times the two methods on the
unit sphere in one OpenGL context.
"""

from __future__ import annotations

import math
import time
from typing import Any

from ..brdf import BRDF
from ..errors import InputError
from ..geometry.camera import Camera
from ..render import GLSGBRDFRenderer, create_context
from ..sgbrdf import FIS_SAMPLES, SGBRDF
from ._machine import machine

__all__ = ["bench_sgbrdf_gl", "time_frames"]


def time_frames(renderer: GLSGBRDFRenderer, min_seconds: float = 1.0, camera=None) -> dict:
    """Frames per second of one renderer: frames drawn back to back with a single
    ``ctx.finish()`` at the end (so the GPU, or llvmpipe's threads, never idle between frames),
    their count raised until one such run lasts at least ``min_seconds``.

    Returns
    -------
    dict with ``fps``, ``ms_per_frame``, ``frames`` and ``seconds`` of the final run
    """
    if not min_seconds > 0:
        raise InputError("min_seconds", f"must be positive, got {min_seconds!r}")
    ctx = renderer.ctx
    renderer.draw(camera)  # warm-up: compiles the program, uploads, first frame
    ctx.finish()
    frames = 1
    while True:
        t0 = time.perf_counter()
        for _ in range(frames):  # a loop over frames, each one draw call
            renderer.draw(camera)
        ctx.finish()
        secs = time.perf_counter() - t0
        if secs >= min_seconds:
            return {
                "fps": frames / secs,
                "ms_per_frame": 1e3 * secs / frames,
                "frames": frames,
                "seconds": secs,
            }
        # aim 20 % past the goal from this run's rate
        frames = max(frames + 1, math.ceil(1.2 * min_seconds * frames / max(secs, 1e-6)))


def bench_sgbrdf_gl(
    model: SGBRDF,
    lighting: Any,
    /,
    *,
    brdf: BRDF | None = None,
    chain: Any = None,
    size: int = 256,
    min_seconds: float = 1.0,
    rounds: int = 2,
    camera: Camera | None = None,
    ctx=None,
) -> dict:
    """Frames per second of our method against 40-sample FIS, both in GLSL, at one size.

    The unit sphere (orthographic, filling the ``size x size`` image as in
    :func:`lobelight.studies.compare_brdf.compare_brdf`, or seen by ``camera``) is drawn by a
    :class:`GLSGBRDFRenderer` of each method in one context. Each round times each method once
    (:func:`time_frames`: back-to-back frames, one ``ctx.finish()``, at least ``min_seconds``),
    alternating, so a change of load on a shared machine hits both alike; each method's best
    round is reported.

    Parameters
    ----------
    model : fitted material;  lighting : as :class:`GLSGBRDFRenderer` (a Lighting or an EnvMap
        serves both methods; a Prefiltered needs ``chain`` for FIS)
    brdf : FIS's material (default ``model.material``);  chain : FIS's base cube map (a
        ``(6, R, R, 3)`` array or a :class:`lobelight.sgbrdf.MipChain`, see
        :class:`GLSGBRDFRenderer`)

    Returns
    -------
    dict with ``benchmark`` ("sgbrdf_gl"), ``size``, ``pixels`` (sphere pixels), ``fps``
    (``{"ours", "fis40"}``), ``ms_per_frame``, ``frames``, ``speedup`` (ours / fis fps),
    ``ours_faster_than_fis``, ``lobes``, ``layout``, ``fis_samples``, ``renderer`` (the GL
    renderer string: "llvmpipe ..." means the CPU rasteriser) and ``machine``
    """

    if not isinstance(size, int) or isinstance(size, bool) or size < 1:
        raise InputError("size", f"must be a positive integer, got {size!r}")
    if not isinstance(rounds, int) or isinstance(rounds, bool) or rounds < 1:
        raise InputError("rounds", f"must be a positive integer, got {rounds!r}")
    own = ctx is None
    ctx = ctx if ctx is not None else create_context()
    rs: dict[str, GLSGBRDFRenderer] = {}
    try:
        rs["ours"] = GLSGBRDFRenderer(model, lighting, size, size, ctx=ctx, method="ours")
        rs["fis40"] = GLSGBRDFRenderer(
            model, lighting, size, size, ctx=ctx, method="fis", brdf=brdf, chain=chain
        )
        _, mask = rs["ours"].render(camera)
        best: dict[str, dict] = {}
        for _ in range(rounds):
            for name, r in rs.items():
                t = time_frames(r, min_seconds, camera)
                if name not in best or t["fps"] > best[name]["fps"]:
                    best[name] = t
        info = dict(ctx.info)
    finally:
        for r in rs.values():
            r.release()
        if own:
            ctx.release()
    fps = {k: v["fps"] for k, v in best.items()}
    return {
        "benchmark": "sgbrdf_gl",
        "size": size,
        "pixels": int(mask.sum()),
        "fps": fps,
        "ms_per_frame": {k: v["ms_per_frame"] for k, v in best.items()},
        "frames": {k: v["frames"] for k, v in best.items()},
        "speedup": fps["ours"] / fps["fis40"],
        "ours_faster_than_fis": bool(fps["ours"] > fps["fis40"]),
        "lobes": model.n_lobes,
        "layout": model.layout,
        "fis_samples": FIS_SAMPLES,
        "min_seconds": min_seconds,
        "rounds": rounds,
        "renderer": str(info.get("GL_RENDERER", "")),
        "machine": machine("cpu"),
    }
