"""Anti-aliasing (samples per pixel), non-negative radiance, image files and turntables."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from PIL import Image

from lobelight import bench, envmap, fit, render, scene
from lobelight.errors import InputError
from lobelight.geometry import sphere
from lobelight.model import Model
from lobelight.render._gl import gl_available

needs_gl = pytest.mark.skipif(not gl_available(), reason="no headless OpenGL context (EGL)")
BACKENDS = [pytest.param("gl", marks=needs_gl), "torch"]

CAM = render.Camera.look_at((0.3, 0.6, 3.0), (0.0, 0.0, 0.0), fov=40)
SIZE = 64


def flat_model(transfer: torch.Tensor | None = None) -> Model:
    """A sphere with no glossy transport; its SH diffuse transfer ``(V, 25, 3)`` defaults to a
    constant first coefficient (under a constant environment: one colour, a sharp silhouette
    against a black background)."""
    sc = scene.builtin("sphere", subdivisions=3)
    v = sc.mesh.n_vertices
    mu = torch.zeros(v, 92, 1, 3)
    mu[..., 2] = 1.0
    g = fit.Gaussians(torch.zeros(v, 92, 1, 3), mu, torch.ones(v, 92, 1))
    if transfer is None:
        transfer = torch.zeros(v, 25, 3)
        transfer[:, 0] = 0.25
    return Model(sc.mesh, sphere.geodesic_views(), g, transfer, sc.materials, {})


@pytest.fixture(scope="module")
def sky():
    return render.Lighting(envmap.builtin().to_latlong(32), base_res=16)


@pytest.fixture(scope="module")
def white():
    env = envmap.EnvMap(torch.ones(6, 16, 16, 3), layout="cubemap", name="white")
    return render.Lighting(env, base_res=16)


def _edge(backend, lighting, samples, size=SIZE):
    with render.Renderer(
        flat_model(), lighting, size, size, backend=backend, samples=samples
    ) as ren:
        return ren.render(CAM, background=False, glossy=False, return_mask="coverage")


@pytest.mark.parametrize("n", range(1, 17))
def test_sample_offsets_are_stratified_and_centred(n):
    o = render.sample_offsets(n)
    assert o.shape == (n, 2)
    assert bool(((o > 0) & (o < 1)).all())
    np.testing.assert_allclose(o.mean(0), [0.5, 0.5], atol=1e-12)
    # n-rooks: every sample alone in its column and its row of the n x n sub-grid
    for axis in range(2):
        assert sorted(np.rint(o[:, axis] * n - 0.5).astype(int)) == list(range(n))
    if n == 4:  # the usual rotated grid
        want = {(0.375, 0.125), (0.875, 0.375), (0.125, 0.625), (0.625, 0.875)}
        assert {tuple(p) for p in o.tolist()} == want


@pytest.mark.parametrize("backend", BACKENDS)
def test_aa_gives_a_silhouette_intermediate_values_closer_to_the_reference(backend, white):
    # a flat-coloured sphere on black: with one sample a pixel is the object's colour or black;
    # with four, the pixels the silhouette crosses take the fraction of samples inside
    img1, cov1 = _edge(backend, white, 1)
    img4, cov4 = _edge(backend, white, 4)
    ref, cov_ref = _edge(backend, white, 16)
    inside = img1[cov1 == 1]
    value = float(inside.mean())
    assert value > 0.1 and float((inside - value).abs().max()) < 1e-5 * value  # flat colour

    def between(img):
        lum = img.mean(-1)
        return int(((lum > 0.02 * value) & (lum < 0.98 * value)).sum())

    # the silhouette's length in pixels: the circle's circumference from its area. Not every
    # pixel it crosses has samples on both sides (about 2/3 do with 4 samples)
    radius = math.sqrt(float(cov_ref.sum()) / math.pi)
    assert between(img1) == 0
    assert between(img4) > 0.5 * 2 * math.pi * radius
    # coverage goes in steps of a quarter, and the image is the colour times the coverage
    torch.testing.assert_close(cov4 * 4, (cov4 * 4).round(), rtol=0, atol=1e-6)
    want = (cov4[..., None] * value).expand_as(img4)
    torch.testing.assert_close(img4, want, rtol=1e-4, atol=1e-5 * value)
    # closer (L2) to a 16-sample reference than the aliased image
    err1 = float((img1 - ref).norm())
    err4 = float((img4 - ref).norm())
    assert err4 < 0.6 * err1, (err4, err1)


@needs_gl
def test_gl_and_torch_agree_with_aa(white, sky):
    # the same sample points in both backends: coverage agrees except where a sample grazes
    # the silhouette, and shaded values (a glossy model under a real sky) agree to 1e-3 on the
    # pixels entirely on the object
    g, cg = _edge("gl", white, 4)
    t, ct = _edge("torch", white, 4)
    assert int((cg != ct).sum()) <= 2
    assert float((g - t).abs().amax(-1).flatten().sort().values[-3]) < 1e-4 * float(g.max())
    model = bench.synthetic_model(1500, 1)
    out = {}
    for backend in ("gl", "torch"):
        with render.Renderer(model, sky, SIZE, 48, backend=backend, samples=4) as ren:
            out[backend] = ren.render(CAM, 40.0, background=False, return_mask=True)
    (a, ma), (b, mb) = out["gl"], out["torch"]
    both = ma & mb
    assert int(both.sum()) > 500
    assert int((ma != mb).sum()) <= 2
    rel = (a - b)[both].abs().amax(-1) / b[both].amax(-1).clamp_min(1e-6)
    assert float(rel.max()) < 1e-3


@pytest.mark.parametrize("backend", BACKENDS)
def test_masks_bool_is_every_sample_on_the_object(backend, white):
    with render.Renderer(flat_model(), white, 40, 30, backend=backend, samples=4) as ren:
        img, cov = ren.render(CAM, background=False, return_mask="coverage")
        img2, full = ren.render(CAM, background=False, return_mask=True)
        with pytest.raises(InputError, match="return_mask"):
            ren.render(CAM, return_mask="yes")
    torch.testing.assert_close(img, img2, rtol=0, atol=0)
    assert cov.dtype == torch.float32 and full.dtype == torch.bool
    assert bool(((cov >= 0) & (cov <= 1)).all())
    assert bool((full == (cov == 1)).all())
    assert bool(((cov > 0) & (cov < 1)).any())  # partly covered pixels exist
    with render.Renderer(flat_model(), white, 40, 30, backend=backend, samples=1) as ren:
        _, cov1 = ren.render(CAM, background=False, return_mask="coverage")
    assert set(cov1.unique().tolist()) <= {0.0, 1.0}


def test_samples_are_checked(white):
    for bad in (0, 257, 2.5, True, "4"):
        with pytest.raises(InputError, match="samples"):
            render.Renderer(flat_model(), white, 8, 8, backend="torch", samples=bad)


@pytest.mark.parametrize("backend", BACKENDS)
def test_radiance_is_never_negative(backend, sky):
    # an SH transfer along the normal (no constant term): its diffuse colour is n . L1 of the
    # sky's linear band, negative on the far half of the sphere, as ringing is in creases
    m = flat_model()
    transfer = torch.zeros(m.mesh.n_vertices, 25, 3)
    transfer[:, 1:4] = m.mesh.normals[:, [1, 2, 0], None]
    m = flat_model(transfer)
    cam = render.Camera.look_at((0.0, -3.0, 0.3), (0.0, 0.0, 0.0), fov=40)
    with render.Renderer(m, sky, 48, 48, backend=backend, samples=4) as ren:
        img, mask = ren.render(cam, background=False, return_mask=True)
        if backend == "gl":
            raw, _ = ren.gl.read()  # the frame before the clamp
        else:
            raw, _ = render._torch.render_torch(
                m, sky, cam, 48, 48, rot=torch.eye(3), background=False, offsets=ren.offsets
            )
        px, hit = ren.render_pixels(cam, mask.nonzero(), background=False)
    assert float(raw.min()) < -1e-3  # the unclamped transfer does go negative
    assert float(img.min()) >= 0 and float(px.min()) >= 0 and bool(hit.all())
    torch.testing.assert_close(img, raw.clamp_min(0), rtol=0, atol=0)


def test_jpeg_files_and_output_path_checks(tmp_path):
    img = torch.rand(6, 9, 3)
    for name in ("a.jpg", "b.JPEG"):
        p = render.save_image(tmp_path / name, img, exposure=0.5)
        with Image.open(p) as im:
            assert im.format == "JPEG" and im.size == (9, 6) and im.mode == "RGB"
    assert render.check_output_path(tmp_path / "c.exr") == tmp_path / "c.exr"
    with pytest.raises(InputError, match="does not exist") as e:
        render.check_output_path(tmp_path / "missing" / "a.png")
    assert str(tmp_path / "missing" / "a.png") in str(e.value)
    (tmp_path / "dir.png").mkdir()
    with pytest.raises(InputError, match="is a directory"):
        render.check_output_path(tmp_path / "dir.png")
    for bad in ("a.tiff", "noext"):
        with pytest.raises(InputError, match="unsupported image type") as e:
            render.check_output_path(tmp_path / bad)
        assert str(tmp_path / bad) in str(e.value)
    # save_image refuses an unknown type before any work: nothing is written
    with pytest.raises(InputError, match="unsupported image type"):
        render.save_image(tmp_path / "a.bmp", img)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.jpg", "b.JPEG", "dir.png"]


def test_orbit_turns_about_the_target_along_up():
    cam = render.Camera.look_at((0.0, 1.0, 3.0), (0.0, 0.5, 0.0), fov=30)
    q = render.orbit(cam, 90.0)
    np.testing.assert_allclose(q.origin, (3.0, 1.0, 0.0), atol=1e-12)
    assert (q.target, q.up, q.fov) == (cam.target, cam.up, cam.fov)
    np.testing.assert_allclose(render.orbit(cam, 360.0).origin, cam.origin, atol=1e-12)


@pytest.mark.parametrize("backend", BACKENDS)
def test_turntable_writes_frames_and_an_animation_with_one_exposure(backend, tmp_path, sky):
    model = bench.synthetic_model(600, 1)
    calls = []
    with render.Renderer(model, sky, 40, 32, backend=backend, samples=4) as ren:
        info = render.turntable(ren, CAM, 5, tmp_path / "tt", progress=lambda *a: calls.append(a))
        first, mask = ren.render(CAM, return_mask=True)
        third = ren.render(render.orbit(CAM, 2 * 360.0 / 5))
    names = [f"frame_{k:03d}.png" for k in range(5)]
    assert [p.rsplit("/", 1)[-1] for p in info["frames"]] == names
    assert calls == [("turntable", k, 5) for k in range(1, 6)]
    # one exposure for all frames, the first frame's object pixels'
    assert info["exposure"] == pytest.approx(render.auto_exposure(first, mask))
    want = render.tonemap(third, exposure=info["exposure"])
    got = np.asarray(Image.open(tmp_path / "tt" / names[2]))
    assert int(np.abs(got.astype(int) - want).max()) <= 1
    with Image.open(info["animation"]) as gif:
        assert gif.format == "GIF" and gif.n_frames == 5 and gif.size == (40, 32)
    assert info["n_frames"] == 5 and info["samples"] == 4 and info["seconds"] > 0


def test_turntable_turns_the_light_and_checks_before_rendering(tmp_path, sky):
    with render.Renderer(flat_model(), sky, 24, 24, backend="torch", samples=1) as ren:
        with pytest.raises(InputError, match="unsupported image type"):
            render.turntable(ren, CAM, 3, tmp_path / "a", animation="frames.mp4")
        with pytest.raises(InputError, match="rotate"):
            render.turntable(ren, CAM, 3, tmp_path / "b", rotate="sun")
        with pytest.raises(InputError, match="n_frames"):
            render.turntable(ren, CAM, 0, tmp_path / "c")
        info = render.turntable(
            ren, CAM, 3, tmp_path / "d", rotate="light", exposure=1.0, animation="spin.webp"
        )
        turned = ren.render(CAM, 120.0)
    assert not (tmp_path / "a").exists()  # nothing made before the check
    assert info["exposure"] == 1.0 and info["rotate"] == "light"
    want = render.tonemap(turned, exposure=1.0)
    got = np.asarray(Image.open(info["frames"][1]))
    assert int(np.abs(got.astype(int) - want).max()) <= 1
    with Image.open(info["animation"]) as anim:
        assert anim.format == "WEBP" and anim.n_frames == 3
