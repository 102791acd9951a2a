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
        ren._gl.set_hdr_dtype("f2")
        verts = model.mesh.vertices
        centre = ((verts.amin(0) + verts.amax(0)) / 2).tolist()
        radius = float((verts - verts.mean(0)).norm(dim=-1).max())
        st = {
            "yaw": 0.0,
            "pitch": 0.3,
            "dist": radius / math.sin(math.radians(20)) * 1.1,
            "light": 0.0,
            "exposure": 0.0,
            "parts": (True, True),
            "aces": False,
            "samples": ren.samples,
            "map": 0,
            "drag": None,
            "last": (0.0, 0.0),
        }

        def on_button(_w, button, action, _mods):
            st["drag"] = button if action == glfw.PRESS else None
            st["last"] = glfw.get_cursor_pos(win)

        def on_move(_w, x, y):
            if st["drag"] is None:
                return
            dx, dy = x - st["last"][0], y - st["last"][1]
            st["last"] = (x, y)
            if st["drag"] == glfw.MOUSE_BUTTON_LEFT:
                st["yaw"] -= dx * 0.01
                st["pitch"] = min(1.5, max(-1.5, st["pitch"] + dy * 0.01))
            else:
                st["light"] += dx * 0.5

        def on_scroll(_w, _dx, dy):
            st["dist"] *= 0.9**dy

        def on_key(_w, key, _sc, action, _mods):
            if action != glfw.PRESS:
                return
            if key == glfw.KEY_ESCAPE:
                glfw.set_window_should_close(win, True)
            elif key == glfw.KEY_D:
                st["parts"] = (True, False)
            elif key == glfw.KEY_G:
                st["parts"] = (False, True)
            elif key == glfw.KEY_B:
                st["parts"] = (True, True)
            elif key in (glfw.KEY_EQUAL, glfw.KEY_KP_ADD):
                st["exposure"] += 0.5
            elif key in (glfw.KEY_MINUS, glfw.KEY_KP_SUBTRACT):
                st["exposure"] -= 0.5
            elif key == glfw.KEY_T:
                st["aces"] = not st["aces"]
            elif key == glfw.KEY_A:
                st["samples"] = 1 if st["samples"] > 1 else ren.samples
                ren._gl.set_offsets(sample_offsets(st["samples"]))
            elif key == glfw.KEY_E and len(maps) > 1:
                st["map"] = (st["map"] + 1) % len(maps)
                ren.set_environment(maps[st["map"]])
                ren._gl.set_offsets(sample_offsets(st["samples"]))  # a remade renderer's

        glfw.set_mouse_button_callback(win, on_button)
        glfw.set_cursor_pos_callback(win, on_move)
        glfw.set_scroll_callback(win, on_scroll)
        glfw.set_key_callback(win, on_key)
        frames, t0, tick, shown = 0, time.perf_counter(), time.perf_counter(), 0
        while not glfw.window_should_close(win):
            cp, sp = math.cos(st["pitch"]), math.sin(st["pitch"])
            eye = np.array(centre) + st["dist"] * np.array(
                [cp * math.sin(st["yaw"]), sp, cp * math.cos(st["yaw"])]
            )
            cam = Camera.look_at(tuple(eye), tuple(centre), fov=40.0)
            d, g = st["parts"]
            ren._gl.draw(cam, as_rotation(st["light"]), diffuse=d, glossy=g)
            ren._gl.present(
                ctx.screen, exposure=st["exposure"], curve="aces" if st["aces"] else "srgb"
            )
            glfw.swap_buffers(win)
            glfw.poll_events()
            frames += 1
            now = time.perf_counter()
            if now - tick > 0.5:
                fps = (frames - shown) / (now - tick)
                glfw.set_window_title(
                    win,
                    f"lobelight  {fps:.1f} fps  exposure {st['exposure']:+.1f}  "
                    f"{st['samples']} sample(s)/pixel  {os.path.basename(maps[st['map']].name)}",
                )
                tick, shown = now, frames
        ren.close()
        return {
            "command": "view",
            "frames": frames,
            "fps_mean": frames / max(time.perf_counter() - t0, 1e-9),
        }
    finally:
        glfw.terminate()
