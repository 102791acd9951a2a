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
from ..errors import InputError, os_problem

__all__ = [
    "CURVES",
    "CURVE_WHITE",
    "DEFAULT_CURVE",
    "HIGHLIGHT_MAX_STOPS",
    "auto_exposure",
    "check_output_path",
    "neutral",
    "save_image",
    "tonemap",
]

#: Display curves, by the name :func:`tonemap` takes; a curve's index is its code in
#: ``shaders/tonemap.glsl`` (the ``curve`` uniform).
CURVES = ("srgb", "aces", "neutral")
#: The display curve where none is named: Khronos PBR Neutral, which keeps saturated colours.
DEFAULT_CURVE = "neutral"
#: Floor of a pixel's luminance in :func:`auto_exposure`'s log-average (Reinhard's delta):
#: black pixels count as very dark instead of sending the average to zero.
_LUMINANCE_FLOOR = 1e-6
#: Floor of that average before the exposure's division: finite stops for any image.
_AVERAGE_FLOOR = 1e-9
#: Khronos PBR Neutral's constants: F90 (a dielectric's reflectance at normal incidence, the
#: toe's offset), Ks (where the highlights' compression starts) and Kd (its desaturation speed).
NEUTRAL_F90 = 0.04
NEUTRAL_KS = 0.8 - NEUTRAL_F90
NEUTRAL_KD = 0.15
#: The share of the object's pixels whose brightest channel :func:`auto_exposure` keeps at or
#: below the curve's white (:data:`CURVE_WHITE`).
HIGHLIGHT_QUANTILE = 0.99
#: The most :func:`auto_exposure`'s highlight rule lowers the log-average's exposure (stops): a
#: mirror's reflected lights and sun can be more than the quantile's share of its pixels, and
#: following them darkens the rest of the object.
HIGHLIGHT_MAX_STOPS = 1.0
#: Each curve's white: the linear grey it shows at 95 % of display white (sRGB: 0.95, where
#: clipping is still ahead; ACES: 2.863; Neutral: 1.712, where a channel at that level is mixed
#: less than 10 % towards grey-white: ``1 - 1 / (Kd (p - p_n) + 1)`` with ``p_n = 0.95``).
CURVE_WHITE = {"srgb": 0.95, "aces": 2.863, "neutral": 1.712}


def _np(img) -> np.ndarray:
    if isinstance(img, torch.Tensor):
        img = img.detach().cpu().numpy()
    return np.asarray(img, dtype=np.float32)


def _check_curve(curve) -> str:
    if curve not in CURVES:
        raise InputError("curve", f"must be one of {CURVES}, got {curve!r}")
    return curve


def auto_exposure(
    img, mask=None, *, key: float = 0.18, curve: str | None = None, quantile=HIGHLIGHT_QUANTILE
) -> float:
    """Exposure (stops) for ``img`` ``(H, W, 3)`` linear radiance (or its pixels where ``mask``
    ``(H, W)`` is set).

    The log-average luminance goes to ``key`` (Reinhard's photographic key; 0.18 is mid grey).
    With a display ``curve`` named, the exposure is the lower of that and the one that puts the
    ``quantile`` of the pixels' brightest channel (``max(r, g, b)``) at the curve's white
    (:data:`CURVE_WHITE`), but at most :data:`HIGHLIGHT_MAX_STOPS` below the log-average's:
    where the log-average would push the highlights past the curve's shoulder (clipped or
    bleached), they lower it. ``curve=None`` is the log-average alone (the scores' display
    exposure).
    """
    if curve is not None:
        _check_curve(curve)
    x = _np(img).reshape(-1, 3) if mask is None else _np(img)[_np(mask) > 0.5]  # (N, 3)
    x = x[np.isfinite(x).all(axis=-1)]
    if x.shape[0] == 0:
        return 0.0
    lum = 0.2126 * x[:, 0] + 0.7152 * x[:, 1] + 0.0722 * x[:, 2]
    avg = float(np.exp(np.mean(np.log(np.maximum(lum, _LUMINANCE_FLOOR)))))
    stops = math.log2(key / max(avg, _AVERAGE_FLOOR))
    if curve is not None:
        high = float(np.quantile(np.max(x, axis=-1), quantile))
        cap = math.log2(CURVE_WHITE[curve] / max(high, _AVERAGE_FLOOR))
        stops = max(stops - HIGHLIGHT_MAX_STOPS, min(stops, cap))
    return stops


def neutral(x):
    """Khronos PBR Neutral: ``(..., 3)`` non-negative linear Rec. 709 to ``(..., 3)`` in [0, 1],
    numpy or torch (the type and dtype of ``x``); ``shaders/tonemap.glsl``'s ``neutral`` is the
    same.

    The Khronos Group's specification (``KhronosGroup/ToneMapping``, ``PBR_Neutral/README.md``):
    with ``F90 = 0.04``, ``Ks = 0.8 - F90``, ``Kd = 0.15`` and ``m = min(r, g, b)``, the offset
    ``f = m - m^2 / (4 F90)`` for ``m <= 2 F90``, else ``F90``; ``c = x - f``;
    ``p = max(c)``; ``p_n = 1 - (1 - Ks)^2 / (p + 1 - 2 Ks)``; ``g = 1 / (Kd (p - p_n) + 1)``;
    the output is ``c`` where ``p <= Ks``, else ``c (p_n / p) g + p_n (1 - g)``: below the
    shoulder colours pass unchanged (less the toe's offset), above it the brightest channel is
    compressed towards 1 with the hue kept and a desaturation that grows with the compression.
    """
    lib = torch if isinstance(x, torch.Tensor) else np
    m = x.min(-1, keepdims=True) if lib is np else x.amin(-1, keepdim=True)  # (..., 1)
    f = lib.where(m < 2 * NEUTRAL_F90, m - m * m / (4 * NEUTRAL_F90), NEUTRAL_F90 + 0 * m)
    c = x - f  # (..., 3)
    p = c.max(-1, keepdims=True) if lib is np else c.amax(-1, keepdim=True)  # (..., 1)
    d = 1 - NEUTRAL_KS
    pn = 1 - d * d / (p + d - NEUTRAL_KS)
    g = 1 / (NEUTRAL_KD * (p - pn) + 1)
    safe = lib.where(p > NEUTRAL_KS, p, NEUTRAL_KS + 0 * p)  # no division by a dark peak
    out = c * (pn / safe) * g + pn * (1 - g)
    return lib.where(p <= NEUTRAL_KS, c, out)


def tonemap(img, *, exposure: float = 0.0, curve: str = DEFAULT_CURVE) -> np.ndarray:
    """``(H, W, 3)`` linear radiance to ``(H, W, 3)`` uint8 sRGB.

    Parameters
    ----------
    exposure : stops (the image is scaled by ``2**exposure``)
    curve : ``"neutral"`` (Khronos PBR Neutral, :func:`neutral`), ``"srgb"`` (clip) or
        ``"aces"`` (Narkowicz's fit of the ACES filmic curve, per channel), then the sRGB
        transfer function; ``shaders/tonemap.glsl`` is the same
    """
    _check_curve(curve)
    x = np.clip(_np(img) * np.float32(2.0**exposure), 0, None)
    if curve == "aces":
        x = x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14)
    elif curve == "neutral":
        x = neutral(x)
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
    try:
        if str(path).endswith(("/", os.sep)) or p.is_dir():
            raise InputError(str(path), "is a directory, not an image file name")
        parent = p.parent
        if not parent.is_dir():
            raise InputError(str(p), f"the directory {str(parent)!r} does not exist")
        if not os.access(parent, os.W_OK | os.X_OK):
            raise InputError(str(p), f"the directory {str(parent)!r} is not writable")
    except OSError as e:  # a name too long, a loop of links: the system's reason
        raise InputError(str(p), os_problem(e)) from None
    return p


def save_image(path, img, *, exposure: float = 0.0, curve: str = DEFAULT_CURVE) -> Path:
    """Write ``(H, W, 3)`` radiance atomically: ``.png`` and ``.jpg``/``.jpeg`` (quality 95)
    tone-mapped (:func:`tonemap`), ``.exr`` (float32, ZIP) and ``.hdr`` linear.

    The path is checked first (:func:`check_output_path`); returns it as a Path.
    """
    p = check_output_path(path)
    ext = p.suffix.lower()
    _check_curve(curve)
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
