"""Animated example: a moving light and a moving occluder, soft shadows by cosine lobes.

The scene of :func:`lobelight.cosine.default_scene` (a plane and a torus approximated by 64
spheres): the light circles the torus while the torus turns and bobs, so the shadow's shape,
size and softness change from frame to frame. Each frame is a G-buffer (plane analytically, the
mesh by Embree) shaded by :func:`lobelight.cosine.shade_points`; frames are written as PNGs
(linear radiance, one fixed exposure for the whole sequence, sRGB), plus an animated GIF and the
paper's Figure 16 false-colour image of the number of table products per pixel for the first
frame. Every file is written under a temporary name and renamed (nothing half-written is left).
"""

from __future__ import annotations

import math
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from PIL import Image

from .._io import atomic_path
from .._tol import SMALL
from ..cosine import (
    FLAT_ROTATION,
    SphereLight,
    default_scene,
    gbuffer,
    get_tables,
    rotation_about_y,
    shade_points,
)
from ..errors import InputError

__all__ = ["false_colour", "lobes_demo"]


def _srgb(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    y = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return (y * 255 + 0.5).astype(np.uint8)


def false_colour(values: np.ndarray, vmax: float | None = None) -> np.ndarray:
    """``(H, W)`` counts to ``(H, W, 3)`` uint8: black (0) -> blue -> green -> yellow -> red."""
    vmax = float(values.max()) if vmax is None else float(vmax)
    t = np.clip(values / max(vmax, SMALL), 0, 1)
    stops = np.array([[0, 0, 0], [0, 0, 1.0], [0, 0.8, 0.2], [1.0, 0.9, 0], [1.0, 0, 0]])
    pos = t * (len(stops) - 1)
    i = np.minimum(pos.astype(int), len(stops) - 2)
    f = (pos - i)[..., None]
    rgb = (1 - f) * stops[i] + f * stops[i + 1]
    return (rgb * 255 + 0.5).astype(np.uint8)


def _save_png(img: np.ndarray, path: Path) -> None:
    with atomic_path(path) as tmp:
        Image.fromarray(img).save(tmp, format="PNG")


def lobes_demo(
    out: str | os.PathLike,
    *,
    frames: int = 24,
    size: int = 256,
    device: Any = "cpu",
    depth: int = 5,
    threshold: float = 1e-3,
    fused: bool = False,
    progress=None,
) -> dict:
    """Render ``frames`` frames of ``size x size`` into the folder ``out``.

    ``fused`` shades with the compiled kernels (:func:`lobelight.cosine.shade_points`'
    ``fused``): worth their compile time, once per process, for long sequences or large
    frames. ``progress(stage, done, total)``, optional, follows the tables' build (the first
    run on a machine) and the frames.

    Returns
    -------
    dict: ``frames`` (PNG paths), ``gif`` (path or None), ``products`` (false-colour PNG),
    ``seconds_per_frame`` (shading only, and with the G-buffer), ``products_per_point_mean``
    """
    if int(frames) < 1:
        raise InputError("frames", f"must be >= 1, got {frames!r}")
    if int(size) < 8:
        raise InputError("size", f"must be >= 8, got {size!r}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    get_tables(device=device, progress=progress)  # built once per machine, then read
    base = default_scene()
    light0 = base.lights[0]
    paths, images, shade_s, total_s, prods = [], [], [], [], []
    exposure = None
    bg = np.array([0.05, 0.05, 0.06])
    product_img = None
    for f in range(int(frames)):
        t0 = time.perf_counter()
        a = 2 * math.pi * f / frames
        light = SphereLight(
            (2.2 * math.cos(a + 0.6), 3.0 + 0.4 * math.sin(2 * a), 2.2 * math.sin(a + 0.6)),
            light0.radius,
            light0.radiance,
        )
        rot = rotation_about_y(0.5 * a) @ rotation_about_x(0.35 * math.sin(a)) @ FLAT_ROTATION
        scene = base.moved(
            rotation=rot,
            translation=[0.5 * math.sin(a), 0.8 + 0.35 * math.sin(a), 0.0],
            lights=[light],
        )
        gb = gbuffer(scene, size, size, device=device)
        t1 = time.perf_counter()
        res = shade_points(
            gb["points"],
            gb["normals"],
            gb["wo"],
            gb["brdf"],
            scene.lights,
            spheres=scene.world_spheres(),
            depth=depth,
            threshold=threshold,
            device=device,
            fused=fused,
            threads=1,  # a second thread contends where other processes share the cores
        )
        t2 = time.perf_counter()
        H, W = gb["shape"]
        img = np.tile(bg, (H * W, 1))
        rad = res.radiance.double().cpu().numpy()
        if exposure is None:
            exposure = 0.85 / max(float(np.percentile(rad.max(-1), 99.5)), 1e-6)
        img[gb["pixel"].cpu().numpy()] = rad * exposure
        png = _srgb(img.reshape(H, W, 3))
        path = out / f"frame_{f:03d}.png"
        _save_png(png, path)
        paths.append(str(path))
        images.append(png)
        prods.append(float(res.products.float().mean()))
        if product_img is None:
            counts = np.zeros(H * W)
            counts[gb["pixel"].cpu().numpy()] = res.products.cpu().numpy()
            product_img = out / "products_frame_000.png"
            _save_png(false_colour(counts.reshape(H, W)), product_img)
        shade_s.append(t2 - t1)
        if progress is not None:
            progress("frames", f + 1, int(frames))
        total_s.append(time.perf_counter() - t0)
    gif = None
    try:
        gif = out / "lobes.gif"
        frames_pil = [Image.fromarray(im) for im in images]
        with atomic_path(gif) as tmp:
            frames_pil[0].save(
                tmp, format="GIF", save_all=True, append_images=frames_pil[1:], duration=80, loop=0
            )
        gif = str(gif)
    except (ImportError, OSError, ValueError):  # pragma: no cover - Pillow without GIF support
        gif = None
    return {
        "frames": paths,
        "gif": gif,
        "products": str(product_img),
        "size": [int(size), int(size)],
        "seconds_per_frame_shading": float(np.mean(shade_s)),
        "seconds_per_frame_total": float(np.mean(total_s)),
        "products_per_point_mean": float(np.mean(prods)),
        "device": str(device),
    }


def rotation_about_x(angle: float) -> torch.Tensor:
    """(3, 3) rotation by ``angle`` radians about +X."""
    c, s = math.cos(angle), math.sin(angle)
    return torch.tensor([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
