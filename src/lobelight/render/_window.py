"""``lobelight view``: an interactive window (glfw + moderngl) around the GL renderer.

The window opens with the model's camera (:func:`model_camera`: the scene's, else the framing
``lobelight render`` gives a bare mesh) and the exposure :func:`auto_exposure` picks for the
first frame under the display curve. Left-drag orbits the camera about its target (around its
up), right-drag turns the lighting, the wheel zooms; ``d``/``g``/``b`` show the diffuse part,
the glossy part or both; ``+``/``-`` change the exposure, ``t`` cycles the display curve
(neutral, srgb, aces), ``a`` switches anti-aliasing between the renderer's samples per pixel and
one, ``e`` lights the model by the next of the maps given (:meth:`Renderer.set_environment`),
``Esc`` quits. The title shows the frame rate, the exposure, the curve, the samples per pixel
and the map.
"""

from __future__ import annotations

import math
import os
import time

import numpy as np

from ..errors import InputError
from ..geometry.camera import Camera
from ..model import Model, load
from ..scene import default_camera
from ._lighting import as_rotation
from ._renderer import Renderer, sample_offsets
from ._tonemap import CURVES, DEFAULT_CURVE, auto_exposure

__all__ = ["Orbit", "model_camera", "view"]

_OFFSCREEN = "render offscreen instead: lobelight render MODEL -o image.png"


def require_display():
    """glfw, or one clear error when no window can be opened here (checked before a model is
    loaded)."""
    try:
        import glfw  # optional (the gl extra)
    except ImportError:
        raise InputError(
            "view", f"needs glfw (pip install 'lobelight[gl]'); {_OFFSCREEN}"
        ) from None
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise InputError(
            "view", f"no display to open a window on (DISPLAY is not set); {_OFFSCREEN}"
        )
    return glfw


def _open_window(width: int, height: int, title: str):
    glfw = require_display()
    if not glfw.init():
        raise InputError("view", f"cannot initialise the window system; {_OFFSCREEN}")
    glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, 3)
    glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, 3)
    glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
    glfw.window_hint(glfw.RESIZABLE, False)
    win = glfw.create_window(width, height, title, None, None)
    if not win:
        glfw.terminate()
        raise InputError("view", f"cannot open an OpenGL 3.3 window; {_OFFSCREEN}")
    glfw.make_context_current(win)
    glfw.swap_interval(0)
    return glfw, win


def stored_camera(provenance: dict | None) -> Camera | None:
    """The camera a model was baked with (its provenance's ``camera``: a scene file's
    ``[camera]``, or the bare mesh's framing), None where it records none; raises
    InputError, TypeError or ValueError where what it records is no camera."""
    cam = (provenance or {}).get("camera")
    if not isinstance(cam, dict):
        return None
    return Camera(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in cam.items()})


def model_camera(model: Model) -> Camera:
    """The camera ``model`` is shown from by default: :func:`stored_camera`, else (none, or
    none that is a camera) :func:`lobelight.scene.default_camera` of its mesh, as ``lobelight
    render`` does."""
    try:
        cam = stored_camera(model.provenance)
    except (TypeError, ValueError, InputError):
        cam = None
    return default_camera(model.mesh) if cam is None else cam


class Orbit:
    """A camera on an orbit about its target: ``yaw`` (radians, about the camera's up),
    ``pitch`` (radians, above the plane normal to up) and ``dist``; :meth:`from_camera` starts
    it at a camera, which :meth:`camera` then gives back (yaw 0, the camera's own pitch)."""

    def __init__(self, target, up, forward, *, dist: float, pitch: float, fov, fov_axis):
        self.target = np.asarray(target, dtype=np.float64)  # (3,)
        self.up = np.asarray(up, dtype=np.float64)  # (3,) unit
        self.forward = np.asarray(forward, dtype=np.float64)  # (3,) unit, normal to up
        self.side = np.cross(self.up, self.forward)  # (3,) completes the frame
        self.yaw, self.pitch, self.dist = 0.0, float(pitch), float(dist)
        self.fov, self.fov_axis = float(fov), fov_axis

    @classmethod
    def from_camera(cls, cam: Camera) -> Orbit:
        """The orbit through ``cam``'s origin about its target, around its up."""
        offset = np.subtract(cam.origin, cam.target)  # (3,) target to eye
        up = np.asarray(cam.up, dtype=np.float64)
        up = up / np.linalg.norm(up)
        flat = offset - np.dot(offset, up) * up  # (3,) the offset normal to up
        if np.linalg.norm(flat) < 1e-9 * np.linalg.norm(offset):  # looking along up
            flat = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 0.0, 1.0])
        forward = flat / np.linalg.norm(flat)
        dist = float(np.linalg.norm(offset))
        pitch = math.asin(max(-1.0, min(1.0, float(np.dot(offset, up)) / dist)))
        return cls(
            cam.target, up, forward, dist=dist, pitch=pitch, fov=cam.fov, fov_axis=cam.fov_axis
        )

    def camera(self) -> Camera:
        """The camera at the orbit's yaw, pitch and distance, looking at the target."""
        cp, sp = math.cos(self.pitch), math.sin(self.pitch)
        cy, sy = math.cos(self.yaw), math.sin(self.yaw)
        eye = self.target + self.dist * (cp * (cy * self.forward + sy * self.side) + sp * self.up)
        return Camera.look_at(
            tuple(eye), tuple(self.target), tuple(self.up), fov=self.fov, fov_axis=self.fov_axis
        )


class _Controls:
    """What the mouse and the keys set (see the module): the camera's orbit about the model,
    the lighting's turn, the exposure, the parts shown, the curve, the samples per pixel and
    the map; the window's input callbacks are its methods."""

    def __init__(self, glfw, win, ren: Renderer, maps: list, orbit: Orbit, **display):
        self.glfw, self.win, self.ren, self.maps = glfw, win, ren, maps
        self.orbit = orbit
        self.light = 0.0
        self.exposure, self.curve = float(display["exposure"]), display["curve"]
        self.parts = (True, True)
        self.samples = ren.samples
        self.map = 0
        self.drag = None
        self.last = (0.0, 0.0)
        glfw.set_mouse_button_callback(win, self.on_button)
        glfw.set_cursor_pos_callback(win, self.on_move)
        glfw.set_scroll_callback(win, self.on_scroll)
        glfw.set_key_callback(win, self.on_key)

    def on_button(self, _w, button, action, _mods) -> None:
        self.drag = button if action == self.glfw.PRESS else None
        self.last = self.glfw.get_cursor_pos(self.win)

    def on_move(self, _w, x, y) -> None:
        if self.drag is None:
            return
        dx, dy = x - self.last[0], y - self.last[1]
        self.last = (x, y)
        if self.drag == self.glfw.MOUSE_BUTTON_LEFT:
            self.orbit.yaw -= dx * 0.01
            self.orbit.pitch = min(1.5, max(-1.5, self.orbit.pitch + dy * 0.01))
        else:
            self.light += dx * 0.5

    def on_scroll(self, _w, _dx, dy) -> None:
        self.orbit.dist *= 0.9**dy

    def on_key(self, _w, key, _sc, action, _mods) -> None:
        glfw, ren = self.glfw, self.ren
        if action != glfw.PRESS:
            return
        if key == glfw.KEY_ESCAPE:
            glfw.set_window_should_close(self.win, True)
        elif key == glfw.KEY_D:
            self.parts = (True, False)
        elif key == glfw.KEY_G:
            self.parts = (False, True)
        elif key == glfw.KEY_B:
            self.parts = (True, True)
        elif key in (glfw.KEY_EQUAL, glfw.KEY_KP_ADD):
            self.exposure += 0.5
        elif key in (glfw.KEY_MINUS, glfw.KEY_KP_SUBTRACT):
            self.exposure -= 0.5
        elif key == glfw.KEY_T:
            self.curve = CURVES[(CURVES.index(self.curve) + 1) % len(CURVES)]
        elif key == glfw.KEY_A:
            self.samples = 1 if self.samples > 1 else ren.samples
            ren.gl.set_offsets(sample_offsets(self.samples))
        elif key == glfw.KEY_E and len(self.maps) > 1:
            self.map = (self.map + 1) % len(self.maps)
            ren.set_environment(self.maps[self.map])
            ren.gl.set_offsets(sample_offsets(self.samples))  # a remade renderer's

    def title(self, fps: float) -> str:
        return (
            f"lobelight  {fps:.1f} fps  exposure {self.exposure:+.1f}  {self.curve}  "
            f"{self.samples} sample(s)/pixel  {os.path.basename(self.maps[self.map].name)}"
        )


def _run(glfw, win, ctx, ren: Renderer, controls: _Controls) -> int:
    """Draw frames until the window is closed, the frame rate in the title every half
    second; returns the frames drawn."""
    frames, tick, shown = 0, time.perf_counter(), 0
    while not glfw.window_should_close(win):
        d, g = controls.parts
        ren.gl.draw(controls.orbit.camera(), as_rotation(controls.light), diffuse=d, glossy=g)
        ren.gl.present(ctx.screen, exposure=controls.exposure, curve=controls.curve)
        glfw.swap_buffers(win)
        glfw.poll_events()
        frames += 1
        now = time.perf_counter()
        if now - tick > 0.5:
            glfw.set_window_title(win, controls.title((frames - shown) / (now - tick)))
            tick, shown = now, frames
    return frames


def view(
    model_path,
    *,
    env,
    width: int = 1024,
    height: int = 768,
    sun: bool = True,
    samples: int = 4,
    camera: Camera | None = None,
    exposure: float | None = None,
    curve: str = DEFAULT_CURVE,
) -> dict:
    """Open the window and run until it is closed; returns frames drawn and the mean fps.

    ``model_path``: a model file, or a loaded :class:`~lobelight.model.Model`; ``env``: an
    EnvMap, or a list of them that the ``e`` key cycles through; ``samples``: samples per pixel
    while anti-aliasing is on (the ``a`` key); ``camera``: the first view (None:
    :func:`model_camera`); ``exposure``: stops (None: :func:`auto_exposure` of the first
    frame's object pixels under ``curve``); ``curve``: the display curve at the start."""
    maps = list(env) if isinstance(env, (list, tuple)) else [env]
    if not maps:
        raise InputError("env", "needs at least one environment map")
    if curve not in CURVES:
        raise InputError("curve", f"must be one of {CURVES}, got {curve!r}")
    glfw, win = _open_window(width, height, "lobelight")
    import moderngl  # optional (the gl extra)

    try:
        model = model_path if isinstance(model_path, Model) else load(model_path)
        ctx = moderngl.create_context()
        fb_w, fb_h = glfw.get_framebuffer_size(win)
        ren = Renderer(model, maps[0], fb_w, fb_h, backend="gl", ctx=ctx, sun=sun, samples=samples)
        # the window shows 8-bit tone-mapped frames: half-float radiance loses nothing there
        ren.gl.set_hdr_dtype("f2")
        cam = camera if camera is not None else model_camera(model)
        if exposure is None:
            img, mask = ren.render(cam, return_mask=True)
            exposure = auto_exposure(img, mask if bool(mask.any()) else None, curve=curve)
        orbit = Orbit.from_camera(cam)
        controls = _Controls(glfw, win, ren, maps, orbit, exposure=exposure, curve=curve)
        t0 = time.perf_counter()
        frames = _run(glfw, win, ctx, ren, controls)
        ren.close()
        return {
            "command": "view",
            "frames": frames,
            "fps_mean": frames / max(time.perf_counter() - t0, 1e-9),
        }
    finally:
        glfw.terminate()
