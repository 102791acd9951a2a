"""A model file's albedo textures (:class:`lobelight.scene.AlbedoTexture`): the arrays that
hold them, their checks on read and before a write, and the texture built from them.

``albedo_uv``         (V, 2) float32 UVs
``albedo_layer``      (V,) int32 image layer of each vertex (0: the white texel)
``albedo_factor``     (V, 3) float32 per-vertex factor
``albedo_texels``     (T, 3) uint8 sRGB-encoded RGB: every layer's image, row-major, one
                      after the other
``albedo_sizes``      (L, 2) int32 each layer's height and width (their products sum to T)
``albedo_wrap``       (L, 2) uint8 wrap codes (:data:`lobelight.scene.WRAP_MODES`)
``albedo_transform``  (L, 2, 3) float32 UV transforms
``albedo_nearest``    (L,) bool read at the nearest texel
``albedo_specular``   optional, (T, 3) uint8 sRGB-encoded: each layer's F0 image
                      (:attr:`lobelight.scene.AlbedoTexture.specular`), laid out as the texels

The arrays come all together (``albedo_specular`` optional) or not at all; with them, the
file's diffuse transfer is per unit albedo (:attr:`lobelight.model.Model.albedo`).
"""

from __future__ import annotations

import numpy as np
import torch

from ..errors import InputError
from ..scene import AlbedoTexture

__all__ = ["ALBEDO_ARRAYS", "ALBEDO_DTYPES", "albedo_arrays", "check_albedo", "read_albedo"]

_F32 = (np.dtype(np.float32),)
#: The albedo arrays and the dtype each must have.
ALBEDO_DTYPES = {
    "albedo_uv": (_F32, "float32"),
    "albedo_layer": ((np.dtype(np.int32),), "int32"),
    "albedo_factor": (_F32, "float32"),
    "albedo_texels": ((np.dtype(np.uint8),), "uint8"),
    "albedo_sizes": ((np.dtype(np.int32),), "int32"),
    "albedo_wrap": ((np.dtype(np.uint8),), "uint8"),
    "albedo_transform": (_F32, "float32"),
    "albedo_nearest": ((np.dtype(np.bool_),), "boolean"),
}
#: The arrays that come together.
_TOGETHER = tuple(ALBEDO_DTYPES)
#: The optional F0 images, with their dtype.
ALBEDO_DTYPES["albedo_specular"] = ((np.dtype(np.uint8),), "uint8")
#: Every albedo array a model file may hold.
ALBEDO_ARRAYS = tuple(ALBEDO_DTYPES)


def albedo_arrays(albedo: AlbedoTexture | None) -> dict[str, np.ndarray]:
    """The arrays of ``albedo`` as a model file holds them (none for None)."""
    if albedo is None:
        return {}
    sizes = np.array([img.shape[:2] for img in albedo.images], np.int32)
    texels = torch.cat([img.reshape(-1, 3) for img in albedo.images]).cpu().numpy()
    out = {}
    if albedo.specular is not None:
        spec = torch.cat([img.reshape(-1, 3) for img in albedo.specular]).cpu().numpy()
        out["albedo_specular"] = np.ascontiguousarray(spec, np.uint8)
    return out | {
        "albedo_uv": albedo.uvs.detach().cpu().numpy().astype(np.float32),
        "albedo_layer": albedo.layer.cpu().numpy().astype(np.int32),
        "albedo_factor": albedo.factor.detach().cpu().numpy().astype(np.float32),
        "albedo_texels": np.ascontiguousarray(texels, np.uint8),
        "albedo_sizes": sizes,
        "albedo_wrap": albedo.wrap.cpu().numpy().astype(np.uint8),
        "albedo_transform": albedo.transform.cpu().numpy().astype(np.float32),
        "albedo_nearest": albedo.nearest.cpu().numpy().astype(np.bool_),
    }


def _need(cond: bool, name: str, problem: str) -> None:
    if not cond:
        raise InputError(name, problem)


def check_albedo(a: dict[str, np.ndarray], v: int, name: str) -> None:
    """The albedo arrays of a model of ``v`` vertices (module docstring), if it holds them:
    all or none, their shapes, the layers' sizes against the texels, the layer indices and
    wrap codes in range, the floats finite. Allocates nothing beyond the arrays."""
    held = [k for k in _TOGETHER if k in a]
    if not held:
        _need("albedo_specular" not in a, name, "albedo_specular comes with the albedo arrays")
        return
    missing = [k for k in _TOGETHER if k not in a]
    _need(not missing, name, f"albedo arrays come together; the file lacks {missing}")
    sizes = a["albedo_sizes"]
    n = int(sizes.shape[0]) if sizes.ndim == 2 else -1
    shapes = {
        "albedo_uv": (v, 2),
        "albedo_layer": (v,),
        "albedo_factor": (v, 3),
        "albedo_sizes": (n, 2),
        "albedo_wrap": (n, 2),
        "albedo_transform": (n, 2, 3),
        "albedo_nearest": (n,),
    }
    _need(n >= 1, name, f"albedo_sizes must be (L, 2) with L >= 1, got {sizes.shape}")
    for k, want in shapes.items():
        _need(a[k].shape == want, name, f"{k} must have shape {want}, got {a[k].shape}")
    _need(bool((sizes >= 1).all()), name, "albedo_sizes holds a layer without texels")
    texels = a["albedo_texels"]
    count = int(np.prod(sizes.astype(np.int64), axis=1).sum())
    want = (count, 3)
    _need(texels.shape == want, name,
          f"albedo_texels must be {want} for its layers' sizes, got {texels.shape}")  # fmt: skip
    if "albedo_specular" in a:
        spec = a["albedo_specular"].shape
        _need(spec == want, name, f"albedo_specular must be {want} as the texels, got {spec}")
    layer = a["albedo_layer"]
    _need(layer.size == 0 or (int(layer.min()) >= 0 and int(layer.max()) < n), name,
          f"albedo_layer holds layers outside 0..{n - 1}")  # fmt: skip
    _need(int(a["albedo_wrap"].max()) <= 2, name, "albedo_wrap holds codes outside 0..2")
    for k in ("albedo_uv", "albedo_factor", "albedo_transform"):
        _need(bool(np.isfinite(a[k]).all()), name, f"{k} has NaN or Inf values")


def read_albedo(a: dict[str, np.ndarray]) -> AlbedoTexture | None:
    """The albedo texture of checked arrays (:func:`check_albedo`), None where they hold
    none."""
    if "albedo_uv" not in a:
        return None
    sizes = a["albedo_sizes"].astype(np.int64)
    ends = np.cumsum(np.prod(sizes, axis=1))

    def split(texels: torch.Tensor) -> tuple[torch.Tensor, ...]:
        return tuple(
            texels[end - h * w : end].reshape(int(h), int(w), 3)
            for (h, w), end in zip(sizes, ends, strict=True)
        )

    images = split(torch.from_numpy(a["albedo_texels"].copy()))
    spec = a.get("albedo_specular")
    specular = None if spec is None else split(torch.from_numpy(spec.copy()))
    return AlbedoTexture(
        uvs=torch.from_numpy(a["albedo_uv"].copy()),
        layer=torch.from_numpy(a["albedo_layer"].astype(np.int64)),
        factor=torch.from_numpy(a["albedo_factor"].copy()),
        images=images,
        wrap=torch.from_numpy(a["albedo_wrap"].astype(np.int64)),
        transform=torch.from_numpy(a["albedo_transform"].copy()),
        nearest=torch.from_numpy(a["albedo_nearest"].copy()),
        specular=specular,
    )
