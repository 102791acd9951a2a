"""Reading and writing environment maps: Radiance ``.hdr`` and OpenEXR ``.exr``.

Formats. ``.hdr`` files are Radiance RGBE (run-length encoded or flat), decoded by OpenCV
(``cv2``) and written by it (RLE). ``.exr`` files are read and written with the ``OpenEXR``
package (channels ``R``, ``G``, ``B``, or a single ``Y`` used for all three; any alpha is
ignored; only the first part of a multi-part file is read). Files are written as float32 (or
half with ``half=True``), ZIP-compressed, scanline EXR. The Radiance ``EXPOSURE`` header is
ignored, as Mitsuba and OpenCV ignore it (a warning is logged when it is not 1).

Layouts in a file, told apart by the image's aspect ratio unless ``layout=`` says:

- ``2:1`` — ``"latlong"``: Mitsuba 3's lat-long orientation (:mod:`lobelight.envmap._envmap`;
  row 0 is the zenith, column 0 looks along -Z, a quarter of the way along +X).
- ``3:4`` — ``"vcross"``, vertical cross of faces of ``n = W/3`` pixels (HDRShop / Debevec)::

        .  +Y  .
       -X  -Z  +X
        .  -Y  .
        .  +Z  .        (+Z, the back, appears rotated by 180 degrees)

- ``4:3`` — ``"hcross"``, horizontal cross, ``n = W/4``::

        .  +Y  .   .
       -X  -Z  +X  +Z
        .  -Y  .   .

- ``6:1`` — ``"strip"``: the GL faces +X, -X, +Y, -Y, +Z, -Z left to right, each exactly as
  stored in a :mod:`lobelight.geometry.cubemap` (rows = t, columns = s).

In the crosses each face is what a viewer at the centre sees with the cube unfolded around the
front face -Z (up +Y, right +X): the pixel at face coordinates ``(a, b)`` in ``[-1, 1]`` (``a``
to the right, ``b`` down, pixel centres at ``(2 k + 1)/n - 1``) looks along
``centre + a * right + b * down`` with::

    face  centre  right  down   (vcross; hcross differs only in +Z: right -X, down -Y)
    +Y    +Y      +X     -Z
    -X    -X      -Z     -Y
    -Z    -Z      +X     -Y
    +X    +X      +Z     -Y
    -Y    -Y      +X     +Z
    +Z    +Z      +X     +Y

so neighbouring pixels across every drawn edge of a cross look in neighbouring directions. A
cross converts to the GL cube layout without resampling: each GL texel is one cross pixel,
found from its direction (:func:`cross_pixels`). Unused areas of a cross are ignored on loading
and written black.

Checks at the door. Every problem is one :class:`~lobelight.errors.InputError` naming the file:
missing file, directory, empty file, unsupported extension, content that is not the format
its extension says (text, PNG, random bytes), a truncated or corrupt file, an aspect ratio that
names no layout, and NaN, infinite or negative radiance. OpenCV 5 rejects truncated RGBE data,
but OpenCV 4 ignores the decoder's error and returns a partly filled image, so the RLE stream is
walked here first (:func:`_rgbe_complete_scanlines`) and a short file is reported with the
scanline where it ends. With ``sanitize=True``, NaN and negative values become 0 and +Inf the
largest finite value in the image, with a logged warning that gives the counts.

Writing is atomic: the file is written under a temporary name in the same directory and then
renamed over ``path`` (``os.replace``), so an interrupted save never leaves a half-written file.
"""

from __future__ import annotations

import logging
import math
import re
from pathlib import Path

import cv2
import numpy as np
import OpenEXR
import torch

from .._io import IMAGE_LIMIT, read_input
from ..errors import InputError
from ._envmap import EnvMap, describe_bad_values
from ._files import _EXTENSIONS, _GRID, CROSS_FACES, FILE_LAYOUTS, cross_pixels, save
from ._library_output import library_output

# the layouts and save live in _files (EnvMap.save calls it there without an import circle)
__all__ = ["CROSS_FACES", "FILE_LAYOUTS", "cross_pixels", "load", "save"]

logger = logging.getLogger(__name__)

# -- loading ---------------------------------------------------------------------------------


def load(path: str | Path, *, layout: str | None = None, sanitize: bool = False) -> EnvMap:
    """Read an environment map from a ``.hdr`` or ``.exr`` file.

    Parameters
    ----------
    path : file path
    layout : ``None`` (from the aspect ratio: 2:1, 3:4, 4:3, 6:1), ``"cubemap"`` (any of the
        cube layouts, from the aspect ratio), or one of ``"latlong"`` (any size), ``"vcross"``,
        ``"hcross"``, ``"strip"``; see the module docstring for their conventions
    sanitize : replace NaN and negative values by 0 and +Inf by the largest finite value (with
        a logged warning) instead of refusing the file

    Returns
    -------
    EnvMap named by the path, layout ``"latlong"`` or ``"cubemap"``, on the CPU.

    Raises
    ------
    InputError
        Naming the file, for every problem listed in the module docstring.
    """
    p = Path(path)
    name = str(path)
    if layout is not None and layout not in (*FILE_LAYOUTS, "cubemap"):
        raise InputError(
            "layout", f"must be None, 'cubemap' or one of {FILE_LAYOUTS}, got {layout!r}"
        )
    ext = p.suffix.lower()
    if not p.exists():
        raise InputError(name, "no such file")
    if p.is_dir():
        raise InputError(name, "is a directory, not an image file")
    if ext not in _EXTENSIONS:
        raise InputError(
            name, f"unsupported file type {ext or '(no extension)'!r}: lobelight reads .hdr, .exr"
        )
    buf = read_input(p, limit=IMAGE_LIMIT)
    if not buf:
        raise InputError(name, "the file is empty")
    img = _read_hdr(buf, name) if ext == ".hdr" else _read_exr(p, buf, name)  # (H, W, 3) f32

    h, w = img.shape[:2]
    kind = _file_layout(h, w, layout, name)
    if kind != "latlong":
        n = w // _GRID[kind][1]
        rows, cols = cross_pixels(kind, n)
        used = np.zeros((h, w), bool)
        used[rows.numpy(), cols.numpy()] = True
        img = np.where(used[..., None], img, np.float32(0))  # unused cross areas do not count
    img = _check_values(img, name, sanitize=sanitize)
    if kind == "latlong":
        return EnvMap(img, layout="latlong", name=name)
    cube = img[rows.numpy(), cols.numpy()]  # (6, n, n, 3)
    return EnvMap(cube, layout="cubemap", name=name)


def _file_layout(h: int, w: int, layout: str | None, name: str) -> str:
    if layout == "latlong":
        return "latlong"
    if layout in _GRID:
        gr, gc = _GRID[layout]
        if w % gc or h * gc != w * gr:
            raise InputError(
                name, f"a {layout} image must be {gc}n x {gr}n pixels (W x H), got {w} x {h}"
            )
        return layout
    fits = [k for k, (gr, gc) in _GRID.items() if w % gc == 0 and h * gc == w * gr]
    if layout is None and w == 2 * h:
        return "latlong"
    if fits:
        return fits[0]
    want = "3:4 vertical cross, 4:3 horizontal cross or 6:1 strip"
    if layout is None:
        want = "2:1 lat-long, " + want
    raise InputError(
        name,
        f"cannot tell the layout of a {w} x {h} image: expected a {want} "
        "(from Python, lobelight.envmap.load(path, layout='latlong') reads a lat-long map of "
        "another size)",
    )


#: The largest radiance a map may hold: a calibrated sun is about 1e9, and sums and squares of
#: 1e15 over any map stay finite in float32 (an RGBE file of 0xFF bytes decodes to 1.7e38).
MAX_RADIANCE = 1e15


def _check_values(img: np.ndarray, name: str, *, sanitize: bool) -> np.ndarray:
    """Refuse, or with ``sanitize`` repair, NaN / Inf / negative radiance; refuse radiance over
    :data:`MAX_RADIANCE`. ``(H, W, 3)``."""
    problem = describe_bad_values(torch.from_numpy(img))
    if problem is None:
        top = float(img.max()) if img.size else 0.0
        if top > MAX_RADIANCE:
            raise InputError(name, f"radiance up to {top:.3g}, over {MAX_RADIANCE:g}: not a map")
        return img
    if not sanitize:
        raise InputError(
            name,
            problem + " (from Python, lobelight.envmap.load(path, sanitize=True) repairs them)",
        )
    nan = np.isnan(img)
    neg = img < 0  # includes -Inf
    pinf = np.isposinf(img)
    finite = img[np.isfinite(img)]
    top = float(finite.max()) if finite.size else 0.0
    out = np.where(nan | neg, np.float32(0), img)
    out = np.where(pinf, np.float32(max(top, 0.0)), out).astype(np.float32)
    logger.warning(
        "%s: sanitized %d NaN and %d negative values to 0 and clamped %d +Inf values to %g",
        name,
        int(nan.sum()),
        int(neg.sum()),
        int(pinf.sum()),
        max(top, 0.0),
    )
    return out


def _sniff(buf: bytes) -> str:
    """Name of a known format from its first bytes, for messages."""
    if buf.startswith(b"\x76\x2f\x31\x01"):
        return "an OpenEXR file"
    if buf.startswith(b"#?"):
        return "a Radiance HDR file"
    if buf.startswith(b"\x89PNG"):
        return "a PNG image"
    if buf.startswith(b"\xff\xd8\xff"):
        return "a JPEG image"
    head = buf[:512]
    if head and all(32 <= c < 127 or c in b"\t\r\n" for c in head):
        return "a text file"
    return "not an image format lobelight knows"


# -- Radiance RGBE ---------------------------------------------------------------------------

_RES_LINE = re.compile(rb"^([-+][XY]) (\d+) ([-+][XY]) (\d+)$")


def _read_hdr(buf: bytes, name: str) -> np.ndarray:
    """Decode a Radiance RGBE file's bytes to ``(H, W, 3)`` float32 RGB, checking everything."""
    if not buf.startswith(b"#?"):
        raise InputError(name, f"not a Radiance HDR file (it is {_sniff(buf)})")
    end = buf.find(b"\n\n", 0, 1 << 16)  # the header ends with an empty line
    if end < 0:
        raise InputError(name, "corrupt Radiance header (no end of header in the first 64 KiB)")
    header = buf[:end].decode("latin-1").split("\n")
    for line in header[1:]:
        if line.startswith("FORMAT=") and line.strip() != "FORMAT=32-bit_rle_rgbe":
            raise InputError(name, f"unsupported Radiance pixel format {line.strip()!r}")
        if line.startswith("EXPOSURE="):
            try:
                exposure = float(line.split("=", 1)[1])
            except ValueError:
                exposure = 1.0
            if not math.isclose(exposure, 1.0, rel_tol=1e-6):
                logger.warning("%s: ignoring EXPOSURE=%g (as Mitsuba does)", name, exposure)
    nl = buf.find(b"\n", end + 2)
    res_line = buf[end + 2 : nl if nl >= 0 else len(buf)].strip()
    m = _RES_LINE.match(res_line)
    if nl < 0 or not m:
        raise InputError(name, "corrupt Radiance header (no resolution line like '-Y 512 +X 1024')")
    if (m.group(1), m.group(3)) != (b"-Y", b"+X"):
        raise InputError(
            name, f"unsupported Radiance pixel order {res_line.decode()!r} (only '-Y H +X W')"
        )
    h, w = int(m.group(2)), int(m.group(4))
    if h == 0 or w == 0:
        raise InputError(name, f"the image is empty ({w} x {h})")
    done = _rgbe_complete_scanlines(buf, nl + 1, h, w)
    if done < h:
        raise InputError(
            name, f"truncated or corrupt RGBE data: scanline {done + 1} of {h} is incomplete"
        )
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)  # we report errors
    try:
        img = cv2.imdecode(np.frombuffer(buf, np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error as e:
        raise InputError(name, f"OpenCV cannot decode the RGBE data ({e})") from e
    finally:
        cv2.utils.logging.setLogLevel(level)
    if img is None or img.shape != (h, w, 3) or img.dtype != np.float32:
        raise InputError(name, "OpenCV cannot decode the RGBE data")
    return np.ascontiguousarray(img[..., ::-1])  # BGR -> RGB


def _rgbe_complete_scanlines(buf: bytes, pos: int, h: int, w: int) -> int:
    """Number of complete scanlines in RGBE data starting at ``pos`` (``h`` when whole).

    Follows the decoder of Radiance / OpenCV (``RGBE_ReadPixels_RLE``): widths outside
    ``[8, 32767]`` are flat; otherwise a scanline starts with ``2 2 hi lo`` (``hi lo`` = width)
    and holds four channels of runs (``128 + n`` then one byte, or ``n`` then ``n`` bytes); a
    scanline without that start means the rest of the image is flat 4-byte pixels. The walk is
    sequential by nature (a run's length is in the data), one Python step per run.
    """
    n = len(buf)
    if w < 8 or w > 0x7FFF:
        return min(h, (n - pos) // (4 * w))
    for y in range(h):
        if pos + 4 > n:
            return y
        if buf[pos] != 2 or buf[pos + 1] != 2 or buf[pos + 2] & 0x80:
            return min(h, y + (n - pos) // (4 * w))  # not RLE: flat from here on
        if (buf[pos + 2] << 8) | buf[pos + 3] != w:
            return y  # wrong scanline width: corrupt
        pos += 4
        for _ in range(4):
            k = 0
            while k < w:
                if pos >= n:
                    return y
                t = buf[pos]
                if t > 128:
                    k += t - 128
                    pos += 2
                elif t == 0:
                    return y  # a zero-length run is invalid
                else:
                    k += t
                    pos += 1 + t
            if k != w or pos > n:
                return y
    return h


# -- OpenEXR ---------------------------------------------------------------------------------


def _read_exr(p: Path, buf: bytes, name: str) -> np.ndarray:
    """Read an OpenEXR file to ``(H, W, 3)`` float32 RGB."""
    if not buf.startswith(b"\x76\x2f\x31\x01"):
        raise InputError(name, f"not an OpenEXR file (it is {_sniff(buf)})")
    # OpenEXR prints its own warnings on stdout and stderr: they become part of our one line
    problem = None
    with library_output() as said:
        try:
            f = OpenEXR.File(str(p), separate_channels=True)
            parts = f.parts
            chans = parts[0].channels if parts else None
        except Exception as e:
            problem = str(e)
    if problem is not None or chans is None:
        detail = "; ".join([problem or "no image could be read", *said[:2]])
        raise InputError(name, f"truncated or corrupt OpenEXR file ({detail})")
    if said:
        logger.warning("%s: OpenEXR: %s", name, "; ".join(said[:2]))
    names = sorted(chans)
    if all(c in chans for c in "RGB"):
        planes = [chans[c].pixels for c in "RGB"]
    elif "Y" in chans:
        planes = [chans["Y"].pixels] * 3
    else:
        raise InputError(name, f"no R, G, B (or Y) channels in the OpenEXR file; it has {names}")
    if any(pl is None or pl.ndim != 2 or pl.shape != planes[0].shape for pl in planes):
        raise InputError(name, "the OpenEXR channels are subsampled or of different sizes")
    return np.stack([np.asarray(pl, dtype=np.float32) for pl in planes], -1)
