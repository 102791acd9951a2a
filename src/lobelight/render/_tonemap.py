"""Display transforms and image files: linear radiance in, 8-bit sRGB or float files out."""

from __future__ import annotations

import math
import os
from pathlib import Path

import cv2
import numpy as np
import OpenEXR
import torch
from PIL import Image

from .._io import atomic_path
from ..errors import InputError

__all__ = ["auto_exposure", "check_output_path", "save_image", "tonemap"]

CURVES = ("srgb", "aces")
#: Floor of a pixel's luminance in :func:`auto_exposure`'s log-average (Reinhard's delta):
#: black pixels count as very dark instead of sending the average to zero.
_LUMINANCE_FLOOR = 1e-6
#: Floor of that average before the exposure's division: finite stops for any image.
_AVERAGE_FLOOR = 1e-9


def _np(img) -> np.ndarray:
    if isinstance(img, torch.Tensor):
        img = img.detach().cpu().numpy()
    return np.asarray(img, dtype=np.float32)


def auto_exposure(img, mask=None, *, key: float = 0.18) -> float:
    """Exposure (stops) mapping the log-average luminance of ``img`` (or its masked pixels) to
    ``key`` (Reinhard's photographic key; 0.18 is mid grey)."""
    x = _np(img)
    lum = 0.2126 * x[..., 0] + 0.7152 * x[..., 1] + 0.0722 * x[..., 2]
    if mask is not None:
        lum = lum[_np(mask) > 0.5]
    lum = lum[np.isfinite(lum)]
    if lum.size == 0:
        return 0.0
    avg = float(np.exp(np.mean(np.log(np.maximum(lum, _LUMINANCE_FLOOR)))))
    return math.log2(key / max(avg, _AVERAGE_FLOOR))


def tonemap(img, *, exposure: float = 0.0, curve: str = "srgb") -> np.ndarray:
    """``(H, W, 3)`` linear radiance to ``(H, W, 3)`` uint8 sRGB.

    Parameters
    ----------
    exposure : stops (the image is scaled by ``2**exposure``)
    curve : ``"srgb"`` (clip, then the sRGB transfer function) or ``"aces"`` (Narkowicz's fit
        of the ACES filmic curve, then sRGB), as ``shaders/tonemap.glsl``
    """
    if curve not in CURVES:
        raise InputError("curve", f"must be one of {CURVES}, got {curve!r}")
    x = np.clip(_np(img) * np.float32(2.0**exposure), 0, None)
    if curve == "aces":
        x = np.clip(x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14), 0, 1)
    x = np.clip(x, 0, 1)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return (np.clip(s, 0, 1) * 255 + 0.5).astype(np.uint8)


#: Image types :func:`save_image` writes: tone-mapped 8-bit, and linear float.
DISPLAY_TYPES = (".png", ".jpg", ".jpeg")
LINEAR_TYPES = (".exr", ".hdr")
#: JPEG quality (Pillow's scale, 1..95): no visible loss on renders
JPEG_QUALITY = 95


def check_type(path, types: tuple[str, ...]) -> Path:
    """``path`` as a Path if its extension is one of ``types`` (case-insensitive), else an
    :class:`InputError` naming it and the types."""
    p = Path(path)
    ext = p.suffix.lower()
    if ext not in types:
        kind = ext or "(none)"
        raise InputError(str(p), f"unsupported image type {kind!r}: use {', '.join(types)}")
    return p


def check_output_path(path, *, types: tuple[str, ...] = DISPLAY_TYPES + LINEAR_TYPES) -> Path:
    """``path`` as a Path if an image can be written there, else an :class:`InputError` naming
    it: its extension is one of ``types`` (case-insensitive), it is not a directory, and its
    directory exists and is writable. Nothing is written; callers check before rendering."""
    p = check_type(path, types)
    if p.is_dir():
        raise InputError(str(p), "is a directory, not an image file name")
    parent = p.parent
    if not parent.is_dir():
        raise InputError(str(p), f"the directory {str(parent)!r} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(str(p), f"the directory {str(parent)!r} is not writable")
    return p


def save_image(path, img, *, exposure: float = 0.0, curve: str = "srgb") -> Path:
    """Write ``(H, W, 3)`` radiance atomically: ``.png`` and ``.jpg``/``.jpeg`` (quality 95)
    tone-mapped (:func:`tonemap`), ``.exr`` (float32, ZIP) and ``.hdr`` linear.

    The path is checked first (:func:`check_output_path`); returns it as a Path.
    """
    p = check_output_path(path)
    ext = p.suffix.lower()
    if curve not in CURVES:
        raise InputError("curve", f"must be one of {CURVES}, got {curve!r}")
    x = _np(img)
    if x.ndim != 3 or x.shape[-1] != 3:
        raise InputError("image", f"expected (H, W, 3), got {x.shape}")

    def write(tmp: str) -> None:
        if ext in DISPLAY_TYPES:
            im = Image.fromarray(tonemap(x, exposure=exposure, curve=curve))
            if ext == ".png":
                im.save(tmp, format="PNG")
            else:
                im.save(tmp, format="JPEG", quality=JPEG_QUALITY)
        elif ext == ".hdr":
            ok, enc = cv2.imencode(".hdr", np.ascontiguousarray(x[..., ::-1]))
            if not ok:
                raise InputError(str(p), "OpenCV could not encode the image")
            Path(tmp).write_bytes(enc.tobytes())
        else:
            header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
            OpenEXR.File(header, {"RGB": np.ascontiguousarray(x)}).write(tmp)

    with atomic_path(p) as tmp:
        write(str(tmp))
    return p
