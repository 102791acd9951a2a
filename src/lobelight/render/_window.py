"""``lobelight view``: an interactive window (glfw + moderngl) around the GL renderer.

Left-drag orbits the camera, right-drag turns the lighting, the wheel zooms; ``d``/``g``/``b``
show the diffuse part, the glossy part or both; ``+``/``-`` change the exposure, ``t`` toggles
the ACES curve, ``a`` switches anti-aliasing between the renderer's samples per pixel and one,
``e`` lights the model by the next of the maps given (:meth:`Renderer.set_environment`), ``Esc``
quits. The title shows the frame rate, the samples per pixel and the map.
"""

from __future__ import annotations

import math
import os
import time

import numpy as np

from ..errors import InputError
from ..geometry.camera import Camera
from ..model import Model, load
from ._lighting import as_rotation
from ._renderer import Renderer, sample_offsets

__all__ = ["view"]

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


class _Controls:
    """What the mouse and the keys set (see the module): the camera's orbit about the model,
    the lighting's turn, the exposure, the parts shown, the curve, the samples per pixel and
    the map; the window's input callbacks are its methods."""

    def __init__(self, glfw, win, ren: Renderer, maps: list, radius: float):
        self.glfw, self.win, self.ren, self.maps = glfw, win, ren, maps
        self.yaw, self.pitch = 0.0, 0.3
        self.dist = radius / math.sin(math.radians(20)) * 1.1
        self.light = 0.0
        self.exposure = 0.0
        self.parts = (True, True)
        self.aces = False
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
            self.yaw -= dx * 0.01
            self.pitch = min(1.5, max(-1.5, self.pitch + dy * 0.01))
        else:
            self.light += dx * 0.5

    def on_scroll(self, _w, _dx, dy) -> None:
        self.dist *= 0.9**dy

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
            self.aces = not self.aces
        elif key == glfw.KEY_A:
            self.samples = 1 if self.samples > 1 else ren.samples
            ren.gl.set_offsets(sample_offsets(self.samples))
        elif key == glfw.KEY_E and len(self.maps) > 1:
            self.map = (self.map + 1) % len(self.maps)
            ren.set_environment(self.maps[self.map])
            ren.gl.set_offsets(sample_offsets(self.samples))  # a remade renderer's

    def camera(self, centre: list[float]) -> Camera:
        """The camera on its orbit about ``centre``."""
        cp, sp = math.cos(self.pitch), math.sin(self.pitch)
        eye = np.array(centre) + self.dist * np.array(
            [cp * math.sin(self.yaw), sp, cp * math.cos(self.yaw)]
        )
        return Camera.look_at(tuple(eye), tuple(centre), fov=40.0)

    def title(self, fps: float) -> str:
        return (
            f"lobelight  {fps:.1f} fps  exposure {self.exposure:+.1f}  "
            f"{self.samples} sample(s)/pixel  {os.path.basename(self.maps[self.map].name)}"
        )


def _run(glfw, win, ctx, ren: Renderer, controls: _Controls, centre: list[float]) -> int:
    """Draw frames until the window is closed, the frame rate in the title every half
    second; returns the frames drawn."""
    frames, tick, shown = 0, time.perf_counter(), 0
    while not glfw.window_should_close(win):
        d, g = controls.parts
        ren.gl.draw(controls.camera(centre), as_rotation(controls.light), diffuse=d, glossy=g)
        ren.gl.present(
            ctx.screen, exposure=controls.exposure, curve="aces" if controls.aces else "srgb"
        )
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
) -> dict:
    """Open the window and run until it is closed; returns frames drawn and the mean fps.

    ``model_path``: a model file, or a loaded :class:`~lobelight.model.Model`; ``env``: an
    EnvMap, or a list of them that the ``e`` key cycles through; ``samples``: samples per pixel
    while anti-aliasing is on (the ``a`` key)."""
    maps = list(env) if isinstance(env, (list, tuple)) else [env]
    if not maps:
        raise InputError("env", "needs at least one environment map")
    glfw, win = _open_window(width, height, "lobelight")
    import moderngl  # optional (the gl extra)

    try:
        model = model_path if isinstance(model_path, Model) else load(model_path)
        ctx = moderngl.create_context()
        fb_w, fb_h = glfw.get_framebuffer_size(win)
        ren = Renderer(model, maps[0], fb_w, fb_h, backend="gl", ctx=ctx, sun=sun, samples=samples)
        # the window shows 8-bit tone-mapped frames: half-float radiance loses nothing there
        ren.gl.set_hdr_dtype("f2")
        verts = model.mesh.vertices
        centre = ((verts.amin(0) + verts.amax(0)) / 2).tolist()
        radius = float((verts - verts.mean(0)).norm(dim=-1).max())
        controls = _Controls(glfw, win, ren, maps, radius)
        t0 = time.perf_counter()
        frames = _run(glfw, win, ctx, ren, controls, centre)
        ren.close()
        return {
            "command": "view",
            "frames": frames,
            "fps_mean": frames / max(time.perf_counter() - t0, 1e-9),
        }
    finally:
        glfw.terminate()
