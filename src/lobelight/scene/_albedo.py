"""Diffuse albedo per pixel: a glTF asset's base colour textures, read at each point's UV.

A mesh's per-vertex colours, interpolated across a triangle, cannot show a texture finer than
the triangle. :class:`AlbedoTexture` keeps what the renderers need to read the texture per
pixel instead: every vertex's UV, the image layer of its material and a per-vertex factor, so
that the diffuse albedo at a surface point of barycentrics ``b`` on corners ``c`` is

    albedo = (sum_i b_i factor[c_i]) * image[layer](sum_i b_i uv[c_i])

For a textured material (its base colour or metallic-roughness texture on ``TEXCOORD_0``) the
image is the diffuse part of glTF's model, ``base colour texture x (1 - metallicFactor x B)``
with ``B`` the metallic-roughness texture's blue channel, composed texel by texel, and the
factor is ``baseColorFactor x COLOR_0``: a metallic pattern (a painted logo on a metal) shows
per pixel as the colour does. Every other vertex reads layer 0, one white texel, with the
bake's own per-vertex diffuse albedo as its factor: such a vertex renders as it would without
textures.

The specular part's colour varies per texel too (a painted logo on a metal, a metallic
texture's pattern): where a layer's material is textured, :attr:`AlbedoTexture.specular` holds
its Fresnel reflectance at normal incidence composed texel by texel, glTF's
``F0 = 0.04 (1 - m) + baseColorFactor x base colour texture x m``, ``m = metallicFactor x B``
(``COLOR_0`` left out: it multiplies the base colour per vertex, and the sum does not factor).
The fitted glossy transport is the bake's, with the per-vertex F0 (the one-ring averages);
the renderers scale it per pixel by the texel's F0 over the interpolated vertices'
(:func:`lobelight.render` reads :meth:`AlbedoTexture.specular_at`): exact at normal incidence,
where Schlick's Fresnel term is F0 itself. The roughness stays per vertex.

The images are kept as the textures are stored, 8-bit sRGB-encoded RGB, and decoded to linear
values when they are read (the bilinear filter runs on linear values, as a GPU's sRGB textures
do).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..errors import InputError
from ._gltf import Texture, sample_texture, wrap_texels, wrap_uv

__all__ = ["WRAP_MODES", "AlbedoTexture", "albedo_texture", "srgb_decode", "srgb_encode"]

#: Wrap modes by code: the order of :attr:`AlbedoTexture.wrap`'s codes.
WRAP_MODES = ("repeat", "clamp", "mirror")


def srgb_decode(x: torch.Tensor) -> torch.Tensor:
    """sRGB-encoded values in [0, 1] to linear ones (the sRGB transfer function's inverse)."""
    return torch.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055).clamp_min(0) ** 2.4)


def srgb_encode(x: torch.Tensor) -> torch.Tensor:
    """Linear values in [0, 1] to sRGB-encoded ones."""
    x = x.clamp(0, 1)
    return torch.where(x <= 0.0031308, x * 12.92, 1.055 * x.clamp_min(1e-12) ** (1 / 2.4) - 0.055)


def _decode_table() -> torch.Tensor:
    """(256,) float32: the linear value of each 8-bit sRGB code."""
    return srgb_decode(torch.arange(256, dtype=torch.float64) / 255).float()


_DECODE = _decode_table()


@dataclass(eq=False)
class AlbedoTexture:
    """Per-vertex UVs, layers and factors, and the layers' images (module docstring).

    Attributes
    ----------
    uvs : (V, 2) float32 UVs (``TEXCOORD_0``; UV (0, 0) is an image's top-left corner)
    layer : (V,) int64 image layer of each vertex's material (0: one white texel)
    factor : (V, 3) float32 linear RGB factor
    images : L images, each (H_l, W_l, 3) uint8 sRGB-encoded RGB
    wrap : (L, 2) int64 wrap codes along U and V (:data:`WRAP_MODES`)
    transform : (L, 2, 3) float32 affine map applied to UVs before reading
        (``KHR_texture_transform``; the identity for none)
    nearest : (L,) bool: the layer is read at its nearest texel (the sampler's magnification
        filter), else bilinearly
    specular : None, or L images of each layer's F0 (module docstring), each of its layer's
        image's shape, uint8 sRGB-encoded RGB (layer 0's unused)
    """

    uvs: torch.Tensor
    layer: torch.Tensor
    factor: torch.Tensor
    images: tuple[torch.Tensor, ...]
    wrap: torch.Tensor
    transform: torch.Tensor
    nearest: torch.Tensor
    specular: tuple[torch.Tensor, ...] | None = None

    def __post_init__(self) -> None:
        v = int(self.uvs.shape[0])
        n = len(self.images)
        checks = (
            ("uvs", tuple(self.uvs.shape) == (v, 2), f"({v}, 2)"),
            ("layer", tuple(self.layer.shape) == (v,), f"({v},)"),
            ("factor", tuple(self.factor.shape) == (v, 3), f"({v}, 3)"),
            ("wrap", tuple(self.wrap.shape) == (n, 2), f"({n}, 2)"),
            ("transform", tuple(self.transform.shape) == (n, 2, 3), f"({n}, 2, 3)"),
            ("nearest", tuple(self.nearest.shape) == (n,), f"({n},)"),
        )
        for name, ok, want in checks:
            if not ok:
                got = tuple(getattr(self, name).shape)
                raise InputError(f"albedo {name}", f"expected shape {want}, got {got}")
        for i, img in enumerate(self.images):
            if img.dtype != torch.uint8 or img.ndim != 3 or img.shape[2] != 3 or 0 in img.shape:
                raise InputError(
                    f"albedo image {i}",
                    f"must be (H, W, 3) uint8, got {img.dtype} {tuple(img.shape)}",
                )
        if self.specular is not None and (
            len(self.specular) != n
            or any(
                sp.dtype != torch.uint8 or sp.shape != img.shape
                for sp, img in zip(self.specular, self.images, strict=True)
            )
        ):
            raise InputError("albedo specular", "must be one uint8 image per layer, of its shape")
        if v and (int(self.layer.min()) < 0 or int(self.layer.max()) >= n):
            raise InputError("albedo layer", f"holds layers outside 0..{n - 1}")
        if self.wrap.numel() and (int(self.wrap.min()) < 0 or int(self.wrap.max()) > 2):
            raise InputError("albedo wrap", "holds codes outside 0..2")
        for name in ("uvs", "factor", "transform"):
            if not bool(torch.isfinite(getattr(self, name)).all()):
                raise InputError(f"albedo {name}", "has NaN or Inf values")

    @property
    def n_vertices(self) -> int:
        return int(self.uvs.shape[0])

    def to(self, device) -> AlbedoTexture:
        """The per-vertex arrays on ``device`` (the images stay on the CPU, where they are
        uploaded from or read in batches)."""
        return AlbedoTexture(
            self.uvs.to(device),
            self.layer.to(device),
            self.factor.to(device),
            self.images,
            self.wrap,
            self.transform,
            self.nearest,
            self.specular,
        )

    def at(self, corners: torch.Tensor, bary: torch.Tensor) -> torch.Tensor:
        """The albedo at surface points: (P, 3) linear RGB.

        Parameters
        ----------
        corners : (P, 3) vertex ids of each point's triangle (its corners have one material);
        bary : (P, 3) barycentrics
        """
        dev = self.uvs.device
        c = corners.to(dev)
        b = bary.to(dev, torch.float32)[..., None]
        uv = (self.uvs[c] * b).sum(1)  # (P, 2)
        factor = (self.factor[c] * b).sum(1)  # (P, 3)
        layer = self.layer[c[:, 0]]
        out = torch.ones_like(factor)
        for i in torch.unique(layer).tolist():
            if i == 0:
                continue  # the white texel
            sel = layer == i
            out[sel] = self.sample(i, uv[sel])
        return factor * out

    def specular_at(self, corners: torch.Tensor, bary: torch.Tensor) -> torch.Tensor | None:
        """The F0 of textured points (corners and barycentrics as :meth:`at`'s): (P, 3) linear
        RGB, NaN where the point's layer is 0 (no texture: the per-vertex F0 holds); None
        without :attr:`specular`."""
        if self.specular is None:
            return None
        dev = self.uvs.device
        c = corners.to(dev)
        uv = (self.uvs[c] * bary.to(dev, torch.float32)[..., None]).sum(1)
        layer = self.layer[c[:, 0]]
        out = torch.full((c.shape[0], 3), float("nan"), device=dev)
        for i in torch.unique(layer).tolist():
            if i == 0:
                continue
            sel = layer == i
            out[sel] = self.sample(i, uv[sel], specular=True)
        return out

    def sample(self, i: int, uv: torch.Tensor, *, specular: bool = False) -> torch.Tensor:
        """Layer ``i`` at ``uv`` (P, 2): (P, 3) linear RGB, bilinear between texel centres (or
        the nearest texel), the layer's transform applied first and indices beyond the edges
        wrapped by its modes; ``specular``: of its F0 image."""
        img = (self.specular if specular else self.images)[i]
        h, w = int(img.shape[0]), int(img.shape[1])
        a = self.transform[i].to(uv)
        uv = uv @ a[:, :2].T + a[:, 2]
        ws, wt = (WRAP_MODES[int(m)] for m in self.wrap[i])
        x = wrap_uv(uv[:, 0], ws) * w - 0.5  # texel centres at integer + 0.5
        y = wrap_uv(uv[:, 1], wt) * h - 0.5
        table = _DECODE.to(uv.device)
        flat = img.to(uv.device).reshape(-1, 3).long()

        def texel(iy: torch.Tensor, ix: torch.Tensor) -> torch.Tensor:
            return table[flat[wrap_texels(iy, h, wt) * w + wrap_texels(ix, w, ws)]]

        if bool(self.nearest[i]):
            return texel(torch.floor(y + 0.5).long(), torch.floor(x + 0.5).long())
        x0, y0 = torch.floor(x), torch.floor(y)
        fx, fy = (x - x0)[:, None], (y - y0)[:, None]
        x0, y0 = x0.long(), y0.long()
        top = texel(y0, x0) * (1 - fx) + texel(y0, x0 + 1) * fx
        bottom = texel(y0 + 1, x0) * (1 - fx) + texel(y0 + 1, x0 + 1) * fx
        return top * (1 - fy) + bottom * fy


def _texel_uvs(tex: Texture) -> torch.Tensor | None:
    """(H, W, 2) the UVs that ``tex``'s transform takes to the centres of its texels (None
    where the transform is singular)."""
    h, w = int(tex.image.shape[0]), int(tex.image.shape[1])
    y, x = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    c = torch.stack([(x + 0.5) / w, (y + 0.5) / h], -1).double()
    if tex.uv_transform is None:
        return c
    a = torch.tensor(tex.uv_transform, dtype=torch.float64)
    if abs(float(torch.linalg.det(a[:, :2]))) < 1e-12:
        return None
    return (c - a[:, 2]) @ torch.linalg.inv(a[:, :2]).T


def _on_uv0(tex: Texture | None) -> Texture | None:
    return tex if tex is not None and tex.tex_coord == 0 else None


def _layer_of(mat) -> tuple | None:
    """A material's diffuse albedo texture as a layer, on the grid of its base colour texture
    (else of its metallic-roughness texture): ``base (1 - metallic)`` without the factors'
    base colour, composed texel by texel (the metallic-roughness texture read at the UVs of the
    grid's texel centres), re-encoded to 8-bit sRGB (an 8-bit base colour image without a
    metallic texture comes back to its own codes); its wrap codes, transform and filter, and
    whether the metallic part is in it (else the per-vertex metallic multiplies the factor);
    and the layer's F0 image (module docstring; with the metallic-roughness texture on another
    UV set, the factor's metallic). None where neither texture is on ``TEXCOORD_0``."""
    base, mr = _on_uv0(mat.base_color_texture), _on_uv0(mat.metallic_roughness_texture)
    grid = base if base is not None else mr
    if grid is None or (base is None and mat.base_color_texture is not None):
        return None  # the base colour is on another UV set: per vertex
    h, w = int(grid.image.shape[0]), int(grid.image.shape[1])
    rgb = torch.ones(h, w, 3, dtype=torch.float64)
    if base is not None:
        rgb = base.image[..., :3].detach().cpu().double()
    uv = None if mr is None else _texel_uvs(grid)
    with_metal = uv is not None or mat.metallic_roughness_texture is None
    m = torch.full((h, w), float(mat.metallic), dtype=torch.float64)
    if uv is not None:
        m = m * sample_texture(mr, uv.to(mr.image))[..., 2].cpu().double()
    diffuse = rgb * (1 - m)[..., None] if with_metal else rgb
    base_full = rgb * torch.tensor(mat.base_color[:3], dtype=torch.float64)
    f0 = 0.04 * (1 - m)[..., None] + base_full * m[..., None]
    img, spec = (
        torch.round(srgb_encode(x) * 255).to(torch.uint8).contiguous() for x in (diffuse, f0)
    )
    s = grid.sampler
    wrap = (WRAP_MODES.index(s.wrap_s), WRAP_MODES.index(s.wrap_t))
    xf = np.array(grid.uv_transform if grid.uv_transform is not None else _IDENTITY, np.float32)
    return img, wrap, xf, s.mag_filter == "nearest", with_metal, spec


_IDENTITY = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0))


def albedo_texture(asset, diffuse: torch.Tensor, metallic: torch.Tensor) -> AlbedoTexture | None:
    """The per-pixel albedo of a glTF asset (module docstring); None where no material has a
    base colour or metallic-roughness texture on ``TEXCOORD_0`` (the per-vertex albedo is then
    all there is).

    Parameters
    ----------
    asset : :class:`lobelight.scene.GltfAsset` (V vertices)
    diffuse : (V, 3) the bake's per-vertex diffuse albedo (the factor of untextured vertices)
    metallic : (V,) per-vertex metallic (for a layer whose metallic part is not in its image)
    """
    mats = asset.materials
    layers = [_layer_of(m) for m in mats]
    if all(x is None for x in layers):
        return None
    dev = asset.uvs.device
    images = [torch.full((1, 1, 3), 255, dtype=torch.uint8)]
    specular = [images[0]]
    wraps, xforms, nearest = [(0, 0)], [np.array(_IDENTITY, np.float32)], [False]
    of_material = torch.zeros(len(mats), dtype=torch.int64)
    metal_inside = torch.zeros(len(mats), dtype=torch.bool)
    for m, found in enumerate(layers):
        if found is not None:
            img, wrap, xf, near, with_metal, spec = found
            of_material[m] = len(images)
            metal_inside[m] = with_metal
            images.append(img)
            specular.append(spec)
            wraps.append(wrap)
            xforms.append(xf)
            nearest.append(near)
    layer = of_material.to(dev)[asset.material]
    base = torch.tensor([m.base_color[:3] for m in mats], dtype=torch.float32, device=dev)
    inside = metal_inside.to(dev)[asset.material]
    keep = torch.where(inside, torch.ones_like(metallic), 1 - metallic.to(dev, torch.float32))
    factor = base[asset.material] * asset.colors[:, :3] * keep[:, None]
    factor = torch.where((layer > 0)[:, None], factor, diffuse.to(dev, torch.float32))
    return AlbedoTexture(
        uvs=asset.uvs.to(torch.float32),
        layer=layer,
        factor=factor.contiguous(),
        images=tuple(images),
        wrap=torch.tensor(wraps, dtype=torch.int64),
        transform=torch.from_numpy(np.stack(xforms)),
        nearest=torch.tensor(nearest),
        specular=tuple(specular),
    )
