"""The WebGL 2 viewer's frames per second in a headless browser (``lobelight bench web``).

Each case exports a synthetic model (:func:`lobelight.bench.synthetic_model`, a sphere of about
10K or 50K vertices, N Gaussians per view) under the built-in sky with its sun
(:func:`lobelight.web.export_web`), opens the page in the system's chromium (Playwright for
Python; ``--headless=new --use-angle=swiftshader``: WebGL 2 on SwiftShader, the CPU) at a fixed
canvas size, and times the page's own frames (its script's ``benchmark`` hook: draw, tone-map
into the canvas, read one pixel back, so each frame is finished before the next), at the
canvas's size and at half its pixels across (the page's least while the view changes), and
the milliseconds of each pass (the page's ``profile`` hook). The folder's size and the page's
load are recorded beside them (the interactive page opened anew, to its first frame on the
canvas, with the page's own steps: its ``timings``), and the time of a still frame (four
samples per pixel, drawn once the view rests), with the machine's load average: the machine
may be shared.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from pathlib import Path

from ..envmap import builtin
from ..errors import InputError
from ..render import Lighting
from ..web import export_web
from ._machine import machine
from .synthetic import synthetic_model

__all__ = ["bench_web"]

#: Chromium's flags for WebGL 2 on SwiftShader without a display.
CHROMIUM_FLAGS = (
    "--headless=new",
    "--no-sandbox",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
)


def _chromium() -> str:
    path = shutil.which("chromium") or shutil.which("chromium-browser")
    if path is None:
        raise InputError("bench web", "needs the system chromium (apt-get install chromium)")
    return path


def _open(browser, folder: Path, size: int, query: str):
    """The page at ``size`` squared (its URL's ``query`` appended) opened and loaded: the
    page, the clock's reading at its navigation, and the seconds to its ``ready``."""
    page = browser.new_page(viewport={"width": size + 40, "height": size + 40})
    t0 = time.perf_counter()
    page.goto(f"file://{folder}/index.html?size={size}x{size}{query}")
    page.wait_for_function("window.lobelight && window.lobelight.ready")
    page.evaluate("window.lobelight.ready")
    return page, t0, time.perf_counter() - t0


def _page_load(browser, folder: Path, size: int) -> dict:
    """Seconds from the navigation's start to each of the interactive page's load steps
    (its ``timings``: ``shown`` is its first frame on the canvas), and to the first frame as
    seen from outside the page."""
    page, t0, _ = _open(browser, folder, size, "")
    if not page.evaluate("window.lobelight.status")["ok"]:
        page.close()
        return {}
    page.wait_for_function("window.lobelight.timings.shown != null")
    wall = time.perf_counter() - t0
    steps = page.evaluate("window.lobelight.timings")
    page.close()
    return {"seconds": wall, "steps_seconds": {k: v / 1000 for k, v in steps.items()}}


def _page_fps(browser, folder: Path, size: int, frames: int, query: str = "") -> dict:
    """Load time and frames per second of the page at ``size`` squared."""
    page, _, load = _open(browser, folder, size, f"&still=1{query}")
    status = page.evaluate("window.lobelight.status")
    if not status["ok"]:
        page.close()
        return {"error": status["message"], "load_seconds": load}
    r = page.evaluate("n => window.lobelight.benchmark(n, 2)", frames)
    # the frames while the view changes at half the pixels across (the page's least)
    half = page.evaluate("n => window.lobelight.benchmark(n, 1, false, {}, 0.5)", frames)
    # milliseconds per pass, each finished before the next (their sum exceeds a frame's)
    passes = page.evaluate("n => window.lobelight.profile(n)", max(2, frames // 2))
    # a still frame: the desktop renderer's samples per pixel (4), drawn once the view rests
    still = page.evaluate("() => window.lobelight.benchmark(2, 0, true)")
    renderer = page.evaluate(
        "() => { const gl = window.lobelight.viewer.gl;"
        " const e = gl.getExtension('WEBGL_debug_renderer_info');"
        " return e ? gl.getParameter(e.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER); }"
    )
    page.close()
    return {
        "fps": r["fps"],
        "frames": r["frames"],
        "fps_half_res": half["fps"],
        "pass_ms": {k: round(v, 1) for k, v in passes.items()},
        "still_frame_seconds": 1.0 / still["fps"],
        "load_seconds": load,
        "renderer": renderer,
    }


def bench_web(
    *,
    vertices: tuple[int, ...] = (10_000, 50_000),
    gaussians: tuple[int, ...] = (1, 3),
    sizes: tuple[int, ...] = (512, 1024),
    frames: int = 10,
    sun: bool = True,
) -> dict:
    """Frames per second of the web viewer per (vertices, Gaussians, canvas size) (module
    docstring); ``sun``: the sky's sun shaded per pixel with its soft shadow (False: in the
    SH and the chain). Needs chromium and ``lobelight[web]`` (Playwright)."""
    try:
        from playwright.sync_api import sync_playwright  # optional (the web extra)
    except ImportError:
        raise InputError("bench web", "needs Playwright: pip install 'lobelight[web]'") from None
    exe = _chromium()
    lighting = Lighting(builtin(), sun=sun)
    load_before = os.getloadavg()
    cases = []
    tmp = Path(tempfile.mkdtemp(prefix="lobelight-bench-web-"))
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=exe, args=list(CHROMIUM_FLAGS))
            for v in vertices:
                for n in gaussians:
                    model = synthetic_model(v, n, vary=True)
                    folder = tmp / f"v{v}-n{n}"
                    info = export_web(model, folder, [lighting])
                    for size in sizes:
                        r = _page_fps(browser, folder, size, frames)
                        cases.append({
                            "vertices": model.mesh.n_vertices,
                            "gaussians": n,
                            "size": size,
                            "folder_bytes": info["bytes"],
                            **r,
                            "first_frame": _page_load(browser, folder, size),
                        })  # fmt: skip
            browser.close()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return {
        "benchmark": "web",
        "browser": f"{exe} {' '.join(CHROMIUM_FLAGS)}",
        "sun": sun,
        "cases": cases,
        "load_average_before": load_before,
        "load_average_after": os.getloadavg(),
        "machine": machine("cpu"),
    }
