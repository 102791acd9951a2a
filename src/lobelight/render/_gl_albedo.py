"""The shader path's albedo textures (``shaders/albedo.glsl``): a model's
:class:`lobelight.scene.AlbedoTexture` layers in one texture array, and the uniforms that say
how each layer is read."""

from __future__ import annotations

import numpy as np
import torch

from ..errors import InputError
from ..scene import srgb_decode

__all__ = ["MAX_ALBEDO_LAYERS", "MAX_ALBEDO_SIZE", "albedo_array", "albedo_uniforms"]

#: Texels across and down of the texture array's layers at most: a larger texture is
#: downsampled (area-averaged) to it. 2048^2 half-float RGB with its mips is 34 MB a layer.
MAX_ALBEDO_SIZE = 2048
#: Layers of the texture array at most (uniform arrays are sized by it).
MAX_ALBEDO_LAYERS = 64


def _layer_size(albedo) -> tuple[int, int]:
    """(width, height) every layer is resampled to: the largest of the layers', at most
    :data:`MAX_ALBEDO_SIZE` each."""
    w = max(int(img.shape[1]) for img in albedo.images)
    h = max(int(img.shape[0]) for img in albedo.images)
    return min(w, MAX_ALBEDO_SIZE), min(h, MAX_ALBEDO_SIZE)


def albedo_array(albedo, *, specular: bool = False) -> np.ndarray:
    """(L, H, W, 3) float16 linear RGB: every layer (``specular``: every layer's F0 image,
    :attr:`lobelight.scene.AlbedoTexture.specular`) decoded from sRGB and resampled to one size
    (:func:`_layer_size`): bilinearly, area-averaged where it shrinks, at the nearest texel for
    a layer read at its nearest texel; layers already of that size are copied exactly."""
    n = len(albedo.images)
    if n > MAX_ALBEDO_LAYERS:
        raise InputError("albedo", f"has {n} texture layers, at most {MAX_ALBEDO_LAYERS}")
    w, h = _layer_size(albedo)
    out = np.empty((n, h, w, 3), np.float16)
    for i, img in enumerate(albedo.specular if specular else albedo.images):
        lin = srgb_decode(img.float() / 255)  # (h_i, w_i, 3)
        if tuple(lin.shape[:2]) != (h, w):
            x = lin.permute(2, 0, 1)[None]
            if bool(albedo.nearest[i]):
                x = torch.nn.functional.interpolate(x, size=(h, w), mode="nearest-exact")
            else:
                shrink = x.shape[-1] > w or x.shape[-2] > h
                x = torch.nn.functional.interpolate(
                    x, size=(h, w), mode="bilinear", align_corners=False, antialias=shrink
                )
            lin = x[0].permute(1, 2, 0)
        out[i] = lin.clamp(0, 1).numpy().astype(np.float16)
    return out


def albedo_uniforms(albedo) -> dict[str, np.ndarray]:
    """The uniforms ``albedo.glsl`` reads: each layer's transform rows and its modes, and the
    layers' size."""
    w, h = _layer_size(albedo)
    xform = albedo.transform.detach().cpu().numpy().astype(np.float32).reshape(-1, 3)
    mode = np.concatenate(
        [albedo.wrap.cpu().numpy(), albedo.nearest.cpu().numpy()[:, None]], axis=1
    ).astype(np.float32)
    return {
        "albedo_xform": np.ascontiguousarray(xform),
        "albedo_mode": np.ascontiguousarray(mode),
        "albedo_size": np.array([w, h], np.float32),
    }
