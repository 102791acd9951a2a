"""Turntables: frames of a model seen by a camera orbiting it, or under a turning light."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from PIL import Image, features

from .._io import atomic_path
from ..errors import InputError
from ..geometry.camera import Camera
from ..progress import resolve
from ._lighting import as_rotation
from ._renderer import Renderer
from ._tonemap import (
    CURVES,
    DEFAULT_CURVE,
    auto_exposure,
    check_output_path,
    check_type,
    tonemap,
)

__all__ = ["ROTATIONS", "orbit", "turntable"]

ROTATIONS = ("camera", "light")
#: Animation types :func:`turntable` writes (Pillow's writers).
ANIMATION_TYPES = (".gif", ".webp")


def orbit(camera: Camera, degrees: float) -> Camera:
    """``camera`` turned by ``degrees`` about the axis through its target along its ``up``
    (right-handed: positive turns +x towards -z for ``up = +y``); target, up and field of view
    stay."""
    axis = np.asarray(camera.up, np.float64)
    axis = axis / np.linalg.norm(axis)
    t = np.asarray(camera.target, np.float64)
    v = np.asarray(camera.origin, np.float64) - t
    a = math.radians(float(degrees))
    # Rodrigues' rotation of the target-to-eye vector
    v = (
        v * math.cos(a)
        + np.cross(axis, v) * math.sin(a)
        + axis * float(axis @ v) * (1.0 - math.cos(a))
    )
    return Camera(
        origin=tuple(t + v), target=camera.target, up=camera.up, fov=camera.fov,
        fov_axis=camera.fov_axis,
    )  # fmt: skip


def turntable(
    renderer: Renderer,
    camera: Camera,
    n_frames: int,
    out_dir,
    *,
    exposure: float | None = None,
    curve: str = DEFAULT_CURVE,
    rotate: str = "camera",
    animation: str | None = "frames.gif",
    fps: float = 25.0,
    light_rotation=None,
    diffuse: bool = True,
    glossy: bool = True,
    background: bool = True,
    progress: bool | Callable[[str, int, int], None] | None = None,
) -> dict:
    """Render ``n_frames`` frames over one full turn and write them as ``frame_000.png``, ...
    in ``out_dir`` (made if missing), and an animation of them.

    Parameters
    ----------
    renderer : the Renderer (its size, backend and samples per pixel)
    camera : the first frame's camera
    n_frames : frames over 360 degrees (frame ``k`` at ``360 k / n_frames``)
    out_dir : folder of the frames
    exposure : stops, one for every frame (no flicker); None: :func:`auto_exposure` of the
        first frame's pixels entirely on the object (of the whole frame if there are none)
    curve : the display curve, ``"neutral"`` (Khronos PBR Neutral), ``"srgb"`` or ``"aces"``
        (:func:`tonemap`)
    rotate : ``"camera"`` orbits the camera about its target along its up (:func:`orbit`),
        the light fixed; ``"light"`` turns the environment about +y, the camera fixed
    animation : file name in ``out_dir`` (or a path) of the animation, ``.gif`` (256 colours
        per frame; Pillow merges identical consecutive frames into one longer one) or
        ``.webp`` (lossless); None writes frames only
    fps : frames per second of the animation (GIF stores delays in 10 ms steps)
    light_rotation : the lighting (None, a (3, 3) rotation or degrees about +y): fixed while
        the camera orbits, the first frame's when the light turns
    diffuse, glossy, background : the parts rendered (as :meth:`Renderer.render`)
    progress : ``progress("turntable", done, n_frames)`` after each frame (``True``: bars or
        lines on stderr, :mod:`lobelight.progress`); None is silent

    Every argument and the output paths are checked before the first frame is rendered.

    Returns
    -------
    dict with ``frames`` (paths), ``animation`` (path or None), ``n_frames``, ``rotate``,
    ``exposure``, ``curve``, ``size`` [W, H], ``samples``, ``seconds_render`` (the frames),
    ``seconds_write`` (the files) and ``seconds`` (all of it)
    """
    t0 = time.perf_counter()
    n = _check_arguments(renderer, camera, n_frames, rotate, curve, exposure, fps)
    base = as_rotation(light_rotation)
    paths, anim = _output_paths(Path(out_dir), n, animation)
    report = resolve(progress)

    t_render = t_write = 0.0
    for k, path in enumerate(paths):
        angle = 360.0 * k / n
        t = time.perf_counter()
        if rotate == "camera":
            cam, rot = orbit(camera, angle), base
        else:
            cam, rot = camera, as_rotation(angle) @ base
        img, mask = renderer.render(
            cam, rot, diffuse=diffuse, glossy=glossy, background=background, return_mask=True
        )
        if exposure is None:
            exposure = auto_exposure(img, mask if bool(mask.any()) else None, curve=curve)
        t_render += time.perf_counter() - t
        t = time.perf_counter()
        frame = Image.fromarray(tonemap(img, exposure=exposure, curve=curve))
        with atomic_path(path) as tmp:
            frame.save(tmp, format="PNG")
        t_write += time.perf_counter() - t
        if report is not None:
            report("turntable", k + 1, n)

    if anim is not None:
        t = time.perf_counter()
        with atomic_path(anim) as tmp:
            _write_animation(str(tmp), paths, anim.suffix, fps)
        t_write += time.perf_counter() - t
    return {
        "frames": [str(p) for p in paths],
        "animation": None if anim is None else str(anim),
        "n_frames": n,
        "rotate": rotate,
        "exposure": float(exposure),
        "curve": curve,
        "size": [renderer.width, renderer.height],
        "samples": renderer.samples,
        "seconds_render": t_render,
        "seconds_write": t_write,
        "seconds": time.perf_counter() - t0,
    }


def _check_arguments(renderer, camera, n_frames, rotate, curve, exposure, fps) -> int:
    """:func:`turntable`'s arguments checked (InputError naming the first bad one); returns
    the number of frames."""
    if not isinstance(renderer, Renderer):
        raise InputError("renderer", f"expected a Renderer, got {type(renderer).__name__}")
    if not isinstance(camera, Camera):
        raise InputError("camera", f"expected a Camera, got {type(camera).__name__}")
    if isinstance(n_frames, bool) or not isinstance(n_frames, (int, np.integer)) or n_frames < 1:
        raise InputError("n_frames", f"must be a positive integer, got {n_frames!r}")
    if rotate not in ROTATIONS:
        raise InputError("rotate", f"must be one of {ROTATIONS}, got {rotate!r}")
    if curve not in CURVES:
        raise InputError("curve", f"must be one of {CURVES}, got {curve!r}")
    if exposure is not None and not math.isfinite(float(exposure)):
        raise InputError("exposure", f"must be a finite number of stops, got {exposure!r}")
    if not (isinstance(fps, (int, float)) and math.isfinite(fps) and fps > 0):
        raise InputError("fps", f"must be a positive number, got {fps!r}")
    return int(n_frames)


def frame_names(n: int) -> list[str]:
    """The file names of a turntable's ``n`` frames, in order (``frame_000.png``, ...)."""
    digits = max(3, len(str(n - 1)))
    return [f"frame_{k:0{digits}d}.png" for k in range(n)]


def _output_paths(out: Path, n: int, animation) -> tuple[list[Path], Path | None]:
    """The ``n`` frames' paths in ``out`` (made if missing) and the animation's path (None
    for none), each checked as an output before any frame is rendered."""
    anim = None if animation is None else check_type(out / animation, ANIMATION_TYPES)
    if anim is not None and anim.suffix.lower() == ".webp" and not features.check("webp"):
        raise InputError(str(anim), "this Pillow has no WebP support: use .gif")
    if out.exists() and not out.is_dir():
        raise InputError(str(out), "is a file, not a folder for the frames")
    names = frame_names(n)
    if out.is_dir():  # frames these would not replace would pass for theirs
        stale = sorted(set(q.name for q in out.glob("frame_*.png")) - set(names))
        if stale:
            raise InputError(
                str(out),
                f"holds {len(stale)} frame(s) of another turntable that these {n} would not "
                f"replace ({stale[0]}, ...): empty it or name another folder",
            )
    out.mkdir(parents=True, exist_ok=True)
    paths = [check_output_path(out / name) for name in names]
    if anim is not None:
        check_output_path(anim, types=ANIMATION_TYPES)
    return paths, anim


def _write_animation(tmp: str, frames: list[Path], ext: str, fps: float) -> None:
    """The frames (read back one at a time: memory of one frame) as an endlessly looping
    animation."""
    first = Image.open(frames[0])
    rest = (Image.open(p) for p in frames[1:])
    kw = {"save_all": True, "append_images": rest, "duration": round(1000.0 / fps), "loop": 0}
    if ext.lower() == ".webp":
        first.save(tmp, format="WEBP", lossless=True, **kw)
    else:
        first.save(tmp, format="GIF", **kw)
