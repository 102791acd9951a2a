"""The display transform (Khronos PBR Neutral, ACES, clipped sRGB), its exposure, the shader's
copy of it, and the camera ``lobelight view`` opens with."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from lobelight import bench, envmap, render, scene
from lobelight.errors import InputError
from lobelight.render._gl import gl_available
from lobelight.render._tonemap import (
    CURVE_WHITE,
    CURVES,
    HIGHLIGHT_MAX_STOPS,
    auto_exposure,
    neutral,
    tonemap,
)
from lobelight.render._window import Orbit, model_camera

needs_gl = pytest.mark.skipif(not gl_available(), reason="no headless OpenGL context (EGL)")

RED_PLASTIC = np.array([0.6, 0.12, 0.08])
#: The curves through the GL path (``present`` passes a curve's index in ``CURVES``).
GL_CURVES = ["srgb", "aces", "neutral"]


def _neutral_spec(rgb) -> np.ndarray:
    """Khronos PBR Neutral for one colour, written from the specification's formulas
    (KhronosGroup/ToneMapping, PBR_Neutral/README.md) in float64 scalars."""
    f90, ks, kd = 0.04, 0.8 - 0.04, 0.15
    r, g, b = (float(v) for v in rgb)
    x = min(r, g, b)
    f = x - x * x / (4 * f90) if x <= 2 * f90 else f90
    c = np.array([r - f, g - f, b - f])
    p = max(c)
    if p <= ks:
        return c
    pn = 1 - (1 - ks) ** 2 / (p + 1 - 2 * ks)
    gg = 1 / (kd * (p - pn) + 1)
    return c * (pn / p) * gg + pn * (1 - gg)


def _oklab(rgb) -> np.ndarray:
    """``(..., 3)`` linear sRGB to OKLab (Ottosson 2020), float64."""
    m1 = np.array(
        [
            [0.4122214708, 0.5363325363, 0.0514459929],
            [0.2119034982, 0.6806995451, 0.1073969566],
            [0.0883024619, 0.2817188376, 0.6299787005],
        ]
    )
    m2 = np.array(
        [
            [0.2104542553, 0.7936177850, -0.0040720468],
            [1.9779984951, -2.4285922050, 0.4505937099],
            [0.0259040371, 0.7827717662, -0.8086757660],
        ]
    )
    return np.cbrt(np.asarray(rgb, dtype=np.float64) @ m1.T) @ m2.T


def _decode(u8) -> np.ndarray:
    """8-bit sRGB to linear, float64 (the sRGB standard's inverse transfer function)."""
    s = np.asarray(u8, dtype=np.float64) / 255
    return np.where(s <= 0.04045, s / 12.92, ((s + 0.055) / 1.055) ** 2.4)


def _hue_shift_deg(linear, u8) -> np.ndarray:
    """Per pixel, the OKLab hue angle of the displayed ``u8`` less that of ``linear``, in
    degrees, wrapped to [0, 180]."""
    a, b = _oklab(linear), _oklab(_decode(u8))
    d = np.arctan2(b[..., 2], b[..., 1]) - np.arctan2(a[..., 2], a[..., 1])
    return np.degrees(np.abs(np.angle(np.exp(1j * d))))


def _red_sphere(n: int = 48):
    """A Lambertian red-plastic ball (albedo :data:`RED_PLASTIC`) under a light of irradiance 3
    and an ambient 0.15, seen from the front: ``(n, n, 3)`` radiance, ``(n, n)`` mask."""
    y, x = np.mgrid[-1 : 1 : n * 1j, -1 : 1 : n * 1j]
    r2 = x * x + y * y
    mask = r2 < 1
    normal = np.stack([x, -y, np.sqrt(np.clip(1 - r2, 0, 1))], axis=-1)  # (n, n, 3)
    light = np.array([0.5, 0.6, 0.62]) / np.linalg.norm([0.5, 0.6, 0.62])
    shade = 3.0 * np.clip(normal @ light, 0, None) + 0.15  # (n, n)
    img = RED_PLASTIC * shade[..., None] * mask[..., None]
    return img.astype(np.float32), mask


def test_neutral_follows_the_khronos_specification():
    rng = np.random.default_rng(3)
    # colours across the toe (min < 0.08), below and above the shoulder, and far past it
    x = np.concatenate([rng.uniform(0, 0.1, (40, 3)), rng.uniform(0, 20, (200, 3))])
    x = np.concatenate([x, [[0, 0, 0], [1, 1, 1], [0.6, 0.12, 0.08], [0.08, 0.08, 0.9]]])
    want = np.stack([_neutral_spec(c) for c in x])
    got = neutral(x.astype(np.float32))
    # float32 against float64 scalars: a few ulps of values in [0, 1]
    np.testing.assert_allclose(got, want, atol=2e-6)
    np.testing.assert_allclose(neutral(torch.tensor(x)).numpy(), want, atol=1e-12)
    assert got.min() >= 0 and got.max() < 1
    # the tonemap applies it before the sRGB transfer function
    s = np.clip(want, 0, 1)
    s = np.where(s <= 0.0031308, 12.92 * s, 1.055 * s ** (1 / 2.4) - 0.055)
    u8 = tonemap(x[None].astype(np.float32), curve="neutral")[0]
    assert int(np.abs(u8.astype(int) - np.round(s * 255)).max()) <= 1


def test_each_curve_white_shows_grey_at_95_percent():
    # CURVE_WHITE is where a grey reaches 95 % of display white (before the sRGB encoding)
    w = CURVE_WHITE
    assert neutral(np.full(3, w["neutral"])) == pytest.approx(0.95, abs=1e-3)
    x = w["aces"]
    assert x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14) == pytest.approx(0.95, abs=1e-3)
    assert w["srgb"] == 0.95
    assert set(w) == set(CURVES)


def test_red_plastic_keeps_its_colour_under_the_default_display():
    img, mask = _red_sphere()
    exposure = auto_exposure(img, mask, curve="neutral")
    out = tonemap(img, exposure=exposure)  # the default curve
    assert (tonemap(img, exposure=exposure, curve="neutral") == out).all()
    # no channel of any object pixel clipped
    assert int(out[mask].max()) < 255
    # hue kept: the OKLab hue angle of the displayed pixels against the exposed linear ones.
    # Below the shoulder PBR Neutral only subtracts its toe offset (<= 0.04) from every channel,
    # above it it scales and mixes towards grey, which keep the hue in linear RGB; OKLab's hue
    # lines are not exactly those, so a few degrees remain. Bounds: 4 degrees mean, 8 the
    # worst; the per-channel ACES curve shifts the same ball by about 7 mean, 15 worst.
    shift = _hue_shift_deg(img[mask] * 2.0**exposure, out[mask])
    assert shift.mean() < 4.0 and shift.max() < 8.0
    aces = tonemap(img, exposure=exposure, curve="aces")
    assert _hue_shift_deg(img[mask] * 2.0**exposure, aces[mask]).mean() > 1.5 * shift.mean()
    # the old default (log-average to 0.18, clipped sRGB) blows the red channel on a third of
    # the ball: what made red plastic read salmon
    key = auto_exposure(img, mask)
    clipped = (tonemap(img, exposure=key, curve="srgb")[mask] == 255).any(axis=-1).mean()
    assert clipped > 0.3


def test_exposure_follows_the_highlights_within_a_stop():
    img, mask = _red_sphere()
    key = auto_exposure(img, mask)
    # log-average luminance to 0.18
    lum = (img[mask] @ np.array([0.2126, 0.7152, 0.0722])).astype(np.float64)
    assert key == pytest.approx(math.log2(0.18 / math.exp(np.log(np.maximum(lum, 1e-6)).mean())))
    # clipped sRGB: the 99th percentile of the brightest channel lands on the curve's white
    high = float(np.quantile(img[mask].max(axis=-1), 0.99))
    srgb = auto_exposure(img, mask, curve="srgb")
    assert key - HIGHLIGHT_MAX_STOPS < srgb < key
    assert srgb == pytest.approx(math.log2(CURVE_WHITE["srgb"] / high), abs=1e-6)
    assert (tonemap(img, exposure=srgb, curve="srgb")[mask] == 255).any(axis=-1).mean() <= 0.01
    # a tiny hot spot (a reflected sun) lowers it by at most HIGHLIGHT_MAX_STOPS
    hot = img.copy()
    ys, xs = np.nonzero(mask)
    hot[ys[:40], xs[:40]] = 1e4  # ~2 % of the ball
    assert auto_exposure(hot, mask, curve="neutral") == pytest.approx(
        auto_exposure(hot, mask) - HIGHLIGHT_MAX_STOPS
    )
    # where the log-average leaves the highlights in place, it stands
    dim = img * 0 + np.float32(0.1) * mask[..., None]
    assert auto_exposure(dim, mask, curve="neutral") == pytest.approx(auto_exposure(dim, mask))
    with pytest.raises(InputError, match="curve"):
        auto_exposure(img, mask, curve="filmic")


@needs_gl
@pytest.mark.parametrize("curve", GL_CURVES)
def test_the_shader_shows_what_tonemap_writes(curve):
    model = bench.synthetic_model(600, 1)
    sky = render.Lighting(envmap.builtin().to_latlong(32), base_res=16)
    cam = render.Camera.look_at((0.3, 0.6, 3.0), (0.0, 0.0, 0.0), fov=40)
    w, h = 40, 32
    with render.Renderer(model, sky, w, h, backend="gl", samples=1) as ren:
        img = ren.render(cam).numpy()
        # bright enough that the top pixels are past Neutral's shoulder and ACES's knee
        exposure = math.log2(4.0 / float(img.max()))
        ren.gl.make_current()
        screen = ren.gl.ctx.simple_framebuffer((w, h), components=4)
        ren.gl.present(screen, exposure=exposure, curve=curve)
        raw = screen.read(components=3, dtype="f1")
        screen.release()
    got = np.frombuffer(raw, np.uint8).reshape(h, w, 3)[::-1]
    want = tonemap(img, exposure=exposure, curve=curve)
    # one 8-bit level: float32 arithmetic in a different order, and the GPU's own rounding
    # of the unorm8 store
    assert int(np.abs(got.astype(int) - want).max()) <= 1
    assert (want > 200).any()  # the test reaches the shoulder


def test_view_opens_with_the_scene_camera(tmp_path):
    # a model keeps the camera it was baked with (a scene file's [camera]) in its provenance
    cam = render.Camera.look_at((3.1, 1.4, -3.3), (0.0, 0.12, 0.1), fov=30)
    model = bench.synthetic_model(12, 1)
    model.provenance["camera"] = cam.to_dict()
    assert model_camera(model) == cam
    # a bare mesh's scene frames it as lobelight render does, and a model without a camera
    # gets that framing too
    obj = tmp_path / "tet.obj"
    obj.write_text("v 0 0 0\nv 2 0 0\nv 0 1 0\nv 0 0 3\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    bare = scene.load(obj)
    assert bare.camera == scene.default_camera(bare.mesh)
    model.provenance["camera"] = bare.camera.to_dict()
    assert model_camera(model) == bare.camera
    model.provenance.pop("camera")
    assert model_camera(model) == scene.default_camera(model.mesh)
    model.provenance["camera"] = {"origin": [0, 0, 0], "target": [0, 0, 0]}  # unreadable
    assert model_camera(model) == scene.default_camera(model.mesh)


@pytest.mark.parametrize(
    "cam",
    [
        render.Camera.look_at((3.1, 1.4, -3.3), (0.0, 0.12, 0.1), fov=30),
        render.Camera.look_at((0.0, 0.2, 4.0), (0.0, 0.0, 0.0), up=(0, 0, 1), fov=50),
        render.Camera.look_at((0.0, 5.0, 0.0), (0.0, 0.0, 0.0), up=(0, 0, -1), fov_axis="smaller"),
    ],
)
def test_orbit_starts_at_the_camera_and_keeps_its_distance(cam):
    orbit = Orbit.from_camera(cam)
    got = orbit.camera()
    np.testing.assert_allclose(got.origin, cam.origin, atol=1e-9)
    np.testing.assert_allclose(got.up, np.asarray(cam.up) / np.linalg.norm(cam.up), atol=1e-12)
    assert (got.target, got.fov, got.fov_axis) == (cam.target, cam.fov, cam.fov_axis)
    orbit.yaw, orbit.pitch = 1.0, 0.4
    eye = np.subtract(orbit.camera().origin, cam.target)
    assert np.linalg.norm(eye) == pytest.approx(np.linalg.norm(np.subtract(cam.origin, cam.target)))
    # pitch is the elevation above the plane normal to the camera's up
    up = np.asarray(cam.up) / np.linalg.norm(cam.up)
    assert math.asin(float(eye @ up) / np.linalg.norm(eye)) == pytest.approx(0.4)


class _NoWindow:
    """glfw's calls that :func:`lobelight.render.view` makes, with no window: a 48x40
    framebuffer, closed after two frames."""

    PRESS, MOUSE_BUTTON_LEFT = 1, 0

    def __init__(self):
        self.polls = 0

    def __getattr__(self, name):
        return lambda *args, **kwargs: None

    def get_framebuffer_size(self, _win):
        return (48, 40)

    def window_should_close(self, _win):
        self.polls += 1
        return self.polls > 2


@needs_gl
def test_view_draws_its_first_frame_from_the_model_camera(monkeypatch):
    import moderngl  # optional (the gl extra)

    from lobelight.render import _gl, _window

    cam = render.Camera.look_at((3.1, 1.4, -3.3), (0.0, 0.12, 0.1), fov=30)
    model = bench.synthetic_model(600, 1)
    model.provenance["camera"] = cam.to_dict()
    drawn, shown = [], []
    draw = _gl.GLRenderer.draw

    def record_draw(self, camera, *args, **kwargs):
        drawn.append(camera)
        return draw(self, camera, *args, **kwargs)

    monkeypatch.setattr(_window, "_open_window", lambda w, h, t: (_NoWindow(), object()))
    # the window's context: a headless one (view's call has no arguments; moderngl's own
    # standalone contexts, the renderer's, pass theirs through)
    real = moderngl.create_context
    headless = {"standalone": True, "backend": "egl", "require": 330}
    monkeypatch.setattr(moderngl, "create_context", lambda **kw: real(**(kw or headless)))
    monkeypatch.setattr(_gl.GLRenderer, "draw", record_draw)
    monkeypatch.setattr(_gl.GLRenderer, "present", lambda self, screen, **kw: shown.append(kw))
    sky = envmap.builtin().to_latlong(32)
    out = render.view(model, env=sky, samples=1)
    assert out["frames"] == 2
    # the first draw is the exposure's probe frame, then the window's frames: all from the
    # scene's camera (nothing moved it)
    assert len(drawn) >= 3
    for c in drawn:
        np.testing.assert_allclose(c.origin, cam.origin, atol=1e-9)
        assert (c.target, c.fov, c.fov_axis) == (cam.target, cam.fov, cam.fov_axis)
    assert [kw["curve"] for kw in shown] == ["neutral", "neutral"]
    # the window's renderer: the sun taken out of the map, as view's default
    with render.Renderer(model, sky, 48, 40, backend="gl", samples=1, sun=True) as ren:
        img, mask = ren.render(cam, return_mask=True)
    want = auto_exposure(img, mask, curve="neutral")
    # the window's half-float target against float32: a few thousandths of a stop
    assert shown[0]["exposure"] == pytest.approx(want, abs=0.01)
