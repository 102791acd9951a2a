"""The OpenGL renderer (moderngl): headless through EGL, or into a window's context.

Everything per frame stays on the GPU (the paper repacks the three nearest views' data on the
CPU every frame, its bottleneck): the Gaussians of every (vertex, view) live in a float
texture, the 180 geodesic triangles' great-circle planes in a uniform block, and the vertex
shader finds each vertex's view triangle itself. The per-frame values (camera, lighting rotation,
the rotated lighting's SH coefficients, the sun) live in one uniform block
(``shaders/frame.glsl``), filled in Python and written in one buffer write when a value changes:
a frame with the camera and lighting of the one before writes no uniform at all.

Prefiltered levels: each level's six faces, each with the one-texel seamless border of
:func:`lobelight.geometry.cubemap.pad_seamless`, are packed into one atlas texture; hardware
bilinear filtering inside a padded face equals GL's seamless cube-map filtering (the same corner
rule) and matches :func:`lobelight.geometry.cubemap.sample` exactly. A Gaussian between two levels
costs two bilinear fetches, blended by the L2 rule of
:meth:`lobelight.envmap.Prefiltered.level_coords` (a trilinear ``textureLod`` would blend mips
linearly in level, which is less accurate).
"""

from __future__ import annotations

import contextlib
import math
import time
from functools import cache
from importlib import resources

import numpy as np
import torch

from .. import model as model_module
from ..brdf import ALBEDO_STEPS, sharp_lobe
from ..envmap import Prefiltered
from ..errors import InputError
from ..geometry import sphere
from ..geometry.camera import Camera
from ..lobes import sg
from ..model import VISIBILITY_RES, HitTexels
from ._albedo import F0_MIN, specular_f0
from ._gl_albedo import albedo_array, albedo_uniforms
from ._lighting import Lighting
from ._lobe_visibility import SAMPLES as LOBE_VISIBILITY_SAMPLES
from ._lobe_visibility import lobe_visibility_applies
from ._lobe_visibility import shader_defines as lobe_visibility_defines
from ._reflection import sharp_shader_defines, sun_shape_resolved, varying_lobe_arrays
from ._sun_glossy import (
    sun_glossy_supported,
    sun_glossy_uniforms,
    sun_glossy_vertex_params,
    sun_widened,
    tail_scale,
)
from ._sun_shadow import BLOCKER_SAMPLES, SHADOW_SAMPLES, disc_radius, sample_taps, sun_frame
from ._tonemap import CURVES, DEFAULT_CURVE

__all__ = [
    "BACKGROUND_RES",
    "CAND_RES",
    "FRAME_LAYOUT",
    "SHADOW_RES",
    "TEX_WIDTH",
    "GLRenderer",
    "PassTimer",
    "atlas_image",
    "atlas_uniforms",
    "create_context",
    "gaussian_records",
    "geodesic_tables",
    "gl_available",
    "load_shader",
    "set_uniforms",
    "stage_layout",
    "stage_sources",
    "stage_texels",
    "stage_varyings",
    "upload_geodesic",
    "upload_prefiltered",
]

#: Texture width used to wrap long 1-D arrays into 2-D textures.
TEX_WIDTH = 4096
#: Face resolution of the cube map of candidate view triangles (sphere.triangle_candidates).
CAND_RES = 32
#: Resolution of the background's cube map.
BACKGROUND_RES = 512
#: Resolution of the sun's shadow map (texels across the mesh's bounding sphere).
SHADOW_RES = 4096
_GL_TEXTURE_CUBE_MAP_SEAMLESS = 0x884F
#: Texture unit of the shadow map's depths read without comparison (the soft shadow's search).
_SHADOW_DEPTH_UNIT = 9
#: Texture unit of the whole map's chain, read by a sharp lobe for the sun's shape.
_WHOLE_ATLAS_UNIT = 5
#: Texture units of the per-pixel reflection's visibility tiles, faces and positions.
_VIS_UNIT = 10
#: Width in texels of the visibility atlas and of the face and position textures.
_VIS_TEX_WIDTH = 4096
#: Texture units of the sharp reflection's hit points (reflection.glsl): normals, albedos,
#: hit tiles.
_SHARP_UNITS = (
    ("nrm_tex", _VIS_UNIT + 3),
    ("alb_tex", _VIS_UNIT + 4),
    ("hit_face_tex", _VIS_UNIT + 5),
    ("hit_dist_tex", _VIS_UNIT + 6),
)
#: Texture unit of the vertex stage's results per vertex (prt.glsl FROM_STAGE, and the sharp
#: reflection's hit points).
_STAGE_UNIT = _VIS_UNIT + 7
#: Texture unit of the albedo textures (albedo.glsl).
_ALBEDO_UNIT = _VIS_UNIT + 8
#: Texture units of a glTF lobe varying per vertex (reflection.glsl ``lobe_tex``,
#: ``split_tex``), after the albedo textures' two.
_LOBE_UNIT = _ALBEDO_UNIT + 2
#: Components one transform feedback captures at most, interleaved: 64 in every OpenGL 3.3 and
#: WebGL 2 implementation (GL_MAX_TRANSFORM_FEEDBACK_INTERLEAVED_COMPONENTS' minimum).
TRANSFORM_FEEDBACK_COMPONENTS = 64
#: The shader files the lobe visibility correction's vertex stage includes, in order.
LOBE_VISIBILITY_INCLUDE = ("frame", "geodesic", "prefiltered", "tiles", "brdf", "lobe_visibility")
#: Colour target texel types: float32 (what ``read`` returns exactly) and half float (display).
HDR_DTYPES = ("f4", "f2")
#: Uniform-block bindings of the PRT programs: the geodesic planes, frame.glsl's two blocks.
_PLANES_BINDING, _FRAME_BINDING, _SAMPLE_BINDING = 0, 1, 2
#: Offsets in floats of the members of frame.glsl's ``Frame`` block (std140: a scalar fills the
#: fourth float after a vec3, a mat3 is three vec4 columns, a vec4 array element is 4 floats);
#: ``sh_sun`` follows ``sh_light``'s ``N_SH`` vec4s.
FRAME_LAYOUT = {
    "eye": 0,
    "sun_on": 3,
    "cam_left": 4,
    "shadow_scale": 7,
    "cam_up": 8,
    "shadow_offset": 11,
    "cam_dir": 12,
    "shadow_bias": 15,
    "sun_dir": 16,
    "diffuse_on": 19,
    "sun_e": 20,
    "glossy_on": 23,
    "shadow_center": 24,
    "tan_half": 28,
    "depth_range": 30,
    "rot_t": 32,
    "shadow_frame": 44,
    "sh_light": 56,
}
#: Buffers the frame block's writes go round (more than the frames a driver keeps in flight).
_FRAME_BUFFERS = 4
#: A context manager that does nothing (a pass's timing when no PassTimer is attached).
_UNTIMED = contextlib.nullcontext()


@cache
def load_shader(name: str) -> str:
    """The text of a package shader file (``render/shaders/NAME.glsl``)."""
    return resources.files("lobelight.render").joinpath("shaders", f"{name}.glsl").read_text()


def stage_sources(
    name: str,
    defines: dict[str, int | str] | None = None,
    include: tuple = (),
    vertex_include: tuple = (),
    *,
    dialect: str = "#version 330\n",
) -> tuple[str, str]:
    """The vertex and fragment stage texts of shader file ``name`` (one file holding both
    stages): ``dialect`` (the version line and whatever a GLSL dialect needs before the shared
    text, e.g. OpenGL ES 3.00's precision statements), the ``defines``, the stage's define, the
    text of the files that ``vertex_include`` / ``include`` name (shared functions, e.g.
    ``"prefiltered"``, ``"geodesic"``), then the file. The desktop renderers and the web
    viewer compile the same files this way, each with its own dialect."""
    head = dialect + "".join(f"#define {k} {v}\n" for k, v in (defines or {}).items())
    src = load_shader(name)

    def lib(names):
        return "".join(load_shader(i) + "\n" for i in names)

    return (
        head + "#define VERTEX_SHADER\n" + lib(vertex_include) + src,
        head + "#define FRAGMENT_SHADER\n" + lib(include) + src,
    )


def _program(
    ctx,
    name: str,
    defines: dict[str, int | str] | None = None,
    include: tuple = (),
    vertex_include: tuple = (),
):
    """A program of :func:`stage_sources`' two stages."""
    vertex, fragment = stage_sources(name, defines, include, vertex_include)
    return ctx.program(vertex_shader=vertex, fragment_shader=fragment)


def create_context():
    """A headless OpenGL 3.3+ context: EGL (Mesa llvmpipe here, the NVIDIA driver on GPUs)."""
    try:
        import moderngl  # optional (the gl extra)
    except ImportError:
        raise InputError(
            "moderngl", "is not installed: pip install 'lobelight[gl]' (or use backend='torch')"
        ) from None
    try:
        return moderngl.create_standalone_context(backend="egl", require=330)
    except Exception as egl_error:
        try:
            return moderngl.create_standalone_context(require=330)
        except Exception:
            raise InputError(
                "OpenGL", f"no headless OpenGL 3.3 context (EGL: {egl_error}); use backend='torch'"
            ) from None


def make_current(ctx, owned: bool) -> None:
    """Make ``ctx`` current if its renderer made it (``owned``). Each headless renderer has a
    context of its own, GL commands go to whichever is current, and making or releasing
    another (another renderer, :func:`gl_available`) changes which that is. A context a
    renderer was given (a window's) is its owner's to keep current."""
    if owned:
        ctx.__enter__()


def gl_available() -> bool:
    """Whether a headless context can be made here."""
    try:
        create_context().release()
        return True
    except InputError:
        return False


def _wrap_size(texels: int, width: int = TEX_WIDTH) -> tuple[int, int]:
    """``(H, W)`` of an image holding ``texels`` texels in rows of ``W >= width`` texels (wider
    where ``H`` would pass GL's usual maximum texture height, 16384)."""
    while -(-texels // width) > 16384:
        width *= 2
    return max(1, -(-texels // width)), width


def _wrap(rows: np.ndarray, width: int = TEX_WIDTH) -> tuple[np.ndarray, int]:
    """Wrap ``(T, 4)`` texels into a ``(H, W, 4)`` image (zero-padded); returns it and W."""
    t = rows.shape[0]
    h, width = _wrap_size(t, width)
    out = np.zeros((h * width, 4), np.float32)
    out[:t] = rows
    return out.reshape(h, width, 4), width


def _tile_atlas(tiles: np.ndarray, per_row: int, dtype=None) -> np.ndarray:
    """Per-vertex ``(V, R, R)`` tiles laid out ``per_row`` to a row of a 2-D image, as
    ``dtype`` (the tiles' own by default): one copy, written in place (a sharp model's tiles
    are its largest arrays after the Gaussians)."""
    v, r = tiles.shape[0], tiles.shape[1]
    rows, full = -(-v // per_row), v // per_row
    out = np.zeros((rows, r, per_row, r), tiles.dtype if dtype is None else dtype)
    out[:full] = tiles[: full * per_row].reshape(full, per_row, r, r).transpose(0, 2, 1, 3)
    if full < rows:  # the last row's tiles, the rest of it zeros
        out[full, :, : v - full * per_row] = tiles[full * per_row :].transpose(1, 0, 2)
    return out.reshape(rows * r, per_row * r)


def hit_atlases(hits: HitTexels, width: int = _VIS_TEX_WIDTH) -> tuple:
    """The hit tiles of the vertices whose tile finds the object as the shaders read them
    (reflection.glsl), laid straight from the texels that hit: each vertex's slot ``(V,)``
    int32 (-1: no hit in its tile, slots in vertex order), the slots' tiles side by side,
    ``per_row`` to a row of at most ``width`` texels, as atlases ``(rows R, per_row R)`` int32
    (-1 where the ray misses) and float16 distances (one tile of misses where no vertex has a
    hit: a texture is never empty), and ``per_row``."""
    r = hits.res
    has = hits.count > 0
    slots = np.where(has, np.cumsum(has) - 1, -1).astype(np.int32)
    n_slots = max(1, int(has.sum()))
    per_row = max(1, min(n_slots, width // r))
    rows, cols = -(-n_slots // per_row) * r, per_row * r
    face = np.full(rows * cols, -1, np.int32)
    dist = np.zeros(rows * cols, np.float16)
    # each slot's first texel in the atlas, then each texel's offset in its tile: one flat
    # index in int32 (a scatter along one axis is faster than along two)
    first = (slots // per_row) * (r * cols) + (slots % per_row) * r  # (V,)
    ty, tx = np.divmod(hits.texel.astype(np.int32), r)
    at = np.repeat(first, hits.count) + ty * cols + tx  # (K,)
    face[at] = hits.face
    dist[at] = hits.dist
    face, dist = face.reshape(rows, cols), dist.reshape(rows, cols)
    return slots, face, dist, per_row


def _set_uniform(prog, name: str, value) -> None:
    """Sets ``prog``'s uniform ``name`` where the compiler kept it: an array (a list) to as
    many elements as it kept (a driver drops an array's elements past the last one the shader
    reads: a sharp lobe's mixture read at its live Gaussians alone)."""
    u = prog.get(name, None)
    if u is None:
        return
    u.value = tuple(value[: u.array_length]) if isinstance(value, list) else value


def atlas_layout(pf: Prefiltered) -> tuple[tuple[int, int], np.ndarray, np.ndarray]:
    """The atlas of all prefiltered levels (:func:`atlas_image`): its ``(H, W)``, and each
    level's first row and resolution ``(L,)`` float32: the levels' padded faces one band of
    rows each, six faces side by side."""
    sizes = [int(p.shape[1]) for p in pf.padded]  # each level's padded face, P
    rows = np.cumsum([0, *sizes[:-1]]).astype(np.float32)
    res = np.asarray(sizes, np.float32) - 2
    return (sum(sizes), 6 * (pf.base_res + 2)), rows, res


def _atlas_bands(pf: Prefiltered):
    """Each level's band of the atlas: its first row and its ``(P, W, 4)`` float32 texels (the
    six padded faces side by side, RGB, alpha 1; ones past them). One buffer per band height,
    reused: a band is used before the next is asked for."""
    width = atlas_layout(pf)[0][1]
    bands: dict[int, np.ndarray] = {}
    y = 0
    for p in pf.padded:
        face = p.cpu().numpy()  # (6, P, P, 3)
        size = face.shape[1]
        # RGBA: llvmpipe filters four-channel float textures faster than three-channel ones,
        # and GPUs pad RGB anyway
        band = bands.setdefault(size, np.ones((size, width, 4), np.float32))
        band[:, : 6 * size, :3] = face.transpose(1, 0, 2, 3).reshape(size, 6 * size, 3)
        yield y, band
        y += size


def atlas_image(pf: Prefiltered) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All prefiltered levels' padded faces in one image: ``(H, W, 4)`` (RGB, alpha 1), row and
    res per level (:func:`atlas_layout`)."""
    (height, width), rows, res = atlas_layout(pf)
    atlas = np.empty((height, width, 4), np.float32)
    for y, band in _atlas_bands(pf):
        atlas[y : y + band.shape[0]] = band
    return atlas, rows, res


def write_atlas(tex, pf: Prefiltered) -> None:
    """Write the chain's atlas (:func:`atlas_image`) into texture ``tex`` of its size a level's
    band at a time: the whole image never exists in memory (a 512-base chain's is 52 MB, and
    a process's fresh memory costs its page faults)."""
    for y, band in _atlas_bands(pf):
        tex.write(band, viewport=(0, y, band.shape[1], band.shape[0]))


def _rgb0(table: torch.Tensor) -> np.ndarray:
    """``(..., 3)`` values as ``(T, 4)`` float texels (alpha 0)."""
    rows = torch.cat([table, torch.zeros_like(table[..., :1])], -1)
    return rows.reshape(-1, 4).detach().cpu().numpy()


#: Texels across a row of the stage texture at most (WebGL 2's smallest texture size).
STAGE_WIDTH = 2048


def stage_texels(model) -> int:
    """RGBA texels per vertex of the vertex stage's results (prt.glsl STAGE_TEXELS): the ``2 N``
    lobe varyings, the diffuse colour, the direct Gaussians' light (stage.glsl)."""
    return 2 * model.n_gaussians + 2


def stage_layout(model) -> tuple[int, int, int]:
    """The stage texture's vertices per row, width and rows (stage.glsl): whole vertices per
    row, so that a vertex's texels are found with one division, and the capture, vertex after
    vertex, copies into it row by row."""
    t = stage_texels(model)
    per_row = STAGE_WIDTH // t
    return per_row, per_row * t, max(1, -(-model.mesh.n_vertices // per_row))


def stage_fits(model) -> bool:
    """Whether one transform feedback captures the vertex stage's results (up to seven
    Gaussians per view); with more, each shading pass computes them itself."""
    return 4 * stage_texels(model) <= TRANSFORM_FEEDBACK_COMPONENTS


def stage_varyings(model) -> list[str]:
    """The outputs prt.glsl's STAGE_PASS captures, in the order of a vertex's texels in the
    stage texture (:func:`stage_texels`; one output each, as WebGL 2 captures no array)."""
    return [f"v_stage{i}" for i in range(stage_texels(model))]


def gaussian_records(model) -> np.ndarray:
    """Two texels per Gaussian ``(2 V J N, 4)``: record ``(v, j, k)`` is texels ``2r`` and
    ``2r + 1`` with ``r = (v J + j) N + k``, holding the light the lobe carries and its width
    ``(e, sigma)``, then its axis and whether the record's view is above the vertex's horizon
    ``(mu, above)`` (prt.glsl's ``gaussian``)."""
    flat = _FlatRecords(model)
    out = torch.empty(2 * flat.count, 4)
    flat.fill(0, flat.count, out.view(-1, 2, 4))
    return out.numpy()


class _FlatRecords:
    """A model's Gaussian records in the order of :func:`gaussian_records`, filled by range
    (from the stored rows where the model was read from a file: :meth:`Gaussians.records`)."""

    def __init__(self, model):
        # C-ordered once, so that each band's records are views, not a copy of every record
        self.g = model.gaussians.contiguous()
        v, j, n = self.g.shape
        self.count = v * j * n
        # whether each record's view is above its vertex's horizon (model.horizon_scale)
        above = (model.views[None] * model.mesh.normals[:, None]).sum(-1) > 0  # (V, J)
        self.above = above.reshape(-1, 1).expand(-1, n).reshape(-1)

    def fill(self, a: int, b: int, out: torch.Tensor) -> None:
        """Records ``a`` to ``b`` into ``out (b - a, 2, 4)``."""
        w, mu, lam = self.g.records(a, b)
        torch.rsqrt(lam, out=out[:, 0, 3])
        # the light each lobe carries (prt.glsl blends it, not the peak weight)
        torch.mul(w, sg.integral(lam)[:, None], out=out[:, 0, :3])
        out[:, 1, :3] = mu
        out[:, 1, 3] = self.above[a:b]


#: Bytes of records written to the records texture at a time: a buffer this size is filled
#: and uploaded band by band, so the records never exist whole outside the texture (a model's
#: records are its largest array) and the buffer stays in the processor's cache.
RECORD_BAND_BYTES = 4 << 20


def upload_records(ctx, model, width: int):
    """The records texture: :func:`gaussian_records` wrapped into rows of ``width`` texels
    (zero-padded), float32, written in bands of :data:`RECORD_BAND_BYTES`."""
    flat = _FlatRecords(model)
    height = _wrap_size(2 * flat.count, width)[0]
    tex = ctx.texture((width, height), 4, dtype="f4")
    rows = max(1, RECORD_BAND_BYTES // (16 * width))
    buf = torch.empty(rows * width, 4)
    for y in range(0, height, rows):
        h = min(rows, height - y)
        a = y * width // 2  # width is even: a row holds whole records
        b = min(a + h * width // 2, flat.count)
        flat.fill(a, b, buf[: 2 * (b - a)].view(-1, 2, 4))
        buf[2 * (b - a) : h * width] = 0
        tex.write(buf[: h * width].numpy(), viewport=(0, y, width, h))
    return tex


def transfer_width(model, bounce: torch.Tensor) -> int:
    """The width in texels the transfer's three textures share (each needs at least its own,
    :func:`_wrap_size`): the records, the diffuse transfer, and ``bounce``."""
    g = model.gaussians.shape
    return max(
        _wrap_size(2 * g[0] * g[1] * g[2])[1],
        _wrap_size(model.diffuse.shape[0] * model.diffuse.shape[1])[1],
        _wrap_size(bounce.shape[0] * bounce.shape[1])[1],
    )


def _bounding_sphere(mesh) -> tuple[np.ndarray, float]:
    """The vertices' centroid ``(3,)`` and the largest distance of a vertex from it."""
    center = mesh.vertices.mean(0)
    radius = float((mesh.vertices - center).norm(dim=-1).max())
    return center.detach().cpu().numpy(), radius


def _background(lighting: Lighting) -> np.ndarray:
    """The map as the background's cube texture, ``(6, BACKGROUND_RES, BACKGROUND_RES, 3)``."""
    # kept on disk beside the chain for a static map; a dynamic one (ChainBuilders) is not
    cube = lighting.env.to_cubemap(BACKGROUND_RES, cache=lighting._builders is None)
    return cube.detach().cpu().numpy().astype(np.float32)


def atlas_uniforms(pf: Prefiltered, atlas_shape, rows: np.ndarray, res: np.ndarray) -> dict:
    """The uniforms ``prefiltered.glsl`` reads of an atlas of :func:`atlas_image`'s layout
    (``atlas_shape`` its ``(H, W, 4)``, ``rows`` and ``res`` per level)."""
    return {
        "atlas_size": (float(atlas_shape[1]), float(atlas_shape[0])),
        "level_y": rows,
        "level_res": res,
        "n_levels": len(pf.levels),
        "lam0": float(pf.lambdas[0]),
        "log_rho": float(torch.log(pf.lambdas[0] / pf.lambdas[1])),
    }


def upload_prefiltered(ctx, pf: Prefiltered):
    """The prefiltered chain as one atlas texture, and the uniforms ``prefiltered.glsl`` reads
    (bind the texture to the unit of its ``atlas`` sampler)."""
    import moderngl  # optional (the gl extra)

    (height, width), rows, res = atlas_layout(pf)
    tex = ctx.texture((width, height), 4, dtype="f4")
    write_atlas(tex, pf)
    tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
    tex.repeat_x = tex.repeat_y = False
    return tex, atlas_uniforms(pf, (height, width, 4), rows, res)


def geodesic_tables() -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
    """What ``geodesic.glsl`` reads, as arrays: the 180 triangles' planes ``(540, 4)`` float32
    (three great-circle normals per triangle, ``.w`` the view index of the opposite corner),
    the candidate table as a ``(6 CAND_RES, CAND_RES CAND_TEXELS, 4)`` float32 image (the
    triangles of each cube-map texel's directions, -1 padded), and the shader's defines."""
    planes, faces = sphere.face_planes(torch.float32, torch.device("cpu"))
    pl = torch.cat([planes.T.reshape(180, 3, 3), faces.reshape(180, 3, 1).float()], -1)
    block = pl.reshape(540, 4).numpy().astype(np.float32)
    cand = sphere.triangle_candidates(CAND_RES)  # (6, R, R, K)
    texels = -(-cand.shape[-1] // 4)
    cand = torch.nn.functional.pad(cand, (0, 4 * texels - cand.shape[-1]), value=-1)
    img = cand.reshape(6 * CAND_RES, CAND_RES * texels, 4).float().numpy()
    return block, img, {"CAND_RES": CAND_RES, "CAND_TEXELS": texels}


def upload_geodesic(ctx):
    """What ``geodesic.glsl`` reads (:func:`geodesic_tables`): the planes as a uniform block
    (bind it to the ``Planes`` block), the candidate table as a texture (bind it to the unit of
    the ``cand_tex`` sampler), and the defines the shader needs.

    Returns
    -------
    planes buffer, candidate texture, ``{"CAND_RES": ..., "CAND_TEXELS": ...}``
    """
    import moderngl  # optional (the gl extra)

    block, img, defines = geodesic_tables()
    ubo = ctx.buffer(block.tobytes())
    tex = ctx.texture((img.shape[1], img.shape[0]), 4, np.ascontiguousarray(img), dtype="f4")
    tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
    return ubo, tex, defines


def set_uniforms(prog, values: dict) -> None:
    """Set a program's uniforms: numpy arrays are written as bytes, the rest by value."""
    for k, v in values.items():
        if isinstance(v, np.ndarray):
            prog[k].write(v.astype(np.float32).tobytes())
        else:
            prog[k].value = v


class _FrameBlock:
    """frame.glsl's ``Frame`` uniform block: a float32 copy ``(56 + 8 N_SH,)`` filled member by
    member (offsets in :data:`FRAME_LAYOUT`), written by :meth:`flush` in one write when it differs
    from what was written last.

    Each write goes into the next of :data:`_FRAME_BUFFERS` buffers (:attr:`buffer` is the one
    written last), so that it never touches a buffer that a frame still in flight reads: a
    driver would wait for that frame, or copy the buffer, first.
    """

    def __init__(self, ctx, n_sh: int):
        self.n_sh = n_sh
        self.data = np.zeros(FRAME_LAYOUT["sh_light"] + 8 * n_sh, np.float32)
        self.buffers = [ctx.buffer(reserve=self.data.nbytes) for _ in range(_FRAME_BUFFERS)]
        self.buffer = self.buffers[0]
        self._next = 0
        self._written: np.ndarray | None = None  # what self.buffer holds

    def set(self, name: str, value) -> None:
        """A scalar or vector member."""
        v = np.asarray(value, np.float32).reshape(-1)
        o = FRAME_LAYOUT[name]
        self.data[o : o + v.size] = v

    def set_columns(self, name: str, columns) -> None:
        """A mat3 member from its ``(3, 3)`` columns (row ``j`` = column ``j``)."""
        o = FRAME_LAYOUT[name]
        self.data[o : o + 12].reshape(3, 4)[:, :3] = np.asarray(columns, np.float32)

    def set_sh(self, name: str, coeffs) -> None:
        """``sh_light`` or ``sh_sun`` from ``(N_SH, 3)`` coefficients."""
        o = FRAME_LAYOUT["sh_light"] + (4 * self.n_sh if name == "sh_sun" else 0)
        rows = self.data[o : o + 4 * self.n_sh].reshape(self.n_sh, 4)
        rows[:, :3] = np.asarray(coeffs, np.float32)

    def flush(self) -> bool:
        """Write the block if it changed; returns whether it wrote."""
        if self._written is not None and np.array_equal(self.data, self._written):
            return False
        self.buffer = self.buffers[self._next]
        self._next = (self._next + 1) % len(self.buffers)
        self.buffer.write(self.data.tobytes())
        self._written = self.data.copy()
        return True

    def release(self) -> None:
        for b in self.buffers:
            b.release()


class PassTimer:
    """GPU and CPU time of each pass of the frames a :class:`GLRenderer` draws while it is the
    renderer's :attr:`~GLRenderer.timer`; a frame is one ``draw`` and what follows it until the
    next (``present``).

    Passes: ``uniforms`` (the per-frame block), ``shadow`` (the sun's shadow map, when it is
    redrawn), ``lobe visibility`` (a rough lobe's correction, render/_lobe_visibility.py),
    ``stage`` (the vertex stage's results, once per frame), ``clear``, ``depth`` (the object's
    depth pre-pass), ``prt`` (the object's shading), ``background``, ``resolve`` (adding a
    sample into the frame, with several samples per pixel), ``tonemap`` (``present``); a pass
    run once per sample sums over the samples.

    GPU time: one GL_TIME_ELAPSED query (core in GL 3.3) around each pass, from when the GPU
    reaches its first command to its last. On llvmpipe it is CPU wall-clock time taken by its
    rasteriser threads, which work through a frame tile by tile with the passes interleaved:
    the sum over the passes roughly follows the frame's time but the split between them does
    not (vertex shading runs inside the draw call there, so it counts as the pass's CPU time,
    and a pass that samples what an earlier one drew waits for it in its CPU time). Every
    query is read by :meth:`summary` after ``ctx.finish()``, never during the frames, so
    timing does not make the CPU wait for the GPU; a query is reused only after it was read.
    CPU time: wall-clock seconds spent in the pass's calls (with a GPU driver: building and
    submitting its commands). ``frames``: how many frames are recorded (later frames are not
    timed). Without timer queries (a query cannot be made, its result cannot be read, or every
    result is zero) :meth:`summary` has no GPU times.
    """

    def __init__(self, ctx, frames: int = 64):
        self.ctx = ctx
        self.max_frames = int(frames)
        self._frames: list[list[tuple[str, object, float]]] = []
        self._current: list | None = None
        self._active = False  # TIME_ELAPSED queries cannot nest
        self._free: list = []
        try:
            self._free.append(ctx.query(time=True))
            self.gpu = True
        except Exception:
            self.gpu = False

    def new_frame(self) -> None:
        """Start recording a frame (nothing once ``frames`` frames are recorded)."""
        if len(self._frames) >= self.max_frames:
            self._current = None
            return
        self._current = []
        self._frames.append(self._current)

    @contextlib.contextmanager
    def section(self, name: str):
        """Time the calls inside as pass ``name`` of the current frame."""
        rec = self._current
        if rec is None or self._active:
            yield
            return
        q = None
        if self.gpu:
            q = self._free.pop() if self._free else self.ctx.query(time=True)
        self._active = True
        if q is not None:
            q.mglo.begin()
        t0 = time.perf_counter()
        try:
            yield
        finally:
            cpu = time.perf_counter() - t0
            if q is not None:
                q.mglo.end()
            self._active = False
            rec.append((name, q, cpu))

    def summary(self) -> dict:
        """Mean time per recorded frame of each pass, in ms (call after ``ctx.finish()``).

        Returns
        -------
        ``{"frames": n, "cpu_ms": {pass: ms}, "gpu_ms": {pass: ms}}`` in the order the passes
        first ran; ``gpu_ms`` is absent without timer queries. The records are cleared.
        """
        n = max(len(self._frames), 1)
        cpu: dict[str, float] = {}
        gpu: dict[str, float] = {}
        ok = self.gpu
        for frame in self._frames:
            for name, q, t in frame:
                cpu[name] = cpu.get(name, 0.0) + t
                if q is None:
                    continue
                if ok:
                    try:
                        gpu[name] = gpu.get(name, 0.0) + float(q.elapsed)
                    except Exception:
                        ok = False
                self._free.append(q)
        out = {"frames": len(self._frames), "cpu_ms": {k: 1e3 * v / n for k, v in cpu.items()}}
        if ok and sum(gpu.values()) > 0:
            out["gpu_ms"] = {k: 1e-6 * gpu.get(k, 0.0) / n for k in cpu}
        self._frames, self._current = [], None
        return out


class GLRenderer:
    """Shader implementation behind :class:`lobelight.render.Renderer` (``backend="gl"``).

    ``offsets`` ``(S, 2)``: the sub-pixel sample positions in ``[0, 1)`` (x right, y down) of
    each frame (:func:`lobelight.render.sample_offsets`); default the pixel centre. With more
    than one, each sample is a pass with the image shifted by its offset (frame.glsl's
    ``jitter``), added into :attr:`color` with weight ``1 / S``: the frame is the box-filtered
    average of the samples and its alpha the fraction of them on the object.

    ``hdr_dtype``: the colour targets' texel type, ``"f4"`` (RGBA32F: :meth:`read` returns the
    shaded floats) or ``"f2"`` (RGBA16F, 11 significant bits: enough for :meth:`present`'s
    8-bit display, half the memory traffic); :meth:`set_hdr_dtype` changes it.

    Per frame the CPU fills frame.glsl's block and writes it when it changed (one buffer write;
    none for a frame like the one before); uniforms outside it are written when their value
    changes. Each sample draws the object's depth first (:attr:`depth_prepass`, default on),
    then shades the object where its depth is the pre-pass's, so every covered pixel runs the
    fragment stage once (back faces drawn before the front ones would run it too), then the
    background where the object left the far plane. A closed surface wound outward
    (:func:`lobelight.geometry.adjacency.encloses_outward`) is drawn without its triangles seen
    from behind (:attr:`cull`): from outside it they lie behind others, so the picture does not
    change. :attr:`timer`: a :class:`PassTimer` to time each pass of the next frames (None:
    untimed).
    """

    def __init__(
        self,
        model,
        lighting: Lighting,
        width: int,
        height: int,
        *,
        ctx=None,
        offsets=None,
        hdr_dtype: str = "f4",
    ):
        self.ctx = ctx if ctx is not None else create_context()
        self.own_ctx = ctx is None
        self.make_current()
        self.width, self.height = int(width), int(height)
        self.ctx.enable_direct(_GL_TEXTURE_CUBE_MAP_SEAMLESS)
        self.timer: PassTimer | None = None
        self._uniform_values: dict = {}  # (program, name) -> the value written last
        n_sh = int(model.diffuse.shape[1])
        if n_sh != lighting.sh.shape[0]:
            raise InputError(
                "lighting", f"has {lighting.sh.shape[0]} SH coefficients, the model {n_sh}"
            )
        pf = self._choose_shading(model, lighting)
        self.planes_ubo, self.cand_tex, geo_defines = upload_geodesic(self.ctx)
        self._compile_programs(model, n_sh, geo_defines)
        tex_width = self._upload_transfer(model)
        self._upload_lighting(lighting, pf)
        self._connect_programs(tex_width)
        self._make_frame_block(n_sh)
        self._upload_mesh(model, lighting)
        self.center, self.radius = _bounding_sphere(model.mesh)
        self._make_shadow_map(lighting)
        self._make_screen_passes()
        self._make_targets(hdr_dtype)
        self.set_offsets(offsets)

    def _choose_shading(self, model, lighting: Lighting) -> Prefiltered:
        """Which parts the programs shade (a sun, its glossy reflection per pixel, the bounce
        it lights) and the chain the Gaussians read, which they return."""
        # the sun's glossy reflection per pixel where the BRDF allows (render/_sun_glossy.py);
        # the Gaussians then integrate the map without the sun
        spec = model.materials.specular
        self._specular, self._n_vertices = spec, model.mesh.n_vertices
        self.has_sun = lighting.sun is not None
        self.sun_glossy = self.has_sun and sun_glossy_supported(spec)
        # a sharp lobe's direct light per pixel (render/_reflection.py), and the vertices' hit
        # tiles as the shaders read them (none finds the object: its code is compiled out)
        self.sharp = sharp_lobe(spec)
        self._hit_slots = None if self.sharp is None else hit_atlases(model.hit_texels())
        self.hits_found = self.sharp is not None and model.sees_itself()
        # ... and whether it reads the sun's shape (prt.glsl SUN_SHAPE)
        self.sun_shape = self._reads_sun_shape(lighting)
        # a closed surface wound outward: its triangles seen from behind are left out
        self.cull = model.mesh.encloses_outward
        # a rough lobe's direct Gaussians corrected for what the object blocks
        # (render/_lobe_visibility.py)
        self.lobe_vis = lobe_visibility_applies(model)
        # the interreflected part of the transfer, lit by the sun as well (Model.bounce)
        self.has_bounce = model.bounce is not None and self.has_sun
        self.lighting = lighting
        # the glossy light scaled per pixel by the textures' F0 (render/_albedo.py)
        self._f0 = specular_f0(model)
        pf = lighting.rest_prefiltered if self.sun_glossy else lighting.prefiltered
        self.n_levels = len(pf.levels)
        return pf

    def _reads_sun_shape(self, lighting: Lighting) -> bool:
        """Whether a sharp lobe reads the sun's shape under ``lighting`` (prt.glsl
        ``sun_shape``, :func:`lobelight.render.layout.sun_shape_resolved`)."""
        if self.sharp is None or lighting.sun is None:
            return False
        if not sun_glossy_supported(self._specular):
            return False
        return sun_shape_resolved(self.sharp, float(lighting.sun.spread))

    def _compile_programs(self, model, n_sh: int, geo_defines: dict) -> None:
        """The object's shading and depth pre-pass programs (prt.glsl), the background's, the
        tone mapping's, the sample accumulation's and the shadow map's."""
        ctx = self.ctx
        prt_defines = {
            "N_GAUSSIANS": model.n_gaussians,
            "N_INDIRECT": model.indirect_gaussians,
            "N_SH": n_sh,
            "MAX_LEVELS": self.n_levels,
            "FLOOR": f"{model_module.LIVE_FLOOR:.6e}",
            "MIN_SAY": f"{model_module.MIN_SAY:.6e}",
            "HAS_BOUNCE": int(self.has_bounce),
            "HAS_SUN": int(self.has_sun),
            "SUN_GLOSSY": int(self.sun_glossy),
            "SUN_SHAPE": int(self.sun_shape),
            "SHARP": int(self.sharp is not None),
            "ALBEDO_TEX": int(model.albedo is not None),
            "ALBEDO_LAYERS": 1 if model.albedo is None else len(model.albedo.images),
            "SPECULAR_TEX": int(self._f0 is not None),
            "F0_MIN": f"{F0_MIN:.6e}",
            "LOBE_VIS": int(self.lobe_vis),
            "LOBE_VIS_PASS": 0,
            "STAGE_PASS": 0,
            "FROM_STAGE": 0,
            "STAGE_TEXELS": stage_texels(model),
            "STAGE_PER_ROW": stage_layout(model)[0],
            **lobe_visibility_defines(),
            "VIS_RES": VISIBILITY_RES,
            "ALBEDO_STEPS": ALBEDO_STEPS,
            **sharp_shader_defines(self.sharp, hit_tiles=self.hits_found),
            "SHADOW_SAMPLES": SHADOW_SAMPLES,
            "BLOCKER_SAMPLES": BLOCKER_SAMPLES,
            **geo_defines,
        }
        include = ("frame", "prefiltered")
        include += ("brdf",) if self.sun_glossy else ()
        include += ("stage", "tiles", "reflection") if self.sharp else ()
        include += ("albedo",) if model.albedo is not None else ()
        # the vertex stage once per frame, captured by transform feedback (prt.glsl STAGE_PASS)
        self.staged = stage_fits(model)
        if self.sharp is not None and not self.staged:
            raise InputError(
                "model",
                f"has {model.n_gaussians} Gaussians per view; a sharp material's per-pixel "
                "reflection reads the vertex stage's capture, which holds at most "
                f"{(TRANSFORM_FEEDBACK_COMPONENTS // 4 - 2) // 2}",
            )
        self.prog = _program(
            ctx,
            "prt",
            {**prt_defines, "DEPTH_ONLY": 0, "FROM_STAGE": int(self.staged)},
            include=include,
            vertex_include=("frame", "geodesic", "stage"),
        )
        self.stage_prog = None
        if self.staged:
            vertex, _ = stage_sources(
                "prt", {**prt_defines, "DEPTH_ONLY": 0, "STAGE_PASS": 1},
                vertex_include=("frame", "geodesic"),
            )  # fmt: skip
            self.stage_prog = ctx.program(vertex_shader=vertex, varyings=stage_varyings(model))
        # the depth pre-pass: the object's depth alone, from the same projection code
        # (prt.glsl's project, invariant gl_Position) so that the shading pass's depths equal it
        self.depth_prog = _program(
            ctx, "prt", {**prt_defines, "DEPTH_ONLY": 1}, ("frame",), ("frame",)
        )
        self.depth_prepass = True
        # each vertex's factor on its direct Gaussians' light, once per frame
        self.lv_prog = None
        if self.lobe_vis:
            vertex, _ = stage_sources(
                "prt", {**prt_defines, "DEPTH_ONLY": 0, "LOBE_VIS": 0, "LOBE_VIS_PASS": 1},
                vertex_include=LOBE_VISIBILITY_INCLUDE,
            )  # fmt: skip
            self.lv_prog = ctx.program(vertex_shader=vertex, varyings=["v_rho"])
        self.bg_prog = _program(ctx, "background", {"N_SH": n_sh}, ("frame",), ("frame",))
        self.tm_prog = _program(ctx, "tonemap")
        self.acc_prog = _program(ctx, "accumulate")
        self.shadow_prog = _program(ctx, "shadow", {"N_SH": n_sh}, ("frame",), ("frame",))

    def _upload_transfer(self, model) -> int:
        """The model's transfer as data textures of one width (:func:`transfer_width`): the
        Gaussian records (:func:`upload_records`), the diffuse transfer ``(V, N_SH)`` RGB per
        texel and its interreflected part; returns the width in texels."""
        import moderngl  # optional (the gl extra)

        # the interreflected part of the transfer (Model.bounce); one vertex of zeros without
        table = model.bounce if self.has_bounce else torch.zeros_like(model.diffuse[:1])
        width = transfer_width(model, table)
        self.gauss_tex = upload_records(self.ctx, model, width)
        self.gauss_tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.diff_tex = self._data_texture(_wrap(_rgb0(model.diffuse), width)[0])
        self.bounce_tex = self._data_texture(_wrap(_rgb0(table), width)[0])
        if self.staged:  # the stage pass's capture, and the texture it is copied into
            _, stage_width, rows = stage_layout(model)
            self.stage_buf = self.ctx.buffer(reserve=16 * rows * stage_width)
            self.stage_tex = self.ctx.texture((stage_width, rows), 4, dtype="f4")
            self.stage_tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        if self.sharp is not None:
            self._upload_sharp(model)
        if self.lv_prog is not None:
            self._upload_lobe_visibility(model)
        self.albedo_tex = self.specular_tex = None
        if model.albedo is not None:
            self._upload_albedo(model.albedo)
        return width

    def _upload_albedo(self, albedo) -> None:
        """The albedo textures as one mipmapped half-float texture array
        (:func:`albedo_array`), and the uniforms that say how each layer is read."""
        import moderngl  # optional (the gl extra)

        layers = albedo_array(albedo)  # (L, H, W, 3)
        n, h, w = layers.shape[:3]
        self.albedo_tex = self.ctx.texture_array(
            (w, h, n), 3, np.ascontiguousarray(layers), dtype="f2"
        )
        self.albedo_tex.repeat_x = self.albedo_tex.repeat_y = True
        self.albedo_tex.build_mipmaps()
        self.albedo_tex.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        set_uniforms(self.prog, albedo_uniforms(albedo))
        if self._f0 is not None:
            f0 = albedo_array(albedo, specular=True)
            self.specular_tex = self.ctx.texture_array(
                (w, h, n), 3, np.ascontiguousarray(f0), dtype="f2"
            )
            self.specular_tex.repeat_x = self.specular_tex.repeat_y = True
            self.specular_tex.build_mipmaps()
            self.specular_tex.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)

    def _upload_visibility(self, model) -> int:
        """The vertices' visibility tiles as one R8 atlas (tiles.glsl); returns the tiles per
        row."""
        import moderngl  # optional (the gl extra)

        tiles = model.visibility().cpu().numpy()  # (V, R, R) uint8
        v, r = tiles.shape[0], tiles.shape[1]
        per_row = max(1, min(v, _VIS_TEX_WIDTH // r))
        atlas = _tile_atlas(tiles, per_row)
        self.vis_tex = self.ctx.texture((atlas.shape[1], atlas.shape[0]), 1, atlas, dtype="f1")
        self.vis_tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        return per_row

    def _upload_lobe_visibility(self, model) -> None:
        """The lobe visibility correction's inputs (lobe_visibility.glsl): the visibility
        tiles; and its output, a buffer of one float32 RGB factor per vertex."""
        self.lv_prog["vis_per_row"].value = self._upload_visibility(model)
        self.rho_buf = self.ctx.buffer(reserve=12 * model.mesh.n_vertices)

    def _upload_sharp(self, model) -> None:
        """The per-pixel reflection's inputs (reflection.glsl): the vertices' visibility tiles,
        the triangles' corners and the vertices' positions as textures, and the material's
        lobe mixture and albedo table as uniforms."""
        import moderngl  # optional (the gl extra)

        per_row = self._upload_visibility(model)
        faces = model.mesh.faces.cpu().numpy().astype(np.int32)
        verts = model.mesh.vertices.detach().cpu().numpy().astype(np.float32)
        width = _VIS_TEX_WIDTH
        # the corners, then from nbr_offset the triangles across each edge (reflection.glsl
        # walk_to_hit)
        nbr_offset = -(-faces.shape[0] // width) * width
        fimg = np.zeros((2 * nbr_offset, 3), np.int32)
        fimg[: faces.shape[0]] = faces
        fimg[nbr_offset : nbr_offset + faces.shape[0]] = model.mesh.face_neighbours.cpu().numpy()
        # (uploaded below and let go: a concave mesh's tiles are S x R^2 texels)
        slots, hit_face, hit_dist, hit_per_row = self._hit_slots
        self._hit_slots = None
        pimg = np.zeros((-(-verts.shape[0] // width) * width, 3), np.float32)
        pimg[: verts.shape[0]] = verts
        self.face_tex = self.ctx.texture(
            (width, fimg.shape[0] // width), 3, np.ascontiguousarray(fimg), dtype="i4"
        )
        # the positions and each vertex's hit-tile slot (exact in float32)
        pos = np.zeros((pimg.shape[0], 4), np.float32)
        pos[:, :3] = pimg
        pos[: verts.shape[0], 3] = slots
        self.pos_tex = self.ctx.texture((width, pimg.shape[0] // width), 4, pos, dtype="f4")
        nimg = np.zeros_like(pimg)
        nimg[: verts.shape[0]] = model.mesh.normals.detach().cpu().numpy()
        aimg = np.zeros_like(pimg)
        aimg[: verts.shape[0]] = model.materials.diffuse.detach().cpu().numpy()
        size = (width, pimg.shape[0] // width)
        self.nrm_tex = self.ctx.texture(size, 3, np.ascontiguousarray(nimg), dtype="f4")
        self.alb_tex = self.ctx.texture(size, 3, np.ascontiguousarray(aimg), dtype="f4")
        self.hit_face_tex = self.ctx.texture(
            (hit_face.shape[1], hit_face.shape[0]), 1, hit_face, dtype="i4"
        )
        self.hit_dist_tex = self.ctx.texture(
            (hit_dist.shape[1], hit_dist.shape[0]), 1, hit_dist, dtype="f2"
        )
        for t in (self.face_tex, self.pos_tex, self.nrm_tex, self.alb_tex, self.hit_face_tex,
                  self.hit_dist_tex):  # fmt: skip
            t.filter = (moderngl.NEAREST, moderngl.NEAREST)
        p, sh = self.prog, self.sharp
        # without hit tiles the hits' code is compiled out, and with a lobe the same at every
        # vertex the pixel's corners with it
        for name, value in (("face_width", width), ("vis_per_row", per_row),
                            ("hit_per_row", hit_per_row), ("nbr_offset", nbr_offset)):  # fmt: skip
            _set_uniform(p, name, value)
        _set_uniform(p, "sharp_weight", [float(x) for x in sh.weights])
        p["sharp_warp"].value = float(sh.warp)
        self.lobe_tex = self.split_tex = None
        if sh.sharp is None:
            _set_uniform(p, "sharp_lam", [float(x) for x in sh.lam])
            p["sharp_albedo"].value = [tuple(float(c) for c in row) for row in sh.albedo]
            return
        # a lobe per vertex: the mixture at the reference roughness, each vertex's roughness
        # (negative where the Gaussians shade it) and F0, and the albedo's split table
        lam, lobe, split = varying_lobe_arrays(sh)
        _set_uniform(p, "sharp_lam", lam)
        limg = np.zeros((pimg.shape[0], 4), np.float32)
        limg[: verts.shape[0]] = lobe
        self.lobe_tex = self.ctx.texture(size, 4, np.ascontiguousarray(limg), dtype="f4")
        self.split_tex = self.ctx.texture(
            (split.shape[1], split.shape[0]), 2, np.ascontiguousarray(split), dtype="f4"
        )
        for t in (self.lobe_tex, self.split_tex):
            t.filter = (moderngl.NEAREST, moderngl.NEAREST)

    def _use_vertex_stage_textures(self) -> None:
        """The textures prt.glsl's vertex stage reads (the records, the diffuse transfer, the
        view triangles' candidates, the bounce's transfer) on their units."""
        self.gauss_tex.use(0)
        self.diff_tex.use(1)
        self.cand_tex.use(2)
        if self.has_bounce:
            self.bounce_tex.use(8)

    def _stage_pass(self) -> None:
        """The vertex stage's results for this frame's view and lighting (prt.glsl STAGE_PASS)
        into ``stage_tex``, by transform feedback, one vertex per vertex: each sample's shading
        pass then reads them (FROM_STAGE) instead of interpolating the views again."""
        import moderngl  # optional (the gl extra)

        with self._section("stage"):
            self.fbo.use()  # a draw needs a complete framebuffer, though this one rasterises none
            self._use_vertex_stage_textures()
            self.stage_vao.transform(
                self.stage_buf, mode=moderngl.POINTS, vertices=self._n_vertices
            )
            self.stage_tex.write(self.stage_buf)

    def _lobe_visibility_pass(self) -> None:
        """Each vertex's factor on its direct Gaussians' light for this frame's view and
        lighting into ``rho_buf``, by transform feedback of the correction's vertex stage
        (one vertex per vertex: the vertex stage runs many vertices at once, where a point per
        vertex would shade a block of pixels for one), read by the shading pass's vertices."""
        import moderngl  # optional (the gl extra)

        with self._section("lobe visibility"):
            # a draw needs a complete framebuffer bound, though this one rasterises nothing
            self.fbo.use()
            self._use_vertex_stage_textures()
            self.atlas.use(3)
            self.vis_tex.use(_VIS_UNIT)
            self.lv_vao.transform(self.rho_buf, mode=moderngl.POINTS, vertices=self._n_vertices)

    def _upload_lighting(self, lighting: Lighting, pf: Prefiltered) -> None:
        """The chain's atlas and the background's cube map."""
        import moderngl  # optional (the gl extra)

        self.atlas, self._atlas_uniforms = upload_prefiltered(self.ctx, pf)
        self.whole_atlas = None
        self._upload_whole(lighting)
        self.env_cube = self.ctx.texture_cube(
            (BACKGROUND_RES,) * 2, 3, np.ascontiguousarray(_background(lighting)), dtype="f4"
        )
        self.env_cube.filter = (moderngl.LINEAR, moderngl.LINEAR)

    def _upload_whole(self, lighting: Lighting) -> None:
        """A sharp lobe's view of the sun's shape (prt.glsl ``sun_shape``): the analytic
        highlight's tail factor (render/_sun_glossy.py ``tail_scale``) and, where a Gaussian of
        the mixture resolves the sun's disc, the whole map's chain as a second atlas of the
        first's layout (:attr:`whole_atlas`, None otherwise: nothing reads it)."""
        if self.whole_atlas is not None:
            self.whole_atlas.release()
            self.whole_atlas = None
        if self.sharp is None or not self.sun_glossy:
            return
        spread = float(lighting.sun.spread)
        if self.sharp.sharp is None:  # a lobe per vertex has its tail per point
            self.prog["sun_tail"].value = tail_scale(self._specular, spread)
        if not self.sun_shape:
            return
        (height, width), _, _ = atlas_layout(lighting.prefiltered)
        if (height, width) != (self.atlas.height, self.atlas.width):
            raise InputError("lighting", "the whole map's chain differs in layout from its rest's")
        tex = self.ctx.texture((width, height), 4, dtype="f4")
        write_atlas(tex, lighting.prefiltered)
        tex.filter = self.atlas.filter
        self.whole_atlas = tex

    def _connect_programs(self, tex_width: int) -> None:
        """The programs' uniform-block bindings, texture units and the uniforms that hold for
        the renderer's life."""
        p = self.prog
        if p.get("tex_width", None) is not None:  # read by the vertex stage, when not captured
            p["tex_width"].value = tex_width
        set_uniforms(p, self._atlas_uniforms)
        p["Planes"].binding = _PLANES_BINDING
        table = tuple(t for t in (self.lv_prog, self.stage_prog) if t is not None)
        if self.lv_prog is not None:
            set_uniforms(self.lv_prog, self._atlas_uniforms)
            set_uniforms(self.lv_prog, sun_glossy_uniforms(self._specular))
            self.lv_prog["lv_samples"].value = LOBE_VISIBILITY_SAMPLES
        for t in table:
            t["tex_width"].value = tex_width
            t["Planes"].binding = _PLANES_BINDING
        for prog in (p, self.depth_prog, self.bg_prog, self.shadow_prog, *table):
            for block, binding in (("Frame", _FRAME_BINDING), ("Sample", _SAMPLE_BINDING)):
                if prog.get(block, None) is not None:  # the shadow pass has no jitter
                    prog[block].binding = binding
        units = (
            ("gauss_tex", 0),
            ("diff_tex", 1),
            ("cand_tex", 2),
            ("atlas", 3),
            ("whole_atlas", _WHOLE_ATLAS_UNIT),
            ("shadow_map", 6),
            ("bounce_tex", 8),
            ("shadow_depth", _SHADOW_DEPTH_UNIT),
            ("vis_tex", _VIS_UNIT),
            ("face_tex", _VIS_UNIT + 1),
            ("pos_tex", _VIS_UNIT + 2),
            ("albedo_tex", _ALBEDO_UNIT),
            ("specular_tex", _ALBEDO_UNIT + 1),
            ("lobe_tex", _LOBE_UNIT),
            ("split_tex", _LOBE_UNIT + 1),
            ("stage_tex", _STAGE_UNIT),
            *_SHARP_UNITS,
        )
        for prog in (p, *table):
            for name, unit in units:
                if prog.get(name, None) is not None:  # compiled out without a sun or a bounce
                    prog[name].value = unit
        self.bg_prog["env"].value = 4
        self.tm_prog["image"].value = 5
        self.acc_prog["image"].value = 7

    def _make_frame_block(self, n_sh: int) -> None:
        """frame.glsl's block (:class:`_FrameBlock`), checked against the compiled one."""
        self.frame_block = _FrameBlock(self.ctx, n_sh)
        size = self.prog["Frame"].size
        if size != self.frame_block.data.nbytes:  # frame.glsl and FRAME_LAYOUT disagree
            raise RuntimeError(
                f"Frame block of {size} bytes, expected {self.frame_block.data.nbytes}"
            )
        self._camera: Camera | None = None  # the camera and rotation the block holds
        self._rot: np.ndarray | None = None
        self._sun_frame: np.ndarray | None = None  # (3, 3) rows: the shadow map's frame

    def _upload_mesh(self, model, lighting: Lighting) -> None:
        """The vertex and index buffers, the per-vertex inputs of the sun's shading when there
        is a sun, and the object's vertex arrays (shading and depth pre-pass)."""
        ctx, p, mesh = self.ctx, self.prog, model.mesh
        verts = mesh.vertices.detach().cpu().numpy().astype(np.float32)
        faces_np = mesh.faces.cpu().numpy().astype(np.uint32)
        self.vbo = ctx.buffer(np.ascontiguousarray(verts))
        self.ibo = ctx.buffer(np.ascontiguousarray(faces_np))
        normals = mesh.normals.detach().cpu().numpy().astype(np.float32)
        self.nbo = ctx.buffer(np.ascontiguousarray(normals))
        content = [(self.vbo, "3f", "in_pos"), (self.nbo, "3f", "in_normal")]
        self.abo = self.sbo = None  # per-vertex inputs of the sun's shading, when it has one
        if self.has_sun and model.albedo is None:  # else the sun reads the textures' albedo
            albedo = model.materials.diffuse.detach().cpu().numpy().astype(np.float32)
            self.abo = ctx.buffer(np.ascontiguousarray(albedo))
            content.append((self.abo, "3f", "in_albedo"))
        self.uvbo = None  # the albedo textures' per-vertex inputs, when the model has them
        if model.albedo is not None:
            a = model.albedo
            layer = a.layer.detach().cpu().numpy().astype(np.float32)[:, None]
            attrs = np.concatenate(
                [a.uvs.detach().cpu().numpy(), layer, a.factor.detach().cpu().numpy()], axis=1
            ).astype(np.float32)
            fmt, names = "2f 1f 3f", ("in_uv", "in_layer", "in_factor")
            if self._f0 is not None:
                attrs = np.concatenate([attrs, self._f0.cpu().numpy().astype(np.float32)], 1)
                fmt, names = fmt + " 3f", (*names, "in_f0")
            self.uvbo = ctx.buffer(np.ascontiguousarray(attrs, np.float32))
            content.append((self.uvbo, fmt, *names))
        if self.sun_glossy:
            spec = self._specular
            sb = sun_glossy_vertex_params(sun_widened(spec, lighting.sun.spread), mesh.n_vertices)
            set_uniforms(p, sun_glossy_uniforms(spec))
            if p.get("sun_spread", None) is not None:  # compiled out without indirect lobes
                p["sun_spread"].value = float(lighting.sun.spread)
            self.sbo = ctx.buffer(np.ascontiguousarray(sb))
            content.append((self.sbo, "4f 3f 3f", "in_sb0", "in_eta", "in_k"))
        # the vertex stage reads the correction pass's factors (prt.glsl in_rho)
        stage = content
        if self.lv_prog is not None:
            stage = [*content, (self.rho_buf, "3f", "in_rho")]
        self.stage_vao = None
        if self.staged:
            self.stage_vao = ctx.vertex_array(self.stage_prog, stage, skip_errors=True)
        shading = content if self.staged else stage
        self.vao = ctx.vertex_array(p, shading, self.ibo, 4, skip_errors=True)
        self.lv_vao = None
        if self.lv_prog is not None:
            # the BRDF as it is (the sun's shading reads it widened by the disc)
            lv = sun_glossy_vertex_params(self._specular, mesh.n_vertices)
            self.lvbo = ctx.buffer(np.ascontiguousarray(lv))
            base = [c for c in content if c[0] is not self.sbo]
            self.lv_vao = ctx.vertex_array(
                self.lv_prog,
                [*base, (self.lvbo, "4f 3f 3f", "in_sb0", "in_eta", "in_k")],
                skip_errors=True,
            )
        self.depth_vao = ctx.vertex_array(
            self.depth_prog, [(self.vbo, "3f", "in_pos")], self.ibo, 4
        )

    def _make_shadow_map(self, lighting: Lighting) -> None:
        """The sun's shadow map, its framebuffer and vertex array (a 1-texel stand-in without
        a sun), and the frame block's values that hold still while the light turns."""
        import moderngl  # optional (the gl extra)

        ctx = self.ctx
        self.shadow_res = SHADOW_RES if self.has_sun else 1
        self.shadow_tex = ctx.depth_texture((self.shadow_res,) * 2)
        self.shadow_tex.compare_func = "<="
        self.shadow_tex.filter = (moderngl.LINEAR, moderngl.LINEAR)  # 2x2 PCF
        self.shadow_tex.repeat_x = self.shadow_tex.repeat_y = False
        # the same depths read without comparison, for the soft shadow's blocker search
        self.shadow_sampler = ctx.sampler(
            texture=self.shadow_tex,
            filter=(moderngl.NEAREST, moderngl.NEAREST),
            repeat_x=False,
            repeat_y=False,
        )
        self.shadow_sampler.compare_func = ""
        self.shadow_fbo = ctx.framebuffer(depth_attachment=self.shadow_tex)
        self.shadow_vao = ctx.vertex_array(
            self.shadow_prog, [(self.vbo, "3f", "in_pos")], self.ibo, 4
        )
        self._shadow_key = None  # the sun frame the shadow map was last rendered for
        if self.has_sun:  # what the sun's shading holds still while the light turns
            blk = self.frame_block
            scale = 1.0 / (1.02 * self.radius)
            texel = 2.0 / (scale * self.shadow_res)  # world size of a shadow-map texel
            blk.set("sun_e", [float(x) for x in lighting.sun.irradiance])
            blk.set("shadow_center", self.center)
            blk.set("shadow_scale", scale)
            blk.set("shadow_offset", 1.5 * texel)
            blk.set("shadow_bias", 1.0 / self.shadow_res)
            self._uniform(self.prog, "shadow_res", float(self.shadow_res))
            self._uniform(self.prog, "sun_tan", math.tan(disc_radius(lighting.sun)))

    def _make_screen_passes(self) -> None:
        """The full-screen quad and the vertex arrays of the passes that cover the frame:
        background, tone mapping, sample accumulation."""
        ctx = self.ctx
        quad = np.array([-1, -1, 1, -1, -1, 1, 1, 1], np.float32)
        self.quad = ctx.buffer(quad.tobytes())
        self.bg_vao = ctx.vertex_array(self.bg_prog, [(self.quad, "2f", "in_xy")])
        self.tm_vao = ctx.vertex_array(self.tm_prog, [(self.quad, "2f", "in_xy")])
        self.acc_vao = ctx.vertex_array(self.acc_prog, [(self.quad, "2f", "in_xy")])

    def _make_targets(self, hdr_dtype: str) -> None:
        """The frame's depth buffer and colour target (:meth:`set_hdr_dtype`), and the stride
        of the sample records (:meth:`set_offsets` writes them)."""
        self.depth = self.ctx.depth_renderbuffer((self.width, self.height))
        # a texture (not a renderbuffer) so that the window's tone-mapping pass can read it
        self.color = self.fbo = None
        # the per-sample pass's target when there are several samples (made on first use)
        self._pass_color = self._pass_fbo = None
        self.hdr_dtype = None
        self.set_hdr_dtype(hdr_dtype)
        # the sample records of frame.glsl's Sample block, one per sample at the alignment GL
        # requires of a bound range
        align = int(self.ctx.info.get("GL_UNIFORM_BUFFER_OFFSET_ALIGNMENT", 256))
        self._sample_stride = max(16, -(-align // 16) * 16)
        self.sample_ubo = None

    def make_current(self) -> None:
        """Make the renderer's context current when the renderer made it
        (:func:`make_current`); every method that issues GL commands starts here."""
        make_current(self.ctx, self.own_ctx)

    def set_lighting(self, lighting: Lighting) -> bool:
        """Light the next frames by ``lighting``: its chain, background, SH and sun written
        into this renderer's textures, buffers and uniforms in place (no program, model data
        or target is made again).

        Returns False, changing nothing, when the programs were compiled for another kind of
        lighting: a sun where there was none or none where there was one, a sun whose shape
        a sharp lobe reads where it read none's or the reverse, or another number of SH
        coefficients or chain layout (base resolution, levels); then a new renderer is
        needed.
        """
        self.make_current()
        sun_glossy = lighting.sun is not None and sun_glossy_supported(self._specular)
        pf = lighting.rest_prefiltered if sun_glossy else lighting.prefiltered
        if (
            (lighting.sun is not None) != self.has_sun
            or sun_glossy != self.sun_glossy
            or lighting.sh.shape[0] != self.frame_block.n_sh
            or len(pf.levels) != self.n_levels
            or pf.base_res != int(self._atlas_uniforms["level_res"][0])
            or float(pf.lambdas[0]) != self._atlas_uniforms["lam0"]
            or self._reads_sun_shape(lighting) != self.sun_shape
        ):
            return False
        write_atlas(self.atlas, pf)
        self._upload_whole(lighting)
        for face, data in enumerate(_background(lighting)):
            self.env_cube.write(face, np.ascontiguousarray(data))
        if self.has_sun:
            sun = lighting.sun
            self.frame_block.set("sun_e", [float(x) for x in sun.irradiance])
            self._uniform(self.prog, "sun_tan", math.tan(disc_radius(sun)))
            if self.sun_glossy:
                sb = sun_glossy_vertex_params(
                    sun_widened(self._specular, sun.spread), self._n_vertices
                )
                self.sbo.write(sb.tobytes())
                if self.prog.get("sun_spread", None) is not None:
                    self._uniform(self.prog, "sun_spread", float(sun.spread))
        self.lighting = lighting
        # the rotation-dependent values (SH, the sun's direction) and the shadow map follow
        # the new lighting at the next frame
        self._rot = None
        self._shadow_key = None
        return True

    def time_passes(self, frames: int = 64) -> PassTimer:
        """Attach a new :class:`PassTimer` as :attr:`timer` for the next ``frames`` frames and
        return it (read it with :meth:`PassTimer.summary` after ``ctx.finish()``; set
        :attr:`timer` to None to stop timing)."""
        self.make_current()
        self.timer = PassTimer(self.ctx, frames)
        return self.timer

    def set_hdr_dtype(self, dtype: str) -> None:
        """The colour targets' texel type (``"f4"`` or ``"f2"``, see the class); their
        content is undefined until the next :meth:`draw`."""
        self.make_current()
        if dtype not in HDR_DTYPES:
            raise InputError("hdr_dtype", f"must be one of {HDR_DTYPES}, got {dtype!r}")
        if dtype == self.hdr_dtype:
            return
        self.hdr_dtype = dtype
        for o in (self.fbo, self.color, self._pass_fbo, self._pass_color):
            if o is not None:
                o.release()
        size = (self.width, self.height)
        self.color = self.ctx.texture(size, 4, dtype=dtype)
        self.fbo = self.ctx.framebuffer([self.color], self.depth)
        if self._pass_color is not None:
            self._pass_color = self.ctx.texture(size, 4, dtype=dtype)
            self._pass_fbo = self.ctx.framebuffer([self._pass_color], self.depth)

    def set_offsets(self, offsets=None) -> None:
        """The sub-pixel sample positions ``(S, 2)`` of the next frames (None: the centre)."""
        self.make_current()
        off = np.full((1, 2), 0.5) if offsets is None else np.asarray(offsets, np.float64)
        if off.ndim != 2 or off.shape[1] != 2 or off.shape[0] < 1:
            raise InputError("offsets", f"expected (S, 2) sub-pixel positions, got {off.shape}")
        if not bool(np.all((off >= 0) & (off < 1))):
            raise InputError("offsets", "sub-pixel positions must lie in [0, 1)")
        self.offsets = off
        if off.shape[0] > 1 and self._pass_fbo is None:
            size = (self.width, self.height)
            self._pass_color = self.ctx.texture(size, 4, dtype=self.hdr_dtype)
            self._pass_fbo = self.ctx.framebuffer([self._pass_color], self.depth)
        stride = self._sample_stride // 4
        rec = np.zeros((off.shape[0], stride), np.float32)
        rec[:, :2] = [self._jitter(o) for o in off]  # a loop over samples, not pixels
        taps = [sample_taps(i, off.shape[0]) for i in range(off.shape[0])]
        rec[:, 2:4] = [(t.start, t.step) for t in taps]  # frame.glsl's tap_first, tap_step
        if self.sample_ubo is not None:
            self.sample_ubo.release()
        self.sample_ubo = self.ctx.buffer(rec.tobytes())
        self._uniform(self.acc_prog, "weight", 1.0 / off.shape[0])
        if self.albedo_tex is not None:
            # each of the S samples covers 1/S of the pixel: the texture's footprint per sample
            # shrinks by sqrt(S) across, so the samples together average the pixel's texels
            self._uniform(self.prog, "albedo_grad_scale", float(off.shape[0]) ** -0.5)

    def _jitter(self, offset) -> tuple[float, float]:
        """The NDC shift that puts the sample at ``offset`` (x right, y down) under the pixel
        centre (GL's y runs up)."""
        return (2.0 * (0.5 - offset[0]) / self.width, 2.0 * (offset[1] - 0.5) / self.height)

    def _data_texture(self, img: np.ndarray):
        import moderngl  # optional (the gl extra)

        # the array itself (its buffer): no copy where it is float32 and contiguous already
        data = np.ascontiguousarray(img, dtype=np.float32)
        t = self.ctx.texture((img.shape[1], img.shape[0]), 4, data, dtype="f4")
        t.filter = (moderngl.NEAREST, moderngl.NEAREST)
        return t

    def _uniform(self, prog, name: str, value) -> None:
        """Write a uniform outside the frame block when its value differs from the last one
        written (programs keep uniform values)."""
        key = (prog.glo, name)
        if self._uniform_values.get(key) != value:
            prog[name].value = value
            self._uniform_values[key] = value

    def _section(self, name: str):
        """The timing of pass ``name`` (:class:`PassTimer`), or nothing when untimed."""
        return _UNTIMED if self.timer is None else self.timer.section(name)

    def _update_frame(self, camera: Camera, rot: torch.Tensor, diffuse: bool, glossy: bool):
        """Fill the frame block with what changed since the last frame and write it; returns
        whether the sun is shaded this frame."""
        blk = self.frame_block
        if camera != self._camera:  # a frozen dataclass: equal cameras look alike
            f = camera.frame(dtype=torch.float64).numpy()
            tx, ty = camera.tan_half(self.width, self.height)
            blk.set("cam_left", f[0])
            blk.set("cam_up", f[1])
            blk.set("cam_dir", f[2])
            blk.set("tan_half", (tx, ty))
            eye = np.asarray(camera.origin, np.float64)
            dist = float(np.linalg.norm(eye - self.center))
            near = max(dist - 1.01 * self.radius, 1e-3 * self.radius)
            blk.set("depth_range", (near, dist + 1.01 * self.radius))
            blk.set("eye", eye)
            self._camera = camera
        r = rot.detach().cpu().numpy().astype(np.float32)
        if self._rot is None or not np.array_equal(r, self._rot):
            blk.set_columns("rot_t", r)  # R^T's columns are R's rows
            blk.set_sh("sh_light", self.lighting.sh_rotated(rot).cpu().numpy())
            if self.has_bounce:
                blk.set_sh("sh_sun", self.lighting.sun_sh_rotated(rot).numpy())
            if self.has_sun:
                frame = sun_frame(self.lighting.sun_direction(rot).detach().cpu().numpy())
                self._sun_frame = frame.astype(np.float32)  # rows u, v, l
                blk.set_columns("shadow_frame", self._sun_frame.T)
                blk.set("sun_dir", frame[2])
            self._rot = r
        sun_on = self.has_sun and (diffuse or (glossy and self.sun_glossy))
        blk.set("diffuse_on", float(diffuse))
        blk.set("glossy_on", float(glossy))
        blk.set("sun_on", float(sun_on))
        blk.flush()
        return sun_on

    def _bind_blocks(self) -> None:
        """Bind the uniform buffers the programs read (another renderer on the context may
        have bound its own to the same points)."""
        self.frame_block.buffer.bind_to_uniform_block(_FRAME_BINDING)
        self.planes_ubo.bind_to_uniform_block(_PLANES_BINDING)

    def draw(
        self,
        camera: Camera,
        rot: torch.Tensor,
        *,
        diffuse: bool = True,
        glossy: bool = True,
        background: bool = True,
        fbo=None,
    ) -> None:
        """Render a frame into ``fbo`` (default the renderer's float framebuffer), one pass per
        sample of :attr:`offsets`."""
        import moderngl  # optional (the gl extra)

        self.make_current()

        if self.timer is not None:
            self.timer.new_frame()
        ctx = self.ctx
        out = fbo or self.fbo
        with self._section("uniforms"):
            sun_on = self._update_frame(camera, rot, diffuse, glossy)
            self._bind_blocks()
        if sun_on:
            self._shadow_pass()
        if self.lv_prog is not None and glossy:
            self._lobe_visibility_pass()
        if self.staged:
            self._stage_pass()
        n = self.offsets.shape[0]
        if n == 1:
            self._draw_sample(out, 0, background)
            return
        with self._section("clear"):
            out.use()
            ctx.viewport = (0, 0, self.width, self.height)
            out.clear(0.0, 0.0, 0.0, 0.0)
        for i in range(n):
            self._draw_sample(self._pass_fbo, i, background)
            with self._section("resolve"):
                out.use()
                ctx.viewport = (0, 0, self.width, self.height)
                ctx.disable(moderngl.DEPTH_TEST)
                ctx.enable(moderngl.BLEND)
                ctx.blend_func = moderngl.ONE, moderngl.ONE
                ctx.blend_equation = moderngl.FUNC_ADD
                self._pass_color.use(7)
                self.acc_vao.render(moderngl.TRIANGLE_STRIP)
                ctx.disable(moderngl.BLEND)

    def _draw_sample(self, fbo, i: int, background: bool) -> None:
        """Sample ``i`` of every pixel into ``fbo``: the object's depth, its shading where the
        depth is the front-most, then the background where the object left the depth at the far
        plane (the frame block is written by :meth:`draw`)."""
        import moderngl  # optional (the gl extra)

        ctx = self.ctx
        with self._section("clear"):
            fbo.use()
            ctx.viewport = (0, 0, self.width, self.height)
            if background:  # object and background write every pixel: clear the depth alone
                # (moderngl applies a framebuffer's colour mask when it is bound)
                fbo.color_mask = (False, False, False, False)
                fbo.use()
                fbo.clear(depth=1.0)
                fbo.color_mask = (True, True, True, True)
                fbo.use()
            else:
                fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        s = self._sample_stride
        self.sample_ubo.bind_to_uniform_block(_SAMPLE_BINDING, offset=i * s, size=16)
        ctx.enable(moderngl.DEPTH_TEST)
        if self.cull:
            ctx.enable(moderngl.CULL_FACE)
            ctx.cull_face = "back"
        if self.depth_prepass:
            with self._section("depth"):
                ctx.depth_func = "<"
                fbo.color_mask = (False, False, False, False)
                fbo.use()
                self.depth_vao.render(moderngl.TRIANGLES)
                fbo.color_mask = (True, True, True, True)
                fbo.use()
        with self._section("prt"):
            ctx.depth_func = "<=" if self.depth_prepass else "<"
            if self.has_sun:
                self.shadow_tex.use(6)
                self.shadow_sampler.use(_SHADOW_DEPTH_UNIT)
            if self.staged:
                self.stage_tex.use(_STAGE_UNIT)
            else:
                self._use_vertex_stage_textures()
            self.atlas.use(3)
            if self.whole_atlas is not None:
                self.whole_atlas.use(_WHOLE_ATLAS_UNIT)
            if self.albedo_tex is not None:
                self.albedo_tex.use(_ALBEDO_UNIT)
            if self.specular_tex is not None:  # set only beside albedo_tex
                self.specular_tex.use(_ALBEDO_UNIT + 1)
            if self.sharp is not None:
                self.vis_tex.use(_VIS_UNIT)
                self.face_tex.use(_VIS_UNIT + 1)
                self.pos_tex.use(_VIS_UNIT + 2)
                sharp_textures = (self.nrm_tex, self.alb_tex, self.hit_face_tex, self.hit_dist_tex)
                for (_, unit), tex in zip(_SHARP_UNITS, sharp_textures, strict=True):
                    tex.use(unit)
                if self.lobe_tex is not None:
                    self.lobe_tex.use(_LOBE_UNIT)
                    self.split_tex.use(_LOBE_UNIT + 1)
            self.vao.render(moderngl.TRIANGLES)
            ctx.disable(moderngl.CULL_FACE)
            if self.has_sun:  # the unit's sampler would override other textures bound there
                self.shadow_sampler.clear(_SHADOW_DEPTH_UNIT)
        if background:
            with self._section("background"):
                # the quad lies at the far plane: it passes where the depth is still clear
                ctx.depth_func = "<="
                self.env_cube.use(4)
                self.bg_vao.render(moderngl.TRIANGLE_STRIP)
                ctx.depth_func = "<"

    def _shadow_pass(self) -> None:
        """Render the sun's shadow map when its direction changed since the last one."""
        import moderngl  # optional (the gl extra)

        key = self._sun_frame.tobytes()
        if key == self._shadow_key:  # the map depends on the sun's direction alone
            return
        self._shadow_key = key
        ctx = self.ctx
        with self._section("shadow"):
            self.shadow_fbo.use()
            ctx.viewport = (0, 0, self.shadow_res, self.shadow_res)
            self.shadow_fbo.clear(depth=1.0)
            ctx.enable(moderngl.DEPTH_TEST)
            ctx.depth_func = "<"
            self.shadow_vao.render(moderngl.TRIANGLES)

    def present(self, screen, *, exposure: float = 0.0, curve: str = DEFAULT_CURVE) -> None:
        """Tone-map the last frame onto ``screen`` (a window's framebuffer) with display curve
        ``curve`` (one of :data:`lobelight.render._tonemap.CURVES`)."""
        import moderngl  # optional (the gl extra)

        self.make_current()

        with self._section("tonemap"):
            screen.use()
            self.ctx.disable(moderngl.DEPTH_TEST)
            self.color.use(5)
            self._uniform(self.tm_prog, "scale", float(2.0**exposure))
            self._uniform(self.tm_prog, "curve", CURVES.index(curve))
            self.tm_vao.render(moderngl.TRIANGLE_STRIP)

    def read(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The colour target as ``(H, W, 3)`` radiance and ``(H, W)`` float32 coverage (the
        fraction of the pixel's samples on the object); float32 values, of half-float
        precision when :attr:`hdr_dtype` is ``"f2"``."""
        self.make_current()
        raw = self.fbo.read(components=4, dtype="f4")
        img = np.frombuffer(raw, np.float32).reshape(self.height, self.width, 4)[::-1]
        img = torch.from_numpy(img.copy())
        return img[..., :3].contiguous(), img[..., 3].contiguous()

    def _lobe_visibility_objects(self) -> tuple:
        """The GL objects of the lobe visibility correction (released with the renderer)."""
        return (self.vis_tex, self.rho_buf, self.lv_vao, self.lvbo, self.lv_prog)

    def _sharp_objects(self) -> tuple:
        """The GL objects of the sharp reflection's hit points (released with the renderer)."""
        lobe = () if self.lobe_tex is None else (self.lobe_tex, self.split_tex)
        return (self.nrm_tex, self.alb_tex, self.hit_face_tex, self.hit_dist_tex, *lobe)

    def release(self) -> None:
        self.make_current()
        for o in (
            self._pass_fbo,
            self._pass_color,
            self.abo,
            self.sbo,
            self.uvbo,
            self.albedo_tex,
            self.specular_tex,
        ):
            if o is not None:
                o.release()
        for o in (
            self.vao,
            self.depth_vao,
            self.depth_prog,
            self.shadow_vao,
            self.shadow_fbo,
            self.shadow_sampler,
            self.shadow_tex,
            self.shadow_prog,
            self.nbo,
            self.bg_vao,
            self.tm_vao,
            self.acc_vao,
            self.vbo,
            self.ibo,
            self.quad,
            self.fbo,
            self.color,
            self.depth,
            self.gauss_tex,
            self.diff_tex,
            self.bounce_tex,
            *(
                (self.stage_vao, self.stage_prog, self.stage_buf, self.stage_tex)
                if self.staged
                else ()
            ),
            self.planes_ubo,
            self.sample_ubo,
            self.cand_tex,
            self.atlas,
            *(() if self.whole_atlas is None else (self.whole_atlas,)),
            self.env_cube,
            self.prog,
            self.bg_prog,
            self.tm_prog,
            self.acc_prog,
            *((self.vis_tex, self.face_tex, self.pos_tex) if self.sharp is not None else ()),
            *(self._sharp_objects() if self.sharp is not None else ()),
            *(self._lobe_visibility_objects() if self.lv_prog is not None else ()),
        ):
            o.release()
        self.frame_block.release()
        if self.own_ctx:
            self.ctx.release()
