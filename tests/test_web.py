"""The WebGL 2 viewer (:mod:`lobelight.web`): its folder written and read back, and the page in
a real browser (headless chromium on SwiftShader, driven by Playwright) against the torch
renderer."""

from __future__ import annotations

import base64
import io
import os
import shutil
import threading
import urllib.request
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

import test_albedo_texture as checker
from lobelight import brdf, envmap, fit, render, scene, web
from lobelight.cli import main
from lobelight.data import DEFAULT_ENVMAP, envmap_path
from lobelight.errors import InputError
from lobelight.geometry import sphere
from lobelight.lobes import sh
from lobelight.model import Model
from lobelight.web._serve import make_server

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
try:
    import playwright.sync_api as _pw  # optional (the web extra)
except ImportError:
    _pw = None

needs_browser = pytest.mark.skipif(
    CHROMIUM is None or _pw is None,
    reason="needs the system chromium (apt-get install chromium) and Playwright for Python "
    "(pip install 'lobelight[web]'); its own browser download is not used",
)
#: Chromium's flags for WebGL 2 on SwiftShader without a display.
FLAGS = ["--headless=new", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]
W, H = 96, 72


def analytic_model(n: int, roughness: float | None = None) -> Model:
    """``sphere:2`` whose transport is ``n`` analytic Gaussians per view (no fit: fast): a
    glossy lobe about the mirror direction, a broad one about the normal, and for ``n = 3`` a
    mid-width one between; weights zero below the horizon, as a fitted model has them.
    ``roughness``: the material's GGX alpha (default the built-in sphere's)."""
    kw = {} if roughness is None else {"roughness": roughness}
    sc = scene.builtin("sphere", subdivisions=2, **kw)
    nrm = sc.mesh.normals  # (V, 3)
    views = sphere.geodesic_views()  # (J, 3)
    cos = nrm @ views.T  # (V, J)
    refl = 2 * cos[..., None] * nrm[:, None] - views[None]  # (V, J, 3)
    mid = torch.nn.functional.normalize(refl + nrm[:, None], dim=-1)
    mu = torch.stack([refl, nrm[:, None].expand_as(refl), mid], 2)[:, :, :n]  # (V, J, n, 3)
    lam = torch.tensor([300.0, 3.0, 40.0])[:n].expand(*cos.shape, n).clone()
    up = (cos > 0).float()[..., None, None]
    w = torch.tensor([[0.9, 0.8, 0.6], [0.05, 0.1, 0.2], [0.2, 0.3, 0.1]])[:n]
    w = w * up * (lam[..., None] / 6.3)
    diffuse = torch.zeros(nrm.shape[0], 25, 3)
    diffuse[:, 0] = 0.2
    diffuse[:, 1:4] = 0.1 * nrm[:, [1, 2, 0], None]
    g = fit.Gaussians(w.contiguous(), torch.nn.functional.normalize(mu, dim=-1), lam)
    return Model(sc.mesh, views, g, diffuse, sc.materials, {"scene": "analytic"})


@pytest.fixture(scope="module")
def sky():
    # the built-in sky made small: the same sun and sky, without seconds of resampling
    return envmap.builtin(height=64)


@pytest.fixture(scope="module")
def browser():  # every test that takes it is marked needs_browser
    with _pw.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
        yield b
        b.close()


def open_page(browser, folder, query="still=1", viewport=(320, 240)):
    """The folder's page, loaded (its ``lobelight.ready`` settled)."""
    page = browser.new_page(viewport={"width": viewport[0], "height": viewport[1]})
    page.goto(f"file://{folder}/index.html?{query}")
    page.wait_for_function("window.lobelight && window.lobelight.ready")
    page.evaluate("window.lobelight.ready")
    return page


def render_in_page(page, cam, rotation, size=(W, H), **parts) -> np.ndarray:
    """The test hook's linear RGBA (H, W, 4) for a camera and a rotation (degrees about +y)."""
    w, h = size
    f = cam.frame(dtype=torch.float64).numpy()
    req = {
        "origin": list(cam.origin),
        "left": f[0].tolist(),
        "up": f[1].tolist(),
        "dir": f[2].tolist(),
        "tan_half": list(cam.tan_half(w, h)),
        "width": w,
        "height": h,
        "rotation": rotation,
        **parts,
    }
    r = page.evaluate("req => window.lobelight.renderLinear(req)", req)
    return np.frombuffer(base64.b64decode(r["b64"]), np.float32).reshape(h, w, 4)


def interior(mask: np.ndarray) -> np.ndarray:
    """Pixels whose 3 x 3 neighbourhood is all on the object."""
    m = mask.copy()
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            m &= np.roll(np.roll(mask, dy, 0), dx, 1)
    return m


# ---------------------------------------------------------------------------------------------
# the folder


def test_the_folder_reads_back_as_the_model(sky, tmp_path):
    m = analytic_model(3)
    info = web.export_web(m, tmp_path / "v", [sky], base_res=32)
    assert info["bytes"] == sum(info["files"].values())
    assert sorted(info["files"]) == sorted(
        ["env-0.js", "model.js", "shaders.js", "index.html", "viewer.js"]
    )
    f = web.read_web(tmp_path / "v")
    a = f.arrays
    np.testing.assert_array_equal(a["positions"], m.mesh.vertices.numpy())
    np.testing.assert_array_equal(a["faces"], m.mesh.faces.numpy())
    keep = (a["flags"] & 1).astype(bool)
    above = (a["flags"] & 2).astype(bool)
    want_above = (m.views[None] * m.mesh.normals[:, None]).sum(-1) > 0
    np.testing.assert_array_equal(above, want_above.numpy())
    g = m.gaussians
    # half floats: 11 significant bits, a rounding of at most 2^-11 relative
    e = (g.w.double() * g.lam.double().mul(-2).exp().neg().add(1)[..., None]
         * (2 * np.pi / g.lam.double())[..., None])[torch.from_numpy(keep)]  # fmt: skip
    np.testing.assert_allclose(a["light"].astype(np.float64), e.numpy(), rtol=2**-11, atol=6e-8)
    np.testing.assert_allclose(
        a["mean"].astype(np.float32), g.mu[torch.from_numpy(keep)].numpy(), rtol=0, atol=2**-11
    )
    sig = g.lam[torch.from_numpy(keep)].rsqrt().numpy()
    np.testing.assert_allclose(a["sigma"].astype(np.float32), sig, rtol=2**-11)
    # the records left out carry no light at their view nor at a neighbour
    assert float(g.w.amax((-1, -2))[~torch.from_numpy(keep)].max()) == 0.0
    # every shader variant is the ES dialect's
    for variant in f.shaders.values():
        for vs, fs in variant.values():
            assert vs.startswith("#version 300 es") and fs.startswith("#version 300 es")
    # the SH fit of the page's rotation is exact on band-limited functions
    env_sh = torch.tensor(np.array(f.envs[0][1]["sh"]), dtype=torch.float64)
    d = torch.tensor(np.array(a["sh_dirs"]), dtype=torch.float64)
    back = torch.tensor(np.array(a["sh_fit"]), dtype=torch.float64) @ (sh.basis(d, 5) @ env_sh)
    torch.testing.assert_close(back, env_sh, rtol=0, atol=1e-5 * float(env_sh.abs().max()))


def test_large_arrays_travel_gzipped_and_damaged_ones_are_refused():
    """An array past GZIP_MIN_BYTES that compresses is stored gzipped and reads back exactly;
    one that does not (random bytes) stays raw; a record whose gzip data is damaged, inflates
    past its shape, or carries bytes after it gets one InputError naming it."""
    from lobelight.web import _format

    flat = np.zeros((64, 1024), np.uint8)
    flat[:, ::7] = 255  # tiles of runs: compresses
    rec = _format.encode_array(flat)
    assert rec.get("gzip") is True and len(rec["b64"]) < 0.2 * flat.nbytes
    np.testing.assert_array_equal(_format.decode_array(rec, "tiles"), flat)
    noise = np.random.default_rng(0).integers(0, 256, (64, 1024), dtype=np.uint8)
    raw = _format.encode_array(noise)
    assert "gzip" not in raw
    np.testing.assert_array_equal(_format.decode_array(raw, "noise"), noise)
    small = np.arange(10, dtype="<f4")  # below the threshold: raw
    assert "gzip" not in _format.encode_array(small)
    packed = base64.b64decode(rec["b64"])
    bad = {**rec, "b64": base64.b64encode(packed[:20] + b"x" * 40 + packed[60:]).decode()}
    big = {**rec, "shape": [32, 1024]}  # inflates to twice its shape
    extra = {**rec, "b64": base64.b64encode(packed + b"tail").decode()}
    for r, says in ((bad, "gzip"), (big, "inflates"), (extra, "after")):
        with pytest.raises(InputError, match=says) as e:
            _format.decode_array(r, "model.js: vis_tiles")
        assert "vis_tiles" in str(e.value)


def test_a_sharp_metals_hit_tiles_read_back_from_their_steps(sky, tmp_path):
    """The hit tiles travel as steps (each texel's flat index and triangle less the one
    before's): summed, they are the model's tiles' texels that see the object, in order, and
    their triangles; steps that do not ascend, or sum past the last tile or face, are
    refused with one InputError naming the problem."""
    from lobelight.web import _export

    m = sharp_torus()
    web.export_web(m, tmp_path / "v", [sky], base_res=32)
    f = web.read_web(tmp_path / "v")
    a, h = f.arrays, f.header
    face = m.hits()[0].reshape(-1).numpy()  # (V R R,) -1 where the texel finds nothing
    hit = np.nonzero(face >= 0)[0]
    assert 0 < hit.size < face.size
    np.testing.assert_array_equal(np.cumsum(a["hit_step"], dtype=np.int64), hit)
    np.testing.assert_array_equal(np.cumsum(a["hit_face_step"], dtype=np.int64), face[hit])
    past = a["hit_step"].copy()
    past[-1] += h["n_vertices"] * h["sharp"]["vis_res"] ** 2
    still = a["hit_step"].copy()
    still[1] = 0
    wrong = a["hit_face_step"].copy()
    wrong[0] = -1
    for change, says in (
        ({"hit_step": past}, "past the last tile"),
        ({"hit_step": still}, "do not ascend"),
        ({"hit_face_step": wrong}, "not one of the mesh's faces"),
        ({"hit_dist": a["hit_dist"][1:]}, "differ in length"),
    ):
        with pytest.raises(InputError, match=says):
            _export._check_sharp_arrays(tmp_path / "v" / "model.js", h, {**a, **change})


def test_the_folder_is_written_atomically_and_never_over_an_input(sky, tmp_path):
    m = analytic_model(1)
    out = tmp_path / "v"
    web.export_web(m, out, [sky], base_res=16)
    web.export_web(m, out, [sky], base_res=16)  # an earlier export is replaced whole
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v"]  # nothing partial left
    other = tmp_path / "other"
    other.mkdir()
    (other / "keep.txt").write_text("x")
    with pytest.raises(InputError, match="not a web export"):
        web.export_web(m, other, [sky], base_res=16)
    src = out / "model.npz"
    with pytest.raises(InputError, match="holds an input"):
        web.export_web(m, out, [sky], base_res=16, inputs=[src])
    (out / "model.js").write_text('lobelight_data("model", {});')
    with pytest.raises(InputError):
        web.read_web(out)


def test_the_server_serves_the_folder(sky, tmp_path):
    web.export_web(analytic_model(1), tmp_path / "v", [sky], base_res=16)
    server = make_server(tmp_path / "v", 0)
    port = server.server_address[1]
    t = threading.Thread(target=server.serve_forever, daemon=True)
    t.start()
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/viewer.js") as r:
            assert r.headers["Content-Type"].startswith("text/javascript")
            assert b"renderLinear" in r.read()
    finally:
        server.shutdown()
        server.server_close()
    assert f"ssh -L {port}:localhost:{port}" in web.tunnel_hint(port)


def test_the_export_command_writes_the_folder(tmp_path):
    src = tmp_path / "m.npz"
    analytic_model(1).save(src)
    out = tmp_path / "web"
    assert main(["export", str(src), "--web", str(out), "--base-res", "16", "-q"]) == 0
    assert web.read_web(out).header["n_gaussians"] == 1
    # a map given by its path is named by its file's stem: the page shows no folder of this
    # machine
    out2 = tmp_path / "web2"
    env = envmap_path(DEFAULT_ENVMAP)
    args = ["export", str(src), "--web", str(out2), "--env", str(env), "--base-res", "16", "-q"]
    assert main(args) == 0
    assert [e["name"] for e in web.read_web(out2).header["envs"]] == [Path(env).stem]
    # one of --gltf and --web; --gltf takes one map
    assert main(["export", str(src), "-q"]) == 2
    glb = tmp_path / "m.glb"
    assert main(["export", str(src), "--gltf", str(glb), "--env", "builtin", "--env",
                 "builtin", "-q"]) == 2  # fmt: skip


def test_view_without_a_display_names_view_web(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    src = tmp_path / "m.npz"
    analytic_model(1).save(src)
    assert main(["view", str(src)]) == 2
    assert "view --web" in capsys.readouterr().err


def test_view_web_under_json_keeps_stdout_for_the_json(tmp_path, monkeypatch, capsys):
    # the server's lines (its URL, the SSH tunnel) go to stderr; stdout is one JSON object
    import json

    import lobelight.cli._commands as commands

    served = []

    def serve(folder, port, *, announce):  # the real one runs until Ctrl-C
        served.append(web.read_web(folder).header["n_vertices"])
        announce(f"lobelight web viewer: http://localhost:{port}/")

    monkeypatch.setattr(commands, "serve", serve)
    src = tmp_path / "m.npz"
    analytic_model(1).save(src)
    assert main(["view", "--web", str(src), "--port", "8123", "--json"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["port"] == 8123 and served == [162]
    assert "http://localhost:8123/" in err and "writing the web viewer" in err


# ---------------------------------------------------------------------------------------------
# the page in a browser


@needs_browser
def test_the_pages_sh_basis_is_lobelights(browser, sky, tmp_path):
    web.export_web(analytic_model(1), tmp_path / "v", [sky], base_res=16)
    page = open_page(browser, tmp_path / "v")
    d = torch.nn.functional.normalize(torch.randn(20, 3, generator=torch.manual_seed(0)), dim=-1)
    got = page.evaluate("ds => ds.map(d => window.lobelight.shBasis(d[0], d[1], d[2], 5))",
                        d.tolist())  # fmt: skip
    page.close()
    # both in float64: agreement to rounding
    torch.testing.assert_close(
        torch.tensor(got, dtype=torch.float64), sh.basis(d.double(), 5), rtol=0, atol=1e-12
    )


@needs_browser
@pytest.mark.parametrize("n", [1, 3])
@pytest.mark.parametrize("sun", [False, True])
def test_the_browser_matches_the_torch_path(browser, sky, tmp_path, n, sun):
    """Linear radiance of the page's test hook against ``Renderer(..., backend="torch")`` on
    400 sampled interior pixels of the object, with and without a lighting rotation.

    Bound: 1e-2 relative (of the pixel's largest channel). The page's data are half floats
    (2^-11 relative per number: the records, the SH transfer, the prefiltered chain), which
    moves a pixel by about 1e-3 here. SwiftShader snaps vertices to 1/16 of a pixel (Vulkan's
    minimum sub-pixel precision; Mesa's llvmpipe, which the desktop renderer's tests use, snaps
    to 1/256), which moves each shading point by up to 1/32 of a pixel: at 96 x 72 that is
    2e-3 of the sphere's radius and up to 4e-2 of a sharp highlight's radiance, so the image is
    rendered at 384 x 288, where it is a quarter of that. Pixels at the silhouette are left out
    (a grazing pixel's glossy image changes by far more than 1e-2 across it)."""
    m = analytic_model(n)
    lighting = render.Lighting(sky, base_res=32, sun=sun)
    assert (lighting.sun is not None) == sun
    web.export_web(m, tmp_path / "v", [lighting])
    page = open_page(browser, tmp_path / "v")
    cam = render.model_camera(m)
    w, h = 4 * W, 4 * H
    tr = render.Renderer(m, lighting, w, h, backend="torch", samples=1)
    gen = torch.Generator().manual_seed(3)
    for rotation in (0.0, 65.0):
        img = render_in_page(page, cam, rotation, size=(w, h))
        px = interior(img[..., 3] > 0.5)
        assert int(px.sum()) > 4000
        rows, cols = np.nonzero(px)
        pick = torch.randperm(rows.size, generator=gen)[:400].numpy()
        at = torch.from_numpy(np.stack([rows[pick], cols[pick]], -1))
        ref, hit = tr.render_pixels(cam, at, rotation or None)
        assert bool(hit.all())  # the page's coverage is the torch path's
        got = img[rows[pick], cols[pick], :3]
        ref = ref.numpy()
        rel = np.abs(got - ref).max(-1) / np.maximum(ref.max(-1), 1e-6)
        if not sun:
            assert float(rel.max()) <= 1e-2, (rotation, float(rel.max()))
            continue
        # the sun's shadow: the shader's soft shadow map against the torch path's rays over
        # the disc differ in the penumbrae and at the terminator, as the desktop shader does
        # (tests/test_sun.py bounds its pixels over 1e-2 and 0.1 likewise): there the page
        # must equal the desktop shader
        assert float((rel > 1e-2).mean()) <= 0.01, (rotation, float(rel.max()))
        assert float(rel.max()) <= 0.1, (rotation, float(rel.max()))
        if render.gl_available():
            with render.Renderer(m, lighting, w, h, backend="gl", samples=1) as gl:
                want = gl.render(cam, rotation or None, background=False).numpy()
            want = want[rows[pick], cols[pick]]
            rel = np.abs(got - want).max(-1) / np.maximum(want.max(-1), 1e-6)
            assert float(rel.max()) <= 1e-2, (rotation, float(rel.max()))
    page.close()


@needs_browser
def test_a_still_frame_averages_the_desktops_samples(browser, sky, tmp_path):
    """Four samples per pixel (``Renderer``'s default, the page's still frame) at their
    sub-pixel offsets (:func:`lobelight.render.sample_offsets`) against the torch path's, over
    the whole object: the silhouette's coverage (alpha) is the fraction of samples on the
    object in both, and the interior within the one-sample bound (test above)."""
    m = analytic_model(1)
    lighting = render.Lighting(sky, base_res=32)
    web.export_web(m, tmp_path / "v", [lighting])
    assert web.read_web(tmp_path / "v").header["samples"] == render.sample_offsets(4).tolist()
    page = open_page(browser, tmp_path / "v")
    cam = render.model_camera(m)
    w, h = 4 * W, 4 * H
    img = render_in_page(page, cam, 0.0, size=(w, h), offsets=render.sample_offsets(4).tolist())
    page.close()
    tr = render.Renderer(m, lighting, w, h, backend="torch", samples=4)
    ref, cov = tr.render(cam, return_mask="coverage", background=False)
    ref, cov = ref.numpy(), cov.numpy()
    # coverage: quarters, equal but where a sample grazes the silhouette: SwiftShader's
    # 1/16-pixel snapping moves an edge by up to 1/32 pixel, so each of a silhouette pixel's
    # four samples, spread over the pixel, flips with a chance of about 1/64 (measured: 7 %
    # of the silhouette's pixels differ, each by one sample)
    assert np.isin(img[..., 3], [0.0, 0.25, 0.5, 0.75, 1.0]).all()
    edge = int(((cov > 0) & (cov < 1)).sum())
    assert edge > 300
    off = np.abs(img[..., 3] - cov)
    assert int((off > 0.1).sum()) <= 0.15 * edge
    assert float(off.max()) <= 0.25 + 1e-6
    px = interior(cov >= 1.0)
    rel = np.abs(img[..., :3] - ref).max(-1) / np.maximum(ref.max(-1), 1e-6)
    assert float(rel[px].max()) <= 1e-2


def _canvas(page) -> np.ndarray:
    """The canvas's pixels (its own PNG: the panel over it is not in it), (H, W, 3) float."""
    from PIL import Image  # optional (matplotlib's dependency, in the dev extra)

    url = page.evaluate("document.getElementById('view').toDataURL('image/png')")
    png = base64.b64decode(url.split(",", 1)[1])
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(np.float32)


@needs_browser
def test_the_page_shows_the_object_and_its_controls_change_it(browser, sky, tmp_path):
    web.export_web(analytic_model(1), tmp_path / "v", [sky, sky], base_res=32)
    page = open_page(browser, tmp_path / "v", "size=160x120&still=1", (400, 300))
    assert page.evaluate("window.lobelight.status.ok")
    page.evaluate("() => new Promise(r => requestAnimationFrame(() => r()))")
    a = _canvas(page)
    # non-blank: the object at the centre differs from the background at the corners
    assert a.std() > 5
    centre = a[50:70, 70:90].mean((0, 1))
    corner = a[:10, :10].mean((0, 1))
    assert np.abs(centre - corner).max() > 10
    if os.environ.get("LOBELIGHT_WEB_SCREENSHOT"):  # the README's picture
        page.screenshot(path=os.environ["LOBELIGHT_WEB_SCREENSHOT"])

    def after(element, prop, value, event):
        page.evaluate(
            "([id, p, v, ev]) => { const e = document.getElementById(id); e[p] = v;"
            " e.dispatchEvent(new Event(ev)); }",
            [element, prop, value, event],
        )
        return _canvas(page)

    b = after("exposure", "value", "-3", "input")
    assert b[50:70, 70:90].mean() < a[50:70, 70:90].mean() - 5  # darker
    c = after("background", "checked", False, "change")
    assert np.abs(c[:10, :10] - b[:10, :10]).max() > 1  # the environment hidden
    assert np.abs(c[55:65, 75:85] - b[55:65, 75:85]).max() < 1e-6  # the object kept
    d = after("parts", "value", "diffuse", "change")
    assert np.abs(d - c).max() > 1  # the glossy part gone
    page.close()


@needs_browser
def test_maps_load_in_any_order_and_a_map_file_without_its_map_is_named(browser, sky, tmp_path):
    # two maps, the second four times as bright: opened at the second (whose file the page
    # reads while the model decodes), then the first; the map a file hands over is its own
    m = analytic_model(1)
    bright = envmap.EnvMap(4 * sky.data, layout=sky.layout)
    web.export_web(m, tmp_path / "v", [sky, bright], base_res=16)
    page = open_page(browser, tmp_path / "v", "size=64x48&still=1&env=1")
    assert page.evaluate("window.lobelight.status.ok")
    cam = render.model_camera(m)
    four = render_in_page(page, cam, 0.0, (32, 24), glossy=False, background=False, env=1)
    plain = render_in_page(page, cam, 0.0, (32, 24), glossy=False, background=False, env=0)
    page.close()
    on = plain[..., 3] > 0.5
    assert on.sum() > 50
    assert np.allclose(four[on, :3], 4 * plain[on, :3], rtol=1e-2, atol=1e-6)
    # a map file that runs without handing over its map: a message naming it, not a wait
    (tmp_path / "v" / "env-1.js").write_text("// damaged\n")
    page = open_page(browser, tmp_path / "v", "size=64x48&still=1&env=1")
    status = page.evaluate("window.lobelight.status")
    assert not status["ok"] and "env-1.js holds no map" in status["message"]
    page.close()


@needs_browser
def test_the_page_refuses_an_array_that_does_not_fill_its_shape(browser, sky, tmp_path):
    # the model's Gaussian records gzipped (as a large model's are) with one row more in their
    # shape than the member holds, and the positions (plain) likewise: each a message naming
    # the array, not a picture drawn from zeros; the same records with their own shape draw
    import gzip
    import json

    from lobelight.web import _format

    web.export_web(analytic_model(1), tmp_path / "v", [sky], base_res=16)
    path = tmp_path / "v" / "model.js"
    text = path.read_text()
    start = text.index("{")
    head, doc = text[:start], json.loads(text[start : text.rstrip().rfind(")")])
    light = _format.decode_array(doc["arrays"]["light"], "light")
    packed = gzip.compress(np.ascontiguousarray(light).tobytes(), mtime=0)
    good = {**doc["arrays"]["light"], "gzip": True, "b64": base64.b64encode(packed).decode()}
    shape = [light.shape[0] + 1, *light.shape[1:]]
    pos = doc["arrays"]["positions"]
    cases = (
        ({"light": good}, None),
        ({"light": {**good, "shape": shape}}, "light does not inflate to its shape"),
        ({"positions": {**pos, "shape": [pos["shape"][0] + 1, 3]}}, "positions holds"),
    )
    for change, says in cases:
        arrays = {**doc["arrays"], **change}
        path.write_text(f"{head}{json.dumps({**doc, 'arrays': arrays})});\n")
        page = open_page(browser, tmp_path / "v", "size=64x48&still=1")
        status = page.evaluate("window.lobelight.status")
        page.close()
        if says is None:
            assert status["ok"], status
        else:
            assert not status["ok"] and says in status["message"], status


@needs_browser
def test_frames_while_moving_have_fewer_pixels_and_the_rested_frame_all(browser, sky, tmp_path):
    # the interactive page (no still=1): frames while the view changes at half the canvas's
    # pixels across (moving=0.5), stretched onto the canvas, then the rested frame
    web.export_web(analytic_model(1), tmp_path / "v", [sky], base_res=32)
    page = open_page(browser, tmp_path / "v", "size=160x120&moving=0.5", (400, 300))
    assert page.evaluate("window.lobelight.status.ok")
    # the view turned at every animation frame for 0.8 s (the readout counts after 0.5 s)
    page.evaluate(
        "() => new Promise(r => { const api = window.lobelight, t0 = performance.now();"
        " const f = () => { api.state.orbit.yaw += 0.01; api.redraw();"
        " if (performance.now() - t0 < 800) requestAnimationFrame(f); else r(); };"
        " requestAnimationFrame(f); })"
    )
    assert "50 % across" in page.locator("#fps").inner_text()
    targets = page.evaluate("Object.values(window.lobelight.viewer.targets).map(t => t.w)")
    assert 80 in targets  # a moving frame drawn at 80 x 60
    moving = _canvas(page)
    page.wait_for_timeout(600)  # the view rests: the full frame
    rested = _canvas(page)
    page.close()
    for img in (moving, rested):  # the object at the centre, unlike the corners
        assert np.abs(img[50:70, 70:90].mean((0, 1)) - img[:10, :10].mean((0, 1))).max() > 10
    # the same view: the stretched half-size frame differs from the full one by its blur
    assert np.abs(moving - rested).mean() < 10


@needs_browser
def test_a_model_beyond_the_texture_limits_gets_a_clear_message(browser, sky, tmp_path):
    # a device whose textures hold 128 x 128 texels: the records need 162 x 92 x 2 more
    web.export_web(analytic_model(1), tmp_path / "v", [sky], base_res=16)
    page = open_page(browser, tmp_path / "v", "max_texture=128")
    status = page.evaluate("window.lobelight.status")
    assert not status["ok"]
    assert "too large for this device's textures" in status["message"]
    assert page.locator("#message").is_visible()
    page.close()


def sharp_torus(indirect: bool = False, varying: bool = False, phong: bool = False) -> Model:
    """A torus of a sharp metal (GGX alpha 0.03: :func:`lobelight.brdf.sharp_lobe` holds a
    mixture for it) with no fitted glossy transport and a constant diffuse transfer
    (tests/test_reflection.py's bare model): the desktop shades its direct light per pixel
    (reflection.glsl), its inner side sees the torus (hit tiles), and the hit points are
    shaded from the vertex stage's capture (their diffuse light). ``indirect``: a second,
    indirect Gaussian about the normal (the capture's indirect lobes, read at the hit points).
    ``varying``: a glTF lobe whose roughness runs from 0.005 to 0.3 around the torus and
    whose F0 changes across it (sharp at some vertices, shaded by the Gaussians at the rest).
    ``phong``: a Phong lobe as sharp (one live Gaussian of the mixture's five) and hit tiles
    that find nothing, as a convex object's (the pages' shaders leave the hits' code out)."""
    tm = trimesh.creation.torus(
        major_radius=1.0, minor_radius=0.45, major_sections=48, minor_sections=24
    )
    mesh = scene.mesh_from_arrays(tm.vertices, tm.faces, name="torus")
    mat = {"diffuse": [0.3, 0.3, 0.3], "model": "ggx", "alpha": 0.03, "specular": [0.9, 0.8, 0.6]}
    v = mesh.n_vertices
    g = fit.Gaussians(
        torch.zeros(v, 92, 1, 3), torch.zeros(v, 92, 1, 3) + torch.tensor([0.0, 0.0, 1.0]),
        torch.ones(v, 92, 1),
    )  # fmt: skip
    if indirect:
        w = torch.cat([g.w, torch.full((v, 92, 1, 3), 0.3)], 2)
        mu = torch.cat([g.mu, mesh.normals[:, None, None].expand(v, 92, 1, 3)], 2)
        g = fit.Gaussians(w, mu, torch.cat([g.lam, torch.full((v, 92, 1), 4.0)], 2))
    diffuse = torch.zeros(v, 25, 3)
    diffuse[:, 0] = 0.2
    if phong:
        mat = {"diffuse": [0.3, 0.3, 0.3], "model": "phong", "specular": 0.6, "exponent": 600.0}
    materials = scene.uniform(mat, v)
    if varying:
        x = mesh.vertices[:, 0]
        alpha = 0.005 * (0.3 / 0.005) ** ((x - x.min()) / (x.max() - x.min()))
        f0 = torch.stack([0.9 - 0.5 * (x > 0).float(), torch.full_like(x, 0.7), 0.3 + 0 * x], -1)
        materials = scene.Materials(materials.diffuse, brdf.GGXSchlick(alpha=alpha, f0=f0))
    m = Model(
        mesh, sphere.geodesic_views(), g, diffuse, materials, {"scene": "torus"},
        indirect_gaussians=int(indirect),
    )  # fmt: skip
    if phong:
        face, dist = m.hits()
        m._hits = (torch.full_like(face, -1), torch.zeros_like(dist))
    return m


@needs_browser
@pytest.mark.parametrize(
    ("sun", "indirect", "varying", "phong"),
    [
        (False, False, False, False),
        (True, True, False, False),
        (True, False, True, False),
        (True, False, False, True),
    ],
)
def test_a_sharp_metal_is_shaded_per_pixel_as_the_torch_path(
    browser, tmp_path, sun, indirect, varying, phong
):
    """A sharp metal's per-pixel reflection (reflection.glsl: visibility tiles, the object seen
    in the lobe through the hit tiles and the vertex stage's capture; with the sun, its shape
    through the whole map's chain, which this sun's disc resolves for the mixture's sharpest
    Gaussian; with an indirect Gaussian, the capture's indirect lobes) against
    ``Renderer(..., backend="torch")`` on 400 sampled interior pixels of the torus, at
    384 x 288 as the Gaussian path's test above (whose docstring gives the 1e-2 bound).

    A sharp reflection is discontinuous across the image (the hit tiles' texels switch between
    the object and the sky, the sky's horizon is mirrored sharply), and SwiftShader's 1/16-pixel
    vertex snapping moves each shading point by up to 1/32 pixel: a pixel beside such a step
    differs by a fraction of the step. So: at most 1 % of the pixels over 1e-2 (measured 0.2 %
    without the sun, 0.3 % with it, over all 85K interior pixels), and each pixel within 1e-2
    plus the reference's largest change to a 4-neighbour (the step it sits beside; the desktop
    shader on llvmpipe, which snaps to 1/256, meets 1e-2 without it). With the sun, the shadow
    map's penumbrae differ from the torch path's rays as the desktop shader's do (up to 0.05,
    tests/test_sun.py): one pixel in 400 may exceed the neighbour bound (measured 3 in 85K).
    A glTF lobe varying per vertex (``lobe`` and ``split`` in the model file, the page's
    ``lobe_at``) is held to the same bounds, and so is a Phong lobe with hit tiles that find
    nothing (the shaders' loops over its one live Gaussian, the hits' code left out)."""
    m = sharp_torus(indirect, varying, phong)
    # the built-in sky at 256 x 128: its sun's disc (spread 0.0095 rad) is resolved by the
    # mixture's sharpest Gaussian (lam sigma^2 >= SUN_RESOLVED), so whole_atlas is read
    lighting = render.Lighting(envmap.builtin(height=128), base_res=32, sun=sun)
    info = web.export_web(m, tmp_path / "v", [lighting])
    assert not info["notes"]
    folder = web.read_web(tmp_path / "v")
    # (the Phong lobe's sharpest live Gaussian does not resolve the disc)
    assert ("whole_atlas" in folder.envs[0][1]) == (sun and not phong)
    assert ("lobe" in folder.arrays) == varying
    page = open_page(browser, tmp_path / "v")
    assert not page.locator("#notes").is_visible()
    cam = render.Camera.look_at((0.0, 2.2, 2.6), (0.0, 0.0, 0.0), fov=45)
    w, h, rotation = 4 * W, 4 * H, 40.0
    img = render_in_page(page, cam, rotation, size=(w, h))
    assert page.evaluate("window.lobelight.viewer.gl.getError()") == 0
    page.close()
    px = interior(interior(img[..., 3] > 0.5))  # the pixels and their neighbours inside
    px[[0, -1]] = False
    px[:, [0, -1]] = False
    assert int(px.sum()) > 4000
    rows, cols = np.nonzero(px)
    pick = torch.randperm(rows.size, generator=torch.Generator().manual_seed(3))[:400].numpy()
    rows, cols = rows[pick], cols[pick]
    tr = render.Renderer(m, lighting, w, h, backend="torch", samples=1)

    def torch_at(dy: int, dx: int) -> np.ndarray:
        at = torch.from_numpy(np.stack([rows + dy, cols + dx], -1))
        ref, hit = tr.render_pixels(cam, at, rotation)
        assert bool(hit.all())
        return ref.numpy()

    ref = torch_at(0, 0)
    scale = np.maximum(ref.max(-1), 1e-6)
    rel = np.abs(img[rows, cols, :3] - ref).max(-1) / scale
    step = np.max([np.abs(torch_at(dy, dx) - ref).max(-1) / scale for dy, dx in NEIGHBOURS], axis=0)
    assert float((rel > 1e-2).mean()) <= 0.01, float(rel.max())
    beyond = int((rel > 1e-2 + step).sum())
    assert beyond <= (1 if sun else 0), (beyond, float(rel.max()))


@needs_browser
def test_no_pre_pass_on_swiftshader_and_a_closed_surface_s_hidden_triangles_left_out(
    browser, tmp_path
):
    """SwiftShader shades every covered fragment before its depth test, so the page leaves
    its depth pre-pass out there unless the URL asks for one (``prepass=1``); and a closed
    surface wound outward (the header's ``closed``: watertight, consistently wound, positive
    volume) is drawn without its triangles seen from behind unless the URL asks for them
    (``cull=0``). From outside they lie behind others, so the picture is the same to the bit
    every way (one sample: the same front fragments, the same shading); were the wrong side
    left out, the torus's far inside would show. A torus with a hole cut in it is not closed,
    and keeps every triangle."""
    m = sharp_torus()
    lighting = render.Lighting(envmap.builtin(height=128), base_res=32, sun=True)
    web.export_web(m, tmp_path / "v", [lighting])
    assert web.read_web(tmp_path / "v").header["closed"] is True
    cam = render.Camera.look_at((0.0, 2.2, 2.6), (0.0, 0.0, 0.0), fov=45)
    images = []
    cases = (("still=1", False, True), ("still=1&prepass=1", True, True),
             ("still=1&cull=0", False, False))  # fmt: skip
    for query, prepass, cull in cases:
        page = open_page(browser, tmp_path / "v", query=query)
        assert "SwiftShader" in page.evaluate(
            "() => { const gl = window.lobelight.viewer.gl;"
            " const e = gl.getExtension('WEBGL_debug_renderer_info');"
            " return gl.getParameter(e.UNMASKED_RENDERER_WEBGL); }"
        )
        viewer = page.evaluate("[window.lobelight.viewer.prepass, window.lobelight.viewer.cull]")
        assert viewer == [prepass, cull]
        images.append(render_in_page(page, cam, 40.0))
        page.close()
    assert int((images[0][..., 3] > 0.5).sum()) > 1000
    for other in images[1:]:
        assert float(np.abs(other - images[0]).max()) == 0.0
    # a hole: the far side's inside shows through it, so no triangle may be left out
    mesh = m.mesh
    holed = scene.mesh_from_arrays(mesh.vertices.numpy(), mesh.faces[10:].numpy(), name="holed")
    h = Model(holed, m.views, m.gaussians, m.diffuse, scene.uniform(
        {"diffuse": [0.3, 0.3, 0.3], "model": "ggx", "alpha": 0.03, "specular": 0.9},
        holed.n_vertices), {"scene": "holed"})  # fmt: skip
    web.export_web(h, tmp_path / "h", [lighting])
    assert web.read_web(tmp_path / "h").header["closed"] is False
    page = open_page(browser, tmp_path / "h")
    assert page.evaluate("window.lobelight.viewer.cull") is False
    page.close()


#: The 4-neighbours of a pixel, (dy, dx).
NEIGHBOURS = ((0, 1), (0, -1), (1, 0), (-1, 0))


@needs_browser
def test_the_tile_atlas_fits_the_devices_largest_texture(browser, sky, tmp_path):
    """The page lays the vertices' 32 x 32 tiles out in rows of the desktop's 4096 texels
    (128 tiles), narrower on a device whose largest texture is smaller, and wider where the
    rows would not fit: 50K vertices at SwiftShader's 8192 take 196 tiles across (6,272
    texels) in 256 rows (8,192 texels), not 128 across in 391 rows (12,512 texels)."""
    web.export_web(analytic_model(1), tmp_path / "v", [sky], base_res=32)
    page = open_page(browser, tmp_path / "v")
    per_row = "a => window.lobelight._tilesPerRow(...a)"
    assert page.evaluate(per_row, [10_000, 32, 4096, 8192]) == 128
    assert page.evaluate(per_row, [50_000, 32, 4096, 8192]) == 196
    assert page.evaluate(per_row, [5_000, 32, 4096, 2048]) == 64
    assert page.evaluate(per_row, [50, 32, 4096, 8192]) == 50
    for nv, most in ((50_000, 8192), (60_000, 8192), (4_000, 2048)):
        p = page.evaluate(per_row, [nv, 32, 4096, most])
        assert p * 32 <= most and -(-nv // p) * 32 <= most
    page.close()


def _page_and_torch(browser, m, folder, cam, size, *, diffuse, glossy):
    """``m`` exported under the built-in sky to ``folder`` and rendered at ``size`` squared by
    the page's test hook and by the torch path, with the given parts: (got, want), (H, W, 3)."""
    lighting = render.Lighting(envmap.builtin(height=64), base_res=16)
    web.export_web(m, folder, [lighting])
    page = open_page(browser, folder)
    got = render_in_page(page, cam, 0.0, size=(size, size), diffuse=diffuse, glossy=glossy)
    page.close()
    r = render.Renderer(m, lighting, size, size, backend="torch", samples=1)
    want = r.render(cam, diffuse=diffuse, glossy=glossy, background=False).numpy()
    return got[..., :3], want


@needs_browser
def test_the_page_reads_albedo_textures_as_the_torch_path(browser, tmp_path):
    """A bilinear, repeating checker texture under a UV transform, magnified
    (tests/test_albedo_texture.py's): the page's texture array and ``albedo.glsl`` against the
    torch path's sampler, by the desktop shader's bound: half-float texels and the rasteriser's
    UVs against the rays' (the bilinear weights move with them), 1 % of the brightest cell."""
    size, cam = checker.SIZE, checker.CAMERA
    p = tmp_path / "checker.glb"
    checker._checker_glb(p, mag_filter=9729)
    sc = scene.load(str(p))
    sc.albedo.transform = torch.tensor([[[1.5, 0.0, 0.25], [0.0, 1.5, -0.1]]] * 2)
    sc.albedo.wrap = torch.tensor([[0, 0], [2, 1]])
    m = fit.fit_model(sc, 1, indirect_paths=0, bounces=0, progress=None)
    got, want = _page_and_torch(browser, m, tmp_path / "v", cam, size, diffuse=True, glossy=False)
    inner = np.isfinite(checker._pixel_uv()).all(-1)
    d = np.abs(got - want)[inner]
    assert d.max() < 0.01 * want[inner].max()


@needs_browser
def test_the_page_reads_the_specular_colour_per_texel_as_the_torch_path(browser, tmp_path):
    """A quad half metal, half dielectric by its metallic texture (tests/test_albedo_texture.py's
    logo): the page's glossy light with the F0 texture array against the torch path's, and the
    jump across the metal's edge, the texels' F0 ratio (per-vertex F0 gives none). Half-float
    texels and the rasteriser's UVs against the rays' move a pixel's bilinear blend by a
    fraction of the jump near the edge, so away from it 1 % of the brightest glossy pixel."""
    size, cam = checker.SIZE, checker.CAMERA
    p = tmp_path / "logo.glb"
    checker._logo_glb(p)
    m = fit.fit_model(scene.load(str(p)), 1, indirect_paths=0, bounces=0, progress=None)
    got, want = _page_and_torch(browser, m, tmp_path / "v", cam, size, diffuse=False, glossy=True)
    u = checker._pixel_uv()[..., 0]
    away = np.isfinite(u) & (np.abs(u - 0.5) > 0.05)
    d = np.abs(got - want)[away]
    assert d.max() < 0.01 * want[away].max()
    # the jump across the edge: the two texels' F0 ratio (test_albedo_texture's bound, 5 %)
    row = size // 2
    left = int(np.nanargmax(np.where(u[row] < 0.5, u[row], np.nan)))
    f0 = m.albedo.specular_at(checker.LOGO_CORNERS, checker.LOGO_BARY).double().numpy()
    np.testing.assert_allclose(got[row, left + 1] / got[row, left], f0[1] / f0[0], rtol=0.05)


@needs_browser
@pytest.mark.parametrize(
    ("hide", "says"),
    [
        ("c === 'webgl2' ? null : get.call(this, c, o)", "no WebGL 2"),
        (None, "lacks EXT_color_buffer_float"),
    ],
)
def test_a_browser_without_webgl2_or_float_targets_gets_a_clear_message(
    browser, sky, tmp_path, hide, says
):
    # the browser's WebGL made to lack what the page needs, before the page's scripts run
    web.export_web(analytic_model(1), tmp_path / "v", [sky], base_res=16)
    page = browser.new_page()
    if hide is not None:
        page.add_init_script(
            "{ const get = HTMLCanvasElement.prototype.getContext;"
            f" HTMLCanvasElement.prototype.getContext = function (c, o) {{ return {hide}; }}; }}"
        )
    else:
        page.add_init_script(
            "{ const ext = WebGL2RenderingContext.prototype.getExtension;"
            " WebGL2RenderingContext.prototype.getExtension = function (n) {"
            " return n === 'EXT_color_buffer_float' ? null : ext.call(this, n); }; }"
        )
    page.goto(f"file://{tmp_path / 'v'}/index.html?still=1")
    page.wait_for_function("window.lobelight && window.lobelight.ready")
    page.evaluate("window.lobelight.ready")
    status = page.evaluate("window.lobelight.status")
    assert not status["ok"] and says in status["message"]
    assert page.locator("#message").is_visible()
    page.close()


@needs_browser
def test_the_page_corrects_a_rough_lobe_cut_by_the_object_as_the_torch_path(
    browser, tmp_path, monkeypatch
):
    """A metal box corner whose analytic Gaussians ignore the walls (tests/
    test_lobe_visibility.py): the page's correction (its tiles' atlas, the transform feedback
    pass) against the torch path's on sampled interior pixels, 1e-2 relative as above; the
    correction changes those pixels by far more."""
    from test_lobe_visibility import _corner_model, _map

    m = _corner_model()
    lighting = render.Lighting(_map(), base_res=64)
    web.export_web(m, tmp_path / "v", [lighting])
    assert web.read_web(tmp_path / "v").header["lobe_visibility"]["vis_res"] == 32
    page = open_page(browser, tmp_path / "v")
    cam = render.Camera.look_at((1.9, 1.3, 2.1), (0.3, 0.2, 0.3), fov=40)
    w, h = 4 * W, 4 * H
    img = render_in_page(page, cam, 0.0, size=(w, h))
    page.close()
    px = interior(img[..., 3] > 0.5)
    rows, cols = np.nonzero(px)
    pick = torch.randperm(rows.size, generator=torch.Generator().manual_seed(3))[:400].numpy()
    at = torch.from_numpy(np.stack([rows[pick], cols[pick]], -1))
    with render.Renderer(m, lighting, w, h, backend="torch", samples=1) as tr:
        ref, hit = tr.render_pixels(cam, at)
        monkeypatch.setattr(render._torch, "lobe_visibility_applies", lambda model: False)
        plain, _ = tr.render_pixels(cam, at)
    assert bool(hit.all())
    got, ref = img[rows[pick], cols[pick], :3], ref.numpy()
    rel = np.abs(got - ref).max(-1) / np.maximum(ref.max(-1), 1e-6)
    assert float(rel.max()) <= 1e-2, float(rel.max())
    change = np.abs(plain.numpy() - ref).max(-1) / np.maximum(ref.max(-1), 1e-6)
    assert float(change.max()) > 0.2, float(change.max())
