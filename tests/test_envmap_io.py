"""Environment map files: formats, cross layouts, atomic saving, and every kind of bad file.

Each bad input must give one InputError whose message names the file (never a crash inside
numpy, OpenCV or OpenEXR), and a failed save must leave nothing behind.
"""

from __future__ import annotations

import logging
import math
import os

import cv2
import numpy as np
import OpenEXR
import pytest
import torch

from conftest import REAL_ENVMAPS
from lobelight.envmap import _io
from lobelight.envmap._envmap import EnvMap
from lobelight.envmap._io import CROSS_FACES, cross_pixels, load, save
from lobelight.errors import InputError
from lobelight.geometry import cubemap

# RGBE stores an 8-bit mantissa per channel with the exponent of the largest channel, and
# OpenCV truncates: a channel is off by less than 2^-7 of the pixel's largest channel.
RGBE_TOL = 2.0**-7


def _rgbe_close(got: torch.Tensor, want: torch.Tensor) -> None:
    bound = RGBE_TOL * want.amax(-1, keepdim=True) + 1e-30
    assert bool(((got - want).abs() <= bound).all()), float(((got - want).abs() / bound).max())


def _write_exr(path, channels: dict) -> None:
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, channels).write(str(path))


def _random_latlong(h=16, w=32, seed=0) -> EnvMap:
    rng = np.random.default_rng(seed)
    return EnvMap(rng.uniform(0.01, 50.0, (h, w, 3)).astype(np.float32), layout="latlong")


def _random_cube(n=5, seed=0) -> EnvMap:
    rng = np.random.default_rng(seed)
    return EnvMap(rng.uniform(0.01, 50.0, (6, n, n, 3)).astype(np.float32), layout="cubemap")


# -- real files -----------------------------------------------------------------------------
# The package's bundled maps (written by OpenCV, RLE), and files made here by an RGBE writer of
# our own that follows the Radiance format description, not OpenCV's code.


@pytest.mark.parametrize("path", REAL_ENVMAPS, ids=lambda p: p.name)
def test_real_hdr_loads_as_opencv_decodes_it(path):
    env = load(path)
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)[..., ::-1]
    assert env.layout == "latlong" and env.name == str(path)
    assert env.data.shape == raw.shape and env.data.dtype == torch.float32
    np.testing.assert_array_equal(env.data.numpy(), raw)


def _rgbe_start(buf: bytes, h: int, w: int) -> int:
    return buf.index(f"-Y {h} +X {w}\n".encode()) + len(f"-Y {h} +X {w}\n")


def test_rgbe_walk_consumes_real_files_exactly():
    # the truncation check follows the RLE stream to the last byte of every real file
    for path in REAL_ENVMAPS:
        buf = path.read_bytes()
        env = load(path)
        h, w = env.resolution
        start = _rgbe_start(buf, h, w)
        assert buf[start : start + 2] == b"\x02\x02"  # run-length encoded scanlines
        assert _io._rgbe_complete_scanlines(buf, start, h, w) == h
        assert _io._rgbe_complete_scanlines(buf[:-1], start, h, w) == h - 1


def _rle_channel(row: np.ndarray) -> bytes:
    """One channel of a scanline in the Radiance RLE scheme: a byte ``128 + n`` then the value
    for a run of ``n <= 127`` equal bytes, or ``n <= 128`` then ``n`` literal bytes. Greedy
    (runs of 3 or more), unlike OpenCV's writer (which takes runs of 4 or more)."""
    out = bytearray()
    lit: list[int] = []
    k, w = 0, len(row)
    while k < w:
        r = 1
        while k + r < w and r < 127 and row[k + r] == row[k]:
            r += 1
        if r >= 3:
            while lit:
                out += bytes([len(lit[:128]), *lit[:128]])
                lit = lit[128:]
            out += bytes([128 + r, int(row[k])])
            k += r
        else:
            lit += [int(v) for v in row[k : k + r]]
            k += r
    while lit:
        out += bytes([len(lit[:128]), *lit[:128]])
        lit = lit[128:]
    return bytes(out)


def _rgbe_file(rgbe: np.ndarray, *, rle: bool) -> bytes:
    """A Radiance file of ``(H, W, 4)`` uint8 RGBE pixels: RLE scanlines or flat pixels."""
    h, w, _ = rgbe.shape
    head = b"#?RADIANCE\n# written by the lobelight tests\nFORMAT=32-bit_rle_rgbe\n\n"
    body = bytearray(f"-Y {h} +X {w}\n".encode())
    for y in range(h):
        if rle:
            body += bytes([2, 2, w >> 8, w & 0xFF])
            for c in range(4):
                body += _rle_channel(rgbe[y, :, c])
        else:
            body += rgbe[y].tobytes()
    return head + bytes(body)


def _rgbe_pixels(h: int, w: int, seed: int) -> np.ndarray:
    """RGBE pixels with long runs (longer than one run byte holds), noise (longer than one
    literal byte holds), black (exponent 0) and a very bright spot."""
    rng = np.random.default_rng(seed)
    px = np.empty((h, w, 4), np.uint8)
    px[..., :3] = rng.integers(128, 256, (h, w, 3))  # normalised mantissas
    px[..., 3] = rng.integers(120, 140, (h, w))
    if w > 200:
        px[:, :200] = (200, 150, 130, 128)  # a run of 200: 127 + 73
    px[1, :] = 0  # a black scanline
    px[2, w // 2] = (255, 250, 240, 150)  # ~2^14: a sun
    return px


def _rgbe_decoded(px: np.ndarray) -> np.ndarray:
    """RGBE to float32 as the Radiance format defines it: ``m 2^(e - 136)``, 0 where e = 0."""
    scale = np.where(px[..., 3] > 0, np.ldexp(1.0, px[..., 3].astype(np.int64) - 136), 0.0)
    return (px[..., :3] * scale[..., None]).astype(np.float32)


@pytest.mark.parametrize(("w", "rle"), [(330, True), (6, False)])
def test_hdr_from_another_writer(tmp_path, w, rle):
    # RLE scanlines (widths 8..32767) and flat pixels (narrower maps are never run-length
    # encoded), written here: the loader must give the format's values exactly
    h = w // 2
    px = _rgbe_pixels(h, w, seed=w)
    buf = _rgbe_file(px, rle=rle)
    path = tmp_path / "other.hdr"
    path.write_bytes(buf)
    env = load(path)
    np.testing.assert_array_equal(env.data.numpy(), _rgbe_decoded(px))
    start = _rgbe_start(buf, h, w)
    assert _io._rgbe_complete_scanlines(buf, start, h, w) == h
    assert _io._rgbe_complete_scanlines(buf[:-1], start, h, w) == h - 1
    # cut inside the last scanline: refused, naming the scanline
    path.write_bytes(buf[: len(buf) - 5])
    _expect_error(path, f"scanline {h} of {h}")


# -- round trips ----------------------------------------------------------------------------


def test_exr_round_trip_is_exact(tmp_path):
    env = _random_latlong()
    back = load(save(env, tmp_path / "a.exr"))
    assert back.layout == "latlong"
    torch.testing.assert_close(back.data, env.data, rtol=0, atol=0)
    cube = _random_cube(n=4)
    for cross in ["vcross", "hcross", "strip"]:
        back = load(save(cube, tmp_path / f"c_{cross}.exr", cross=cross))
        assert back.layout == "cubemap"
        torch.testing.assert_close(back.data, cube.data, rtol=0, atol=0)


def test_exr_half_round_trip(tmp_path):
    env = _random_latlong()
    back = load(save(env, tmp_path / "h.exr", half=True))
    # half floats keep 11 significant bits: relative error <= 2^-11
    torch.testing.assert_close(back.data, env.data, rtol=2.0**-11, atol=0)
    hot = EnvMap(torch.full((4, 8, 3), 1e5), layout="latlong")
    with pytest.raises(InputError, match="half"):
        save(hot, tmp_path / "hot.exr", half=True)
    assert not (tmp_path / "hot.exr").exists()


def test_hdr_round_trip_within_rgbe_precision(tmp_path):
    env = _random_latlong()
    _rgbe_close(load(save(env, tmp_path / "a.hdr")).data, env.data)
    cube = _random_cube(n=8)  # width 24 >= 8: written run-length encoded
    _rgbe_close(load(save(cube, tmp_path / "c.hdr")).data, cube.data)


# -- cross layouts --------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["vcross", "hcross", "strip"])
def test_cross_pixels_is_a_bijection(kind):
    n = 6
    rows, cols = cross_pixels(kind, n)
    gr, gc = _io._GRID[kind]
    flat = (rows * gc * n + cols).reshape(-1)
    assert flat.unique().numel() == 6 * n * n
    assert int(rows.max()) < gr * n and int(cols.max()) < gc * n


def _table_direction(kind: str, face: str, r: torch.Tensor, c: torch.Tensor, n: int):
    """Direction of cross pixel (r, c) within a face block, from the docstring's table."""
    _, _, centre, right, down = CROSS_FACES[kind][face]
    a = (2 * c.double() + 1) / n - 1
    b = (2 * r.double() + 1) / n - 1
    t = lambda v: torch.tensor(v, dtype=torch.float64)  # noqa: E731
    return t(centre) + a[..., None] * t(right) + b[..., None] * t(down)


@pytest.mark.parametrize("kind", ["vcross", "hcross"])
def test_cross_orientation(tmp_path, kind):
    """Every pixel of a saved cross equals the map's radiance in the direction the table gives.

    With n odd the centre pixel of each face block looks exactly along its axis: the centre
    pixel of the front face (-Z) equals radiance(0, 0, -1), and so on. Lookups at texel
    centres return the texel itself (bilinear weights 1) up to float32 rounding of the weights
    (~1e-7 times the contrast to a neighbour; values in [1, 2]: rtol 1e-5).
    """
    n = 5
    rng = np.random.default_rng(4)
    env = EnvMap(rng.uniform(1, 2, (6, n, n, 3)).astype(np.float32), layout="cubemap")
    save(env, tmp_path / "x.exr", cross=kind)
    img = torch.from_numpy(OpenEXR.File(str(tmp_path / "x.exr")).channels()["RGB"].pixels)
    r, c = torch.meshgrid(torch.arange(n), torch.arange(n), indexing="ij")
    for face, (brow, bcol, centre, _, _) in CROSS_FACES[kind].items():
        block = img[brow * n : (brow + 1) * n, bcol * n : (bcol + 1) * n]
        axis = torch.tensor(centre, dtype=torch.float32)
        torch.testing.assert_close(block[n // 2, n // 2], env.radiance(axis), rtol=1e-5, atol=0)
        d = _table_direction(kind, face, r, c, n).float()
        torch.testing.assert_close(block, env.radiance(d), rtol=1e-5, atol=0)
    # the unused areas are black
    used = torch.zeros(img.shape[:2], dtype=torch.bool)
    rows, cols = cross_pixels(kind, n)
    used[rows, cols] = True
    assert float(img[~used].abs().max()) == 0


@pytest.mark.parametrize("kind", ["vcross", "hcross"])
def test_cross_seams_are_continuous(kind):
    """Neighbouring pixels across every drawn edge of the cross look in neighbouring directions.

    Inside a face, neighbours are at most one texel apart (2/n in face coordinates, < 2/n
    radians); across an edge the same holds, while a wrongly rotated face would put them up
    to a face (90 degrees) apart. Bound: 2.5/n radians.
    """
    n = 8
    gr, gc = _io._GRID[kind]
    dirs = torch.full((gr * n, gc * n, 3), float("nan"), dtype=torch.float64)
    r, c = torch.meshgrid(torch.arange(n), torch.arange(n), indexing="ij")
    for face, (brow, bcol, *_rest) in CROSS_FACES[kind].items():
        d = torch.nn.functional.normalize(_table_direction(kind, face, r, c, n), dim=-1)
        dirs[brow * n : (brow + 1) * n, bcol * n : (bcol + 1) * n] = d
    for a, b in [(dirs[:, :-1], dirs[:, 1:]), (dirs[:-1], dirs[1:])]:
        cos = (a * b).sum(-1)
        both = ~torch.isnan(cos)
        angle = torch.acos(cos[both].clamp(-1, 1))
        assert float(angle.max()) < 2.5 / n
        assert int(both.sum()) > 0


def test_cross_matches_gl_faces():
    # the cross face of each axis and the GL face of that axis agree pixel for pixel in
    # direction: cross_pixels maps GL texel centres onto the pixel centres of the table
    n = 4
    dirs = cubemap.texel_directions(n, dtype=torch.float64)  # (6, n, n, 3)
    for kind in ["vcross", "hcross"]:
        rows, cols = cross_pixels(kind, n)
        for f, face in enumerate(cubemap.FACE_NAMES):
            brow, bcol, *_ = CROSS_FACES[kind][face]
            d = _table_direction(kind, face, rows[f] - brow * n, cols[f] - bcol * n, n)
            d = torch.nn.functional.normalize(d, dim=-1)
            torch.testing.assert_close(d, dirs[f])


def test_layout_detection_and_explicit_layout(tmp_path):
    env = _random_latlong(h=8, w=16)
    assert load(save(env, tmp_path / "ll.exr")).layout == "latlong"
    odd = _random_latlong(h=10, w=12)  # 6:5: no layout by aspect
    path = save(odd, tmp_path / "odd.exr")
    with pytest.raises(InputError, match=r"odd\.exr.*cannot tell the layout"):
        load(path)
    back = load(path, layout="latlong")
    torch.testing.assert_close(back.data, odd.data, rtol=0, atol=0)
    cube = _random_cube(n=3)
    path = save(cube, tmp_path / "v.exr", cross="vcross")
    torch.testing.assert_close(load(path, layout="cubemap").data, cube.data, rtol=0, atol=0)
    with pytest.raises(InputError, match=r"v\.exr.*hcross"):
        load(path, layout="hcross")
    with pytest.raises(InputError, match="layout"):
        load(path, layout="sphere")
    # a 4:3 image read as a horizontal cross
    path = save(cube, tmp_path / "h.exr", cross="hcross")
    torch.testing.assert_close(load(path).data, cube.data, rtol=0, atol=0)


def test_exr_luminance_and_alpha_channels(tmp_path):
    y = np.random.default_rng(1).uniform(0, 2, (8, 16)).astype(np.float32)
    _write_exr(tmp_path / "y.exr", {"Y": y})
    env = load(tmp_path / "y.exr")
    np.testing.assert_array_equal(env.data.numpy(), np.repeat(y[..., None], 3, -1))
    rgba = np.random.default_rng(2).uniform(0, 2, (8, 16, 4)).astype(np.float32)
    _write_exr(tmp_path / "rgba.exr", {"RGBA": rgba})
    np.testing.assert_array_equal(load(tmp_path / "rgba.exr").data.numpy(), rgba[..., :3])
    _write_exr(tmp_path / "z.exr", {"Z": y})
    with pytest.raises(InputError, match=r"z\.exr.*no R, G, B"):
        load(tmp_path / "z.exr")


# -- bad files ------------------------------------------------------------------------------


def _hdr_bytes(h=16, w=32) -> bytes:
    img = np.random.default_rng(0).uniform(0.1, 5, (h, w, 3)).astype(np.float32)
    ok, buf = cv2.imencode(".hdr", img)
    assert ok
    return buf.tobytes()


def _exr_bytes(tmp_path) -> bytes:
    save(_random_latlong(h=64, w=128), tmp_path / "src.exr")
    return (tmp_path / "src.exr").read_bytes()


def _png_bytes() -> bytes:
    ok, buf = cv2.imencode(".png", np.zeros((8, 16, 3), np.uint8))
    assert ok
    return buf.tobytes()


def _expect_error(path, *words: str) -> None:
    with pytest.raises(InputError) as e:
        load(path)
    msg = str(e.value)
    assert str(path) in msg, msg
    assert os.path.basename(path) in msg
    for w in words:
        assert w in msg, msg


def test_missing_directory_empty_and_unsupported(tmp_path):
    _expect_error(tmp_path / "nope.hdr", "no such file")
    (tmp_path / "dir.exr").mkdir()
    _expect_error(tmp_path / "dir.exr", "directory")
    for ext in [".hdr", ".exr"]:
        (tmp_path / f"empty{ext}").write_bytes(b"")
        _expect_error(tmp_path / f"empty{ext}", "empty")
    (tmp_path / "image.png").write_bytes(_png_bytes())
    _expect_error(tmp_path / "image.png", "unsupported file type '.png'")
    (tmp_path / "noext").write_bytes(b"x")
    _expect_error(tmp_path / "noext", "unsupported file type")


@pytest.mark.parametrize("ext", [".hdr", ".exr"])
def test_not_an_image(tmp_path, ext):
    (tmp_path / f"text{ext}").write_text("just some notes\nnot an image\n")
    _expect_error(tmp_path / f"text{ext}", "text file")
    (tmp_path / f"png{ext}").write_bytes(_png_bytes())
    _expect_error(tmp_path / f"png{ext}", "PNG")
    (tmp_path / f"noise{ext}").write_bytes(np.random.default_rng(0).bytes(5000))
    _expect_error(tmp_path / f"noise{ext}", "not an")


def test_exr_named_hdr_and_back(tmp_path):
    (tmp_path / "swapped.hdr").write_bytes(_exr_bytes(tmp_path))
    _expect_error(tmp_path / "swapped.hdr", "OpenEXR")
    (tmp_path / "swapped.exr").write_bytes(_hdr_bytes())
    _expect_error(tmp_path / "swapped.exr", "Radiance")


def _truncations(n: int) -> list[int]:
    return sorted({5, 30, n // 10, n // 2, (9 * n) // 10, n - 7, n - 1})


def test_truncated_hdr(tmp_path):
    """Truncated RGBE data is refused, never returned half black.

    OpenCV 5 returns None for it; OpenCV 4 returns a partly filled image without complaint, so
    lobelight walks the RLE stream itself: the walk must also catch every truncation.
    """
    buf = _hdr_bytes()
    header_end = buf.index(b"+X 32\n") + len(b"+X 32\n")
    for n in _truncations(len(buf)):
        path = tmp_path / f"cut{n}.hdr"
        path.write_bytes(buf[:n])
        _expect_error(path)
        if n > header_end:
            assert _io._rgbe_complete_scanlines(buf[:n], header_end, 16, 32) < 16
    assert _io._rgbe_complete_scanlines(buf, header_end, 16, 32) == 16


def test_truncated_real_hdr(tmp_path):
    src = REAL_ENVMAPS[0]
    h = load(src).resolution[0]
    buf = src.read_bytes()
    for n in [200, len(buf) // 2, len(buf) - 1]:
        path = tmp_path / f"real_cut{n}.hdr"
        path.write_bytes(buf[:n])
        _expect_error(path)
    # the scanline named in the message is where the data stops
    path = tmp_path / "real_half.hdr"
    path.write_bytes(buf[: len(buf) // 2])
    with pytest.raises(InputError, match=rf"scanline \d+ of {h}"):
        load(path)


def test_truncated_exr(tmp_path):
    buf = _exr_bytes(tmp_path)
    for n in _truncations(len(buf)):
        path = tmp_path / f"cut{n}.exr"
        path.write_bytes(buf[:n])
        _expect_error(path)


def test_truncated_real_exr(tmp_path):
    # a real map converted to EXR, then cut
    src = save(load(REAL_ENVMAPS[-1]), tmp_path / "real.exr")
    buf = src.read_bytes()
    for n in [len(buf) // 3, len(buf) - 10]:
        path = tmp_path / f"real_cut{n}.exr"
        path.write_bytes(buf[:n])
        _expect_error(path)


def test_corrupt_hdr_header(tmp_path):
    good = _hdr_bytes()
    cases = {
        "order": (good.replace(b"-Y 16 +X 32", b"+Y 16 +X 32"), "pixel order"),
        "xyze": (good.replace(b"32-bit_rle_rgbe", b"32-bit_rle_xyze"), "pixel format"),
        "nores": (good.split(b"\n\n")[0] + b"\n\nhello\n", "resolution"),
        "noend": (b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n", "end of header"),
    }
    for name, (data, words) in cases.items():
        (tmp_path / f"{name}.hdr").write_bytes(data)
        _expect_error(tmp_path / f"{name}.hdr", words)


def test_hdr_exposure_is_ignored_with_warning(tmp_path, caplog):
    good = _hdr_bytes()
    data = good.replace(b"FORMAT=", b"EXPOSURE=2.0\nFORMAT=", 1)
    (tmp_path / "exp.hdr").write_bytes(data)
    (tmp_path / "plain.hdr").write_bytes(good)
    with caplog.at_level(logging.WARNING, logger="lobelight.envmap._io"):
        env = load(tmp_path / "exp.hdr")
    assert "EXPOSURE" in caplog.text
    torch.testing.assert_close(env.data, load(tmp_path / "plain.hdr").data, rtol=0, atol=0)


def test_wrong_aspect_names_the_file(tmp_path):
    _write_exr(tmp_path / "wide.exr", {"RGB": np.ones((10, 37, 3), np.float32)})
    _expect_error(tmp_path / "wide.exr", "37 x 10")


def _bad_values_image() -> np.ndarray:
    img = np.ones((8, 16, 3), np.float32)
    img[1, 2, 0] = np.nan
    img[3, 4, 1] = np.inf
    img[5, 6, 2] = -2.0
    img[7, 8, :] = -np.inf
    return img


def test_bad_values_refused(tmp_path):
    _write_exr(tmp_path / "bad.exr", {"RGB": _bad_values_image()})
    _expect_error(
        tmp_path / "bad.exr", "3 pixels with NaN or Inf", "[1, 2]", "negative", "sanitize"
    )


def test_bad_values_sanitized(tmp_path, caplog):
    img = _bad_values_image()
    img[0, 0] = 7.0  # the largest finite value
    _write_exr(tmp_path / "bad.exr", {"RGB": img})
    with caplog.at_level(logging.WARNING, logger="lobelight.envmap._io"):
        env = load(tmp_path / "bad.exr", sanitize=True)
    assert "bad.exr" in caplog.text and "1 NaN" in caplog.text and "4 negative" in caplog.text
    assert "1 +Inf" in caplog.text
    data = env.data.numpy()
    assert data[1, 2, 0] == 0 and data[5, 6, 2] == 0 and (data[7, 8] == 0).all()
    assert data[3, 4, 1] == 7.0
    assert np.isfinite(data).all() and (data >= 0).all()


def test_bad_values_in_unused_cross_area_are_ignored(tmp_path):
    cube = _random_cube(n=3)
    path = save(cube, tmp_path / "v.exr")
    img = OpenEXR.File(str(path)).channels()["RGB"].pixels.copy()
    img[0, 0] = np.nan  # top-left block of a vertical cross is not a face
    _write_exr(path, {"RGB": img})
    torch.testing.assert_close(load(path).data, cube.data, rtol=0, atol=0)


# -- saving ---------------------------------------------------------------------------------


def test_save_is_atomic(tmp_path, monkeypatch):
    env = _random_latlong()
    path = save(env, tmp_path / "a.hdr")
    before = path.read_bytes()

    def broken(*args, **kwargs):
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(_io.cv2, "imencode", broken)
    with pytest.raises(InputError, match=r"a\.hdr"):
        save(_random_latlong(seed=1), path)
    assert path.read_bytes() == before  # the old file is untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.hdr"]  # no temporary left


def test_save_overwrites_and_leaves_no_temporaries(tmp_path):
    a, b = _random_latlong(seed=1), _random_latlong(seed=2)
    save(a, tmp_path / "m.exr")
    save(b, tmp_path / "m.exr")
    torch.testing.assert_close(load(tmp_path / "m.exr").data, b.data, rtol=0, atol=0)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.exr"]
    # EnvMap.save forwards here
    assert a.save(tmp_path / "n.exr") == tmp_path / "n.exr"


def test_save_refuses_bad_targets(tmp_path):
    env = _random_latlong()
    with pytest.raises(InputError, match="does not exist"):
        save(env, tmp_path / "missing" / "a.exr")
    with pytest.raises(InputError, match=r"a\.png.*unsupported"):
        save(env, tmp_path / "a.png")
    with pytest.raises(InputError, match="half"):
        save(env, tmp_path / "a.hdr", half=True)
    with pytest.raises(InputError, match="cross"):
        save(_random_cube(), tmp_path / "c.exr", cross="diagonal")
    (tmp_path / "d.exr").mkdir()
    with pytest.raises(InputError, match="directory"):
        save(env, tmp_path / "d.exr")


def test_saved_latlong_is_what_mitsuba_reads(tmp_path):
    # channel order: R stays R (a map that is red above and blue below)
    data = np.zeros((8, 16, 3), np.float32)
    data[:4, :, 0] = 1
    data[4:, :, 2] = 1
    path = save(EnvMap(data, layout="latlong"), tmp_path / "rb.exr")
    chans = OpenEXR.File(str(path), separate_channels=True).channels()
    assert chans["R"].pixels[0, 0] == 1 and chans["B"].pixels[-1, 0] == 1
    assert math.isclose(float(chans["B"].pixels[0, 0]), 0.0)
