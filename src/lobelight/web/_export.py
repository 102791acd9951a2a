"""The web viewer's folder: a model, its maps and the page, written and read back.

:func:`export_web` writes a folder that a browser opens from ``file://`` or any static server
(no network, no build step): ``index.html`` and ``viewer.js`` (the page, package data),
``shaders.js`` (the shared shader files in the page's GLSL ES 3.00 dialect, assembled by
:func:`lobelight.render.stage_sources`), ``model.js`` and one ``env-K.js`` per map (data files
of :mod:`._format`). :func:`read_web` loads a folder back and checks it. The layout is
``docs/web-viewer.md``'s; the page uploads what the desktop renderer uploads, laid out by
:mod:`lobelight.render.layout` (the desktop's own layouts and constants), converted here to
half floats and to what the page's files hold; a sharp material's per-pixel reflection
included (its visibility and hit tiles, the whole map's chain).
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
from dataclasses import dataclass
from importlib import resources
from pathlib import Path, PurePath

import numpy as np
import torch

from .. import model as model_module
from ..brdf import ALBEDO_STEPS, SPLIT_ALPHAS, sharp_lobe
from ..envmap import EnvMap
from ..errors import InputError
from ..lobes import sh
from ..render import Lighting, model_camera, sample_offsets
from ..render.layout import (
    BLOCKER_SAMPLES,
    F0_MIN,
    FRAME_LAYOUT,
    LOBE_VISIBILITY_INCLUDE,
    LOBE_VISIBILITY_MOVING_SAMPLES,
    LOBE_VISIBILITY_SAMPLES,
    SHADOW_RES,
    SHADOW_SAMPLES,
    TEX_WIDTH,
    albedo_array,
    albedo_uniforms,
    atlas_image,
    atlas_uniforms,
    disc_radius,
    gaussian_records,
    geodesic_tables,
    kept_records,
    lobe_visibility_applies,
    lobe_visibility_defines,
    sharp_shader_defines,
    specular_f0,
    stage_layout,
    stage_sources,
    stage_texels,
    stage_varyings,
    sun_glossy_supported,
    sun_glossy_uniforms,
    sun_glossy_vertex_params,
    sun_shape_resolved,
    sun_widened,
    tail_scale,
    varying_lobe_arrays,
)
from ._format import read_data_file, write_data_file

__all__ = [
    "MAX_BACKGROUND_RES",
    "WEB_VERSION",
    "WebFolder",
    "dialect",
    "export_web",
    "read_web",
    "shader_variant",
]

#: Version of the folder's layout (the model file's ``header.version``).
WEB_VERSION = 1
#: Largest face resolution of the background's cube map in the folder (below the desktop's
#: :data:`lobelight.render.layout.BACKGROUND_RES`: the folder is downloaded; the background
#: is only seen behind the object).
MAX_BACKGROUND_RES = 256
#: Samples per pixel of a still frame (lobelight.render.Renderer's default).
STILL_SAMPLES = 4
#: Directions at which the page evaluates the rotated SH lighting to refit its coefficients
#: (a Fibonacci sphere: more than the 25 coefficients, well conditioned).
SH_FIT_DIRECTIONS = 64
#: The largest finite half float; brighter texels are clipped to it (the SH keep their light).
HALF_MAX = 65504.0
#: Files of the page copied from the package's assets.
_PAGE_FILES = ("index.html", "viewer.js")
#: The marker that a folder is one this module wrote (it may be replaced as a whole).
_MARKER = "model.js"


def dialect() -> str:
    """The page's GLSL ES 3.00 header (``web/assets/es300.glsl``): the version line and the
    precision statements, given to :func:`lobelight.render.stage_sources` as ``dialect``."""
    return resources.files("lobelight.web").joinpath("assets", "es300.glsl").read_text()


@dataclass(frozen=True)
class WebFolder:
    """A web folder read back (:func:`read_web`): the model file's header and arrays, each
    map's, and the shader variants by key."""

    path: Path
    header: dict
    arrays: dict
    envs: list
    shaders: dict


def _f16(x, float16: bool = True) -> np.ndarray:
    """float16 of ``x`` with magnitudes clipped to the largest finite half float (float32
    with ``float16=False``)."""
    a = np.asarray(x, np.float64)
    if not float16:
        return a.astype("<f4")
    return np.clip(a, -HALF_MAX, HALF_MAX).astype("<f2")


def _np(t: torch.Tensor, dtype) -> np.ndarray:
    return t.detach().cpu().numpy().astype(dtype)


def _records(model, float16: bool) -> dict[str, np.ndarray]:
    """The stored records as half floats, from the desktop's texels
    (:func:`lobelight.render.layout.gaussian_records`): ``flags (V, J)`` (bit 0 stored, bit 1
    the view above the vertex's horizon), then per stored record (row-major) and Gaussian the
    light it carries ``light (K, N, 3)``, its width ``sigma (K, N)`` and mean ``mean (K, N, 3)``;
    stored are :func:`lobelight.render.layout.kept_records`.

    A record whose light is live (mean over RGB at least ``LIVE_FLOOR``) but rounds to zero in
    half floats keeps the smallest half float: the live rule blends widths and means over the
    live records, and a record must not die on the way."""
    g = model.gaussians
    v, j, n = g.lam.shape
    keep = kept_records(g.w).cpu().numpy()  # (V, J)
    rec = gaussian_records(model).reshape(v, j, n, 2, 4)  # (e, sigma), (mu, above)
    above = rec[:, :, 0, 1, 3] > 0  # (V, J)
    flags = keep.astype(np.uint8) | (above.astype(np.uint8) << 1)
    kept = rec[keep]  # (K, N, 2, 4)
    light = _f16(kept[..., 0, :3], float16)  # (K, N, 3)
    live = kept[..., 0, :3].mean(-1) >= model_module.LIVE_FLOOR  # (K, N)
    dead16 = light.astype(np.float32).mean(-1) < model_module.LIVE_FLOOR
    light[live & dead16] = np.float16(2.0**-24)
    return {
        "flags": flags,
        "light": light,
        "sigma": _f16(kept[..., 0, 3], float16),
        "mean": _f16(kept[..., 1, :3], float16),
    }


def _geodesic() -> tuple[dict[str, np.ndarray], dict[str, int]]:
    """What ``geodesic.glsl`` reads (:func:`lobelight.render.layout.geodesic_tables`): the
    planes ``(540, 4)`` and the candidate image ``(6 R, R T, 4)`` as 16-bit integers; and the
    shader's defines (``CAND_RES``, ``CAND_TEXELS``)."""
    planes, cand, defines = geodesic_tables()
    arrays = {"planes": planes.astype("<f4"), "candidates": cand.astype("<i2")}
    return arrays, dict(defines)


def _fibonacci(n: int) -> np.ndarray:
    """``(n, 3)`` float64 unit directions of a Fibonacci sphere."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    r = np.sqrt(1 - z * z)
    a = i * math.pi * (3 - math.sqrt(5))
    return np.stack([r * np.cos(a), r * np.sin(a), z], -1)


def _sh_fit(order: int) -> dict[str, np.ndarray]:
    """The page's SH rotation: the rotated lighting's coefficients are ``fit @ (Y(R^T d_i) c)``
    with ``fit`` the pseudo-inverse of the basis at the directions ``d_i`` (exact: a rotation
    keeps each band)."""
    d = _fibonacci(SH_FIT_DIRECTIONS)
    y = sh.basis(torch.from_numpy(d), order).numpy()  # (D, n^2)
    return {"sh_dirs": d.astype("<f4"), "sh_fit": np.linalg.pinv(y).astype("<f4")}


def _atlas(pf) -> tuple[np.ndarray, dict]:
    """The prefiltered chain's atlas (:func:`lobelight.render.layout.atlas_image`) as a
    ``(H, W, 3)`` half-float image, and the uniforms ``prefiltered.glsl`` reads of it
    (:func:`lobelight.render.layout.atlas_uniforms`)."""
    atlas, rows, res = atlas_image(pf)
    u = atlas_uniforms(pf, atlas.shape, rows, res)
    uniforms = {
        **u,
        "atlas_size": [float(x) for x in u["atlas_size"]],
        "level_y": [float(x) for x in u["level_y"]],
        "level_res": [float(x) for x in u["level_res"]],
    }
    return _f16(atlas[..., :3]), uniforms


def _sun_vertex_params(spec, spread: float | None, n_vertices: int) -> np.ndarray:
    """:func:`lobelight.render.layout.sun_glossy_vertex_params` of the lobe (widened by the
    sun's disc of RMS angle ``spread``; as it is for None), ``(V, 10)`` float32, or its first
    row ``(1, 10)`` when every vertex has the same."""
    lobe = spec if spread is None else sun_widened(spec, spread)
    out = sun_glossy_vertex_params(lobe, n_vertices).astype("<f4")
    return out[:1] if bool((out == out[:1]).all()) else out


def _lobe_visibility(model) -> tuple[dict | None, dict[str, np.ndarray]]:
    """The lobe visibility correction (``lobe_visibility.glsl``) where it applies: the header
    (the tiles' resolution, the BRDF's shader switches) and the arrays (the vertices'
    visibility tiles ``vis_tiles`` and the BRDF's parameters as they are, ``lv_params``);
    None and nothing for another material."""
    if not lobe_visibility_applies(model):
        return None, {}
    spec = model.materials.specular
    tiles = model.visibility().cpu().numpy().astype(np.uint8)  # (V, R, R)
    u = sun_glossy_uniforms(spec)
    header = {
        "vis_res": int(tiles.shape[-1]),
        "brdf": {"model": int(u["sun_model"]), "fresnel": float(u["sun_fresnel"])},
        # the quadrature's directions: a still frame's, and those of a frame drawn while the
        # view moves
        "samples": LOBE_VISIBILITY_SAMPLES,
        "moving_samples": LOBE_VISIBILITY_MOVING_SAMPLES,
    }
    arrays = {
        "vis_tiles": tiles,
        "lv_params": _sun_vertex_params(spec, None, model.mesh.n_vertices),
    }
    return header, arrays


def shader_variant(
    has_sun: bool, sun_glossy: bool, bounce: bool, levels: int, shape: bool = False
) -> str:
    """The key of the shader variant a map needs (``shaders.js``); ``shape``: a sharp lobe
    reads its sun's shape (``whole_atlas``)."""
    key = f"sun{int(has_sun)}-glossy{int(sun_glossy)}-bounce{int(bounce)}-levels{levels}"
    return key + ("-shape" if shape else "")


def _programs(model, n_sh: int, geo_defines: dict, key_args: tuple) -> dict[str, list[str]]:
    """The page's programs of one variant as ES 3.00 stage texts: the object's shading and
    depth pre-pass (prt.glsl), the shadow map's, the background's and the tone mapping's."""
    has_sun, sun_glossy, bounce, levels, shape = key_args
    es = dialect()
    defines = {
        "N_GAUSSIANS": model.n_gaussians,
        "N_INDIRECT": model.indirect_gaussians,
        "N_SH": n_sh,
        "MAX_LEVELS": levels,
        "FLOOR": f"{model_module.LIVE_FLOOR:.6e}",
        "MIN_SAY": f"{model_module.MIN_SAY:.6e}",
        "HAS_BOUNCE": int(bounce),
        "HAS_SUN": int(has_sun),
        "SUN_GLOSSY": int(sun_glossy),
        "SUN_SHAPE": int(shape),
        "SHARP": 0,
        "ALBEDO_TEX": int(model.albedo is not None),
        "ALBEDO_LAYERS": 1 if model.albedo is None else len(model.albedo.images),
        "SPECULAR_TEX": int(specular_f0(model) is not None),
        "F0_MIN": f"{F0_MIN:.6e}",
        "STAGE_PASS": 0,
        "FROM_STAGE": 0,
        "STAGE_TEXELS": stage_texels(model),
        "STAGE_PER_ROW": stage_layout(model)[0],
        "SHADOW_SAMPLES": SHADOW_SAMPLES,
        "BLOCKER_SAMPLES": BLOCKER_SAMPLES,
        **geo_defines,
    }
    sharp = sharp_lobe(model.materials.specular) is not None
    if sharp:
        defines.update(_sharp_defines(model))
    lobe_vis = lobe_visibility_applies(model)
    defines.update(LOBE_VIS=int(lobe_vis), LOBE_VIS_PASS=0, **lobe_visibility_defines())
    if lobe_vis:
        defines["VIS_RES"] = int(model.visibility().shape[-1])
    frame = ("frame",)
    include = ("frame", "prefiltered") + (("brdf",) if sun_glossy else ())
    include += ("stage", "tiles", "reflection") if sharp else ()
    include += ("albedo",) if model.albedo is not None else ()
    # the vertex stage once per frame, captured by transform feedback (prt.glsl STAGE_PASS)
    stage_defines = {**defines, "DEPTH_ONLY": 0, "STAGE_PASS": 1}
    table = {
        "stage": list(stage_sources("prt", stage_defines, frame, ("frame", "geodesic"), dialect=es))
    }
    if lobe_vis:  # each vertex's factor on its direct Gaussians' light, by transform feedback
        lv_defines = {**defines, "DEPTH_ONLY": 0, "LOBE_VIS": 0, "LOBE_VIS_PASS": 1}
        table["lobevis"] = list(
            stage_sources("prt", lv_defines, frame, LOBE_VISIBILITY_INCLUDE, dialect=es)
        )
    return {
        **table,
        "prt": list(
            stage_sources(
                "prt",
                {**defines, "DEPTH_ONLY": 0, "FROM_STAGE": 1},
                include,
                ("frame", "geodesic", "stage"),
                dialect=es,
            )
        ),
        "depth": list(stage_sources("prt", {**defines, "DEPTH_ONLY": 1}, frame, frame, dialect=es)),
        "shadow": list(stage_sources("shadow", {"N_SH": n_sh}, frame, frame, dialect=es)),
        "background": list(stage_sources("background", {"N_SH": n_sh}, frame, frame, dialect=es)),
        "tonemap": list(stage_sources("tonemap", dialect=es)),
        "accumulate": list(stage_sources("accumulate", dialect=es)),
    }


def _sharp_defines(model) -> dict:
    """The defines of a sharp material's programs: the tiles' resolution, the albedo table's
    size, and :func:`lobelight.render.layout.sharp_shader_defines` (the mixture's live
    Gaussians, whether any vertex's hit tile finds the object)."""
    return {
        "SHARP": 1,
        "VIS_RES": int(model.visibility().shape[-1]),
        "ALBEDO_STEPS": ALBEDO_STEPS,
        **sharp_shader_defines(sharp_lobe(model.materials.specular), hit_tiles=model.sees_itself()),
    }


def _albedo(model) -> tuple[dict, dict[str, np.ndarray]]:
    """The albedo textures' header (what ``albedo.glsl``'s uniforms hold) and arrays (the
    layers and the per-vertex UVs, layers and factors); where the model has the specular
    colour per texel (:func:`lobelight.render.layout.specular_f0`), its F0 layers
    (``specular_layers``, the albedo layers' layout) and the bake's per-vertex F0 (``f0``)."""
    albedo = model.albedo
    layers = albedo_array(albedo)  # (L, H, W, 3) float16
    u = albedo_uniforms(albedo)
    f0 = specular_f0(model)
    header = {
        "layers": int(layers.shape[0]),
        "xform": u["albedo_xform"].astype(np.float64).reshape(-1).tolist(),
        "mode": u["albedo_mode"].astype(np.float64).reshape(-1).tolist(),
        "size": u["albedo_size"].astype(np.float64).tolist(),
        "specular": f0 is not None,
    }
    arrays = {
        "albedo_layers": layers,
        "uvs": _np(albedo.uvs, "<f4"),
        "layer": _np(albedo.layer, "<f4"),
        "factor": _np(albedo.factor, "<f4"),
    }
    if f0 is not None:
        arrays["specular_layers"] = albedo_array(albedo, specular=True)
        arrays["f0"] = _np(f0, "<f4")
    return header, arrays


def _sharp(model) -> tuple[dict | None, dict[str, np.ndarray]]:
    """A sharp material's per-pixel reflection (``reflection.glsl``): the header (the lobe's
    mixture, its directional albedo table, the tiles' resolution) and the arrays (the
    vertices' visibility and hit tiles, ``model.visibility()``, ``model.hit_texels()``); None and
    nothing for another material. A glTF lobe varying per vertex has the mixture at
    :data:`lobelight.brdf.VARYING_ALPHA_REF` and no albedo table in the header, and two
    arrays more, as the desktop renderer uploads them: ``lobe`` (V, 4), each vertex's
    roughness (negative where the fitted Gaussians shade it) and F0, and ``split`` (S, T, 2),
    :func:`lobelight.brdf.schlick_split` by roughness."""
    sl = sharp_lobe(model.materials.specular)
    if sl is None:
        return None, {}
    tiles = model.visibility().cpu().numpy().astype(np.uint8)  # (V, R, R)
    hits = model.hit_texels()  # the texels that see the object: the rest find none
    hit = hits.offsets().numpy()  # (K,) ascending places in the tiles laid end to end
    varying = sl.sharp is not None
    lam, lobe, split = varying_lobe_arrays(sl) if varying else (sl.lam, None, None)
    header = {
        "weights": [float(x) for x in sl.weights],
        "lam": [float(x) for x in lam],
        "warp": float(sl.warp),
        "albedo": [] if varying else [[float(c) for c in row] for row in sl.albedo],
        "vis_res": int(tiles.shape[-1]),
        "varying": varying,
    }
    arrays = {
        "vis_tiles": tiles,
        # ascending texel indices, and the triangles of neighbouring texels, as steps from
        # the one before: runs of small numbers that gzip shrinks several times over
        "hit_step": np.diff(hit, prepend=0).astype("<u4"),
        "hit_face_step": np.diff(hits.face.astype(np.int64), prepend=0).astype("<i4"),
        "hit_dist": hits.dist.astype("<f2"),
        # the triangle across each edge: a hit walked to the pixel's own ray's triangle
        "face_neighbours": model.mesh.face_neighbours.cpu().numpy().astype("<i4"),
    }
    if varying:
        arrays["lobe"], arrays["split"] = lobe.astype("<f4"), split.astype("<f4")
    return header, arrays


def _model_file(model, float16: bool) -> tuple[dict, dict[str, np.ndarray], int]:
    """The model data file's header and arrays, and the geodesic tables' shader defines."""
    mesh = model.mesh
    verts = mesh.vertices.detach().cpu().double()
    center = verts.mean(0)
    radius = float((verts - center).norm(dim=-1).max())
    geo, geo_defines = _geodesic()
    n_sh = int(model.diffuse.shape[1])
    arrays = {
        "positions": _np(mesh.vertices, "<f4"),
        "normals": _np(mesh.normals, "<f4"),
        "faces": _np(mesh.faces, "<u4"),
        "albedo": _np(model.materials.diffuse.expand(mesh.n_vertices, 3), "<f4"),
        **_records(model, float16),
        "diffuse": _f16(_np(model.diffuse, np.float64), float16),
        **geo,
        **_sh_fit(math.isqrt(n_sh)),
    }
    if model.bounce is not None:
        arrays["bounce"] = _f16(_np(model.bounce, np.float64), float16)
    sharp_header, sharp_arrays = _sharp(model)
    arrays.update(sharp_arrays)
    lv_header, lv_arrays = _lobe_visibility(model)
    arrays.update(lv_arrays)
    albedo_header = None
    if model.albedo is not None:
        albedo_header, albedo_arrays = _albedo(model)
        arrays.update(albedo_arrays)
    cam = model_camera(model)
    spec = model.materials.specular
    header = {
        "version": WEB_VERSION,
        "n_vertices": mesh.n_vertices,
        "n_faces": int(mesh.faces.shape[0]),
        # a closed surface wound outward: the page leaves out the triangles seen from behind
        "closed": mesh.encloses_outward,
        "n_views": int(model.views.shape[0]),
        "n_gaussians": model.n_gaussians,
        "indirect_gaussians": model.indirect_gaussians,
        "n_sh": n_sh,
        "records": int(arrays["light"].shape[0]),
        "center": center.tolist(),
        "radius": radius,
        "camera": {
            "origin": list(cam.origin),
            "target": list(cam.target),
            "up": list(cam.up),
            "fov": cam.fov,
            "fov_axis": cam.fov_axis,
        },
        "sun_glossy": sun_glossy_supported(spec),
        "shadow": {"res": SHADOW_RES, "samples": SHADOW_SAMPLES, "blockers": BLOCKER_SAMPLES},
        # frame.glsl's block (offsets in floats) and the width long arrays wrap at, as the
        # desktop lays them out
        "frame_layout": dict(FRAME_LAYOUT),
        "tex_width": TEX_WIDTH,
        # what the vertex stage's pass captures per vertex, in order (prt.glsl STAGE_PASS),
        # and the texture it is copied into: vertices per row, width, rows (stage.glsl)
        "stage_varyings": stage_varyings(model),
        "stage_layout": list(stage_layout(model)),
        # a still frame's sub-pixel samples: the desktop renderer's default
        "samples": sample_offsets(STILL_SAMPLES).tolist(),
        "notes": [],
        "sharp": sharp_header,
        "lobe_visibility": lv_header,
        "albedo_textures": albedo_header,
        "name": str((model.provenance or {}).get("scene", "model")),
    }
    return header, arrays, geo_defines


def _env_file(model, lighting: Lighting, sun_glossy_spec: bool) -> tuple[dict, dict, tuple]:
    """One map's data file header and arrays, and its shader variant's arguments."""
    has_sun = lighting.sun is not None
    sun_glossy = has_sun and sun_glossy_spec
    pf = lighting.rest_prefiltered if sun_glossy else lighting.prefiltered
    atlas, uniforms = _atlas(pf)
    # about the map's own texel density (a lat-long row spans four faces), at most 256
    width = int(lighting.env.data.shape[1])
    res = int(min(MAX_BACKGROUND_RES, max(16, 2 ** math.ceil(math.log2(max(width // 4, 1))))))
    cube = lighting.env.to_cubemap(res, cache=True)
    arrays = {
        "atlas": atlas,
        "background": _f16(_np(cube, np.float64)),
        "sh": _np(lighting.sh, "<f4"),
    }
    header = {
        # the map's file name without its folder: the page shows it, and a folder of this
        # machine means nothing where the page is opened
        "name": PurePath(str(lighting.name)).stem or str(lighting.name),
        "prefiltered": uniforms,
        "base_res": pf.base_res,
        "sun": None,
        "has_bounce": bool(model.bounce is not None and has_sun),
        "sun_glossy": sun_glossy,
    }
    if has_sun:
        sun = lighting.sun
        spec = model.materials.specular
        header["sun"] = {
            "direction": _np(sun.direction, np.float64).tolist(),
            "irradiance": _np(sun.irradiance, np.float64).tolist(),
            "spread": float(sun.spread),
            # the shadow's disc (lobelight.render.layout.disc_radius)
            "tan": math.tan(disc_radius(sun)),
        }
        if sun_glossy:
            v = model.mesh.n_vertices
            arrays["sun_params"] = _sun_vertex_params(spec, float(sun.spread), v)
            _sharp_sun(model, lighting, atlas.shape, header, arrays)
            u = sun_glossy_uniforms(spec)
            header["sun_brdf"] = {"model": int(u["sun_model"]), "fresnel": float(u["sun_fresnel"])}
    key_args = (has_sun, sun_glossy, header["has_bounce"], len(pf.levels), "whole_atlas" in arrays)
    header["variant"] = shader_variant(*key_args)
    return header, arrays, key_args


def _sharp_sun(model, lighting: Lighting, shape, header: dict, arrays: dict) -> None:
    """A sharp lobe's view of the sun's shape (prt.glsl ``sun_shape``): the analytic
    highlight's tail factor ``sun_tail`` (:func:`lobelight.render.layout.tail_scale`) and,
    where a Gaussian of the mixture resolves the sun's disc, the whole map's chain
    ``whole_atlas``, an atlas of the chain's layout (the chain itself is the map without the
    sun), as the desktop renderer uploads them."""
    sl = sharp_lobe(model.materials.specular)
    if sl is None:
        return
    spread = float(lighting.sun.spread)
    if sl.sharp is None:  # a lobe varying per vertex has its tail per point
        header["sun_tail"] = float(tail_scale(model.materials.specular, spread))
    if not sun_shape_resolved(sl, spread):
        return
    whole = _atlas(lighting.prefiltered)[0]
    if whole.shape != shape:
        raise InputError("lighting", "the whole map's chain differs in layout from its rest's")
    arrays["whole_atlas"] = whole


def _as_lighting(env, *, base_res: int, sun: bool, device) -> Lighting:
    if isinstance(env, Lighting):
        return env
    if not isinstance(env, EnvMap):
        raise InputError("envs", f"expected EnvMaps or Lightings, got {type(env).__name__}")
    return Lighting(env, base_res=base_res, sun=sun, device=device)


def _check_out(out: Path, inputs) -> None:
    """``out`` may be made, or replaced when it is a folder this module wrote; never a file
    read as an input or a folder holding one."""
    if out.exists() and not out.is_dir():
        raise InputError(str(out), "is a file: name a folder for the web viewer")
    if out.is_dir() and any(out.iterdir()) and not (out / _MARKER).is_file():
        raise InputError(str(out), "is a folder that is not a web export: not written over")
    if not out.parent.is_dir():
        raise InputError(str(out), f"the directory {str(out.parent)!r} does not exist")
    res = out.resolve()
    for p in inputs:
        q = Path(p).resolve()
        if q == res or res in q.parents:
            raise InputError(str(out), f"holds an input ({p}): not written over")


def export_web(
    model,
    out,
    envs,
    *,
    base_res: int = 128,
    sun: bool = True,
    device=None,
    inputs=(),
    float16: bool = True,
) -> dict:
    """Write the web viewer's folder for ``model`` under the maps ``envs`` (EnvMaps or
    Lightings, the first shown first) at ``out``, atomically: a temporary folder beside it,
    renamed into place (an earlier export there is replaced whole).

    ``inputs``: paths the caller read (the model file, the maps): ``out`` must not be one or
    hold one. ``float16``: the records and transfers as half floats (False: float32, twice
    the size; the chain and background are half floats either way).

    Returns ``{"output", "files": {name: bytes}, "bytes", "notes"}``."""
    out = Path(out)
    envs = list(envs)
    if not envs:
        raise InputError("envs", "give at least one map")
    _check_out(out, inputs)
    lightings = [_as_lighting(e, base_res=base_res, sun=sun, device=device) for e in envs]
    header, arrays, geo_defines = _model_file(model, float16)
    n_sh = header["n_sh"]
    for li in lightings:
        if li.sh.shape[0] != n_sh:
            raise InputError("envs", f"{li.name}: {li.sh.shape[0]} SH coefficients, model {n_sh}")
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".partial", dir=out.parent))
    try:
        files = {}
        variants = {}
        header["envs"] = []
        for i, li in enumerate(lightings):
            eh, ea, key_args = _env_file(model, li, header["sun_glossy"])
            name = f"env-{i}.js"
            files[name] = write_data_file(tmp / name, "env", eh, ea)
            header["envs"].append({"name": eh["name"], "file": name})
            if eh["variant"] not in variants:
                variants[eh["variant"]] = _programs(model, n_sh, geo_defines, key_args)
        files["model.js"] = write_data_file(tmp / "model.js", "model", header, arrays)
        files["shaders.js"] = write_data_file(tmp / "shaders.js", "shaders", variants, {})
        assets = resources.files("lobelight.web").joinpath("assets")
        for name in _PAGE_FILES:
            (tmp / name).write_bytes(assets.joinpath(name).read_bytes())
            files[name] = (tmp / name).stat().st_size
        read_web(tmp)  # what the page will read passes our own reader
        _replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return {
        "output": str(out),
        "files": files,
        "bytes": sum(files.values()),
        "notes": header["notes"],
    }


def _replace(tmp: Path, out: Path) -> None:
    """Rename the finished folder ``tmp`` to ``out``; an earlier export there is moved aside
    first and removed after."""
    os.chmod(tmp, 0o755)
    if not out.exists():
        os.replace(tmp, out)
        return
    old = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".old", dir=out.parent))
    old.rmdir()
    os.replace(out, old)
    os.replace(tmp, out)
    shutil.rmtree(old, ignore_errors=True)


def _check_model_arrays(path: Path, h: dict, a: dict) -> None:
    """The model file's arrays against its header's counts."""
    v, f, j, n, s, k = (h["n_vertices"], h["n_faces"], h["n_views"], h["n_gaussians"],
                        h["n_sh"], h["records"])  # fmt: skip
    want = {
        "positions": (v, 3),
        "normals": (v, 3),
        "faces": (f, 3),
        "albedo": (v, 3),
        "flags": (v, j),
        "light": (k, n, 3),
        "sigma": (k, n),
        "mean": (k, n, 3),
        "diffuse": (v, s, 3),
        "planes": (540, 4),
    }
    for name, shape in want.items():
        if name not in a or tuple(a[name].shape) != shape:
            got = None if name not in a else tuple(a[name].shape)
            raise InputError(str(path), f"array {name} has shape {got}, expected {shape}")
    if int((a["flags"] & 1).sum()) != k:
        raise InputError(str(path), f"flags mark {int((a['flags'] & 1).sum())} records, not {k}")
    if f and int(a["faces"].max()) >= v:
        raise InputError(str(path), "a face names a vertex past the last")
    if "bounce" in a and a["bounce"].shape != (v, s, 3):
        raise InputError(str(path), f"array bounce has shape {a['bounce'].shape}")
    _check_sharp_arrays(path, h, a)
    _check_lobe_visibility_arrays(path, h, a)
    at = h.get("albedo_textures")
    if at is not None:
        shapes = {"uvs": (v, 2), "layer": (v,), "factor": (v, 3)}
        for name, shape in shapes.items():
            if name not in a or a[name].shape != shape:
                raise InputError(str(path), f"array {name} missing or not of shape {shape}")
        layers = a.get("albedo_layers")
        if layers is None or layers.ndim != 4 or layers.shape[0] != at["layers"]:
            raise InputError(str(path), "its albedo layers do not match the header")
        if at.get("specular"):
            spec = a.get("specular_layers")
            if spec is None or spec.shape != layers.shape:
                raise InputError(str(path), "its specular layers do not match its albedo layers")
            if "f0" not in a or a["f0"].shape != (v, 3):
                raise InputError(str(path), f"array f0 missing or not of shape {(v, 3)}")


def _check_lobe_visibility_arrays(path: Path, h: dict, a: dict) -> None:
    """The lobe visibility correction's tiles and BRDF parameters against the header."""
    lv = h.get("lobe_visibility")
    if lv is None:
        return
    r, v = int(lv["vis_res"]), h["n_vertices"]
    if "vis_tiles" not in a or a["vis_tiles"].shape != (v, r, r):
        raise InputError(str(path), f"array vis_tiles missing or not of shape (V, {r}, {r})")
    p = a.get("lv_params")
    if p is None or p.ndim != 2 or p.shape[1] != 10 or p.shape[0] not in (1, v):
        raise InputError(str(path), "array lv_params missing or not of shape (1 or V, 10)")
    if not np.isfinite(p).all():
        raise InputError(str(path), "its lv_params hold non-finite values")


def _check_sharp_arrays(path: Path, h: dict, a: dict) -> None:
    """A sharp material's tiles against the header's counts."""
    if h.get("sharp") is None:
        return
    r = int(h["sharp"]["vis_res"])
    if "vis_tiles" not in a or a["vis_tiles"].shape != (h["n_vertices"], r, r):
        raise InputError(str(path), f"array vis_tiles missing or not of shape (V, {r}, {r})")
    if any(name not in a for name in ("hit_step", "hit_face_step", "hit_dist")):
        raise InputError(str(path), "has no hit tiles (hit_step, hit_face_step, hit_dist)")
    n = a["hit_step"].shape
    if a["hit_face_step"].shape != n or a["hit_dist"].shape != n or len(n) != 1:
        raise InputError(str(path), "its hit tiles' arrays differ in length")
    f = h["n_faces"]
    if n[0]:
        if bool((a["hit_step"][1:] == 0).any()):
            raise InputError(str(path), "its hit tile texels do not ascend")
        if int(a["hit_step"].sum(dtype=np.int64)) >= h["n_vertices"] * r * r:  # the last
            raise InputError(str(path), "a hit tile texel lies past the last tile")
        face = np.cumsum(a["hit_face_step"], dtype=np.int64)
        if int(face.min()) < 0 or int(face.max()) >= f:
            raise InputError(
                str(path), "a hit tile texel's triangle is not one of the mesh's faces"
            )
    nb = a.get("face_neighbours")
    if nb is None or nb.shape != (f, 3):
        raise InputError(str(path), f"array face_neighbours missing or not of shape ({f}, 3)")
    if f and (int(nb.min()) < -1 or int(nb.max()) >= f):
        raise InputError(str(path), "a face's neighbour lies past the last face")
    if h["sharp"].get("varying"):
        shapes = {"lobe": (h["n_vertices"], 4), "split": (SPLIT_ALPHAS, ALBEDO_STEPS, 2)}
        for name, shape in shapes.items():
            if name not in a or a[name].shape != shape:
                raise InputError(str(path), f"array {name} missing or not of shape {shape}")
        if not (np.isfinite(a["lobe"]).all() and np.isfinite(a["split"]).all()):
            raise InputError(str(path), "its varying lobe's arrays hold non-finite values")


def read_web(path) -> WebFolder:
    """Load a web folder back and check it: every file present, the model's arrays against its
    counts, each map's arrays and shader variant. One :class:`InputError` naming the problem."""
    path = Path(path)
    for name in (*_PAGE_FILES, "shaders.js", "model.js"):
        if not (path / name).is_file():
            raise InputError(str(path), f"has no {name}: not a web export")
    header, arrays = read_data_file(path / "model.js", "model")
    if header.get("version") != WEB_VERSION:
        raise InputError(str(path), f"layout version {header.get('version')}, not {WEB_VERSION}")
    _check_model_arrays(path / "model.js", header, arrays)
    if not isinstance(header.get("closed", False), bool):
        raise InputError(str(path / "model.js"), "its header's closed is not true or false")
    shaders, _ = read_data_file(path / "shaders.js", "shaders")
    envs = []
    for rec in header["envs"]:
        eh, ea = read_data_file(path / rec["file"], "env")
        if eh["variant"] not in shaders:
            raise InputError(str(path / rec["file"]), f"needs shader variant {eh['variant']}")
        sh_shape = (header["n_sh"], 3)
        if ea["sh"].shape != sh_shape or ea["background"].shape[0] != 6:
            raise InputError(str(path / rec["file"]), "has an SH or background of another shape")
        atlas = ea["atlas"].shape
        if list(atlas[1::-1]) != [int(x) for x in eh["prefiltered"]["atlas_size"]]:
            raise InputError(str(path / rec["file"]), "its atlas does not match its size")
        envs.append((eh, ea))
    return WebFolder(path, header, arrays, envs, shaders)
