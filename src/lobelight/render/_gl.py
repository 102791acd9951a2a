"""The OpenGL renderer (moderngl): headless through EGL, or into a window's context.

Everything per frame stays on the GPU (the paper's bottleneck was repacking the three nearest
views' data on the CPU every frame): the Gaussians of every (vertex, view) live in a float
texture, the 180 geodesic triangles' great-circle planes in a uniform block, and the vertex
shader finds each vertex's view triangle itself. Per frame the CPU uploads only the camera, the
lighting rotation and the rotated lighting's 25 SH coefficients.

Prefiltered levels: each level's six faces, each with the one-texel seamless border of
:func:`lobelight.geometry.cubemap.pad_seamless`, are packed into one atlas texture; hardware
bilinear filtering inside a padded face equals GL's seamless cube-map filtering (the same corner
rule) and matches :func:`lobelight.geometry.cubemap.sample` exactly. A Gaussian between two levels
costs two bilinear fetches, blended by the L2 rule of
:meth:`lobelight.envmap.Prefiltered.level_coords` (a trilinear ``textureLod`` would blend mips
linearly in level, which is less accurate).
"""

from __future__ import annotations

from functools import cache
from importlib import resources

import numpy as np
import torch

from .. import model as model_module
from ..envmap import Prefiltered
from ..errors import InputError
from ..geometry import cubemap, sphere
from ..geometry.camera import Camera
from ..lobes import sg
from ._lighting import Lighting
from ._sun_glossy import (
    sun_glossy_supported,
    sun_glossy_uniforms,
    sun_glossy_vertex_params,
    sun_widened,
)

__all__ = [
    "GLRenderer",
    "create_context",
    "gl_available",
    "load_shader",
    "set_uniforms",
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


@cache
def load_shader(name: str) -> str:
    """The text of a package shader file (``render/shaders/NAME.glsl``)."""
    return resources.files("lobelight.render").joinpath("shaders", f"{name}.glsl").read_text()


def _program(
    ctx,
    name: str,
    defines: dict[str, int | str] | None = None,
    include: tuple = (),
    vertex_include: tuple = (),
):
    """A program from one shader file holding both stages; ``include`` and ``vertex_include``
    name shader files whose text goes before the fragment and the vertex stage (shared
    functions, e.g. ``"prefiltered"``, ``"geodesic"``)."""
    head = "#version 330\n" + "".join(f"#define {k} {v}\n" for k, v in (defines or {}).items())
    src = load_shader(name)

    def lib(names):
        return "".join(load_shader(i) + "\n" for i in names)

    return ctx.program(
        vertex_shader=head + "#define VERTEX_SHADER\n" + lib(vertex_include) + src,
        fragment_shader=head + "#define FRAGMENT_SHADER\n" + lib(include) + src,
    )


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


def gl_available() -> bool:
    """Whether a headless context can be made here."""
    try:
        create_context().release()
        return True
    except InputError:
        return False


def _wrap(rows: np.ndarray, width: int = TEX_WIDTH) -> tuple[np.ndarray, int]:
    """Wrap ``(T, 4)`` texels into a ``(H, W, 4)`` image (zero-padded); returns it and W."""
    t = rows.shape[0]
    while -(-t // width) > 16384:  # GL's usual maximum texture height
        width *= 2
    h = max(1, -(-t // width))
    out = np.zeros((h * width, 4), np.float32)
    out[:t] = rows
    return out.reshape(h, width, 4), width


def _atlas(pf: Prefiltered) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All prefiltered levels' padded faces in one image: ``(H, W, 4)`` (RGB, alpha 1), row and
    res per level."""
    base = pf.base_res
    width = 6 * (base + 2)
    pads = [cubemap.pad_seamless(lv).cpu().numpy() for lv in pf.levels]  # (6, P, P, 3)
    height = sum(p.shape[1] for p in pads)
    # RGBA: llvmpipe filters four-channel float textures faster than three-channel ones, and
    # GPUs pad RGB anyway
    atlas = np.ones((height, width, 4), np.float32)
    y = 0
    rows, res = [], []
    for p in pads:
        size = p.shape[1]
        for f in range(6):  # six faces side by side: a loop over faces, not texels
            atlas[y : y + size, f * size : (f + 1) * size, :3] = p[f]
        rows.append(y)
        res.append(size - 2)
        y += size
    return atlas, np.asarray(rows, np.float32), np.asarray(res, np.float32)


def upload_prefiltered(ctx, pf: Prefiltered):
    """The prefiltered chain as one atlas texture, and the uniforms ``prefiltered.glsl`` reads
    (bind the texture to the unit of its ``atlas`` sampler)."""
    import moderngl  # optional (the gl extra)

    atlas, rows, res = _atlas(pf)
    tex = ctx.texture((atlas.shape[1], atlas.shape[0]), 4, atlas.tobytes(), dtype="f4")
    tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
    tex.repeat_x = tex.repeat_y = False
    uniforms = {
        "atlas_size": (float(atlas.shape[1]), float(atlas.shape[0])),
        "level_y": rows,
        "level_res": res,
        "n_levels": len(pf.levels),
        "lam0": float(pf.lambdas[0]),
        "log_rho": float(torch.log(pf.lambdas[0] / pf.lambdas[1])),
    }
    return tex, uniforms


def upload_geodesic(ctx):
    """What ``geodesic.glsl`` reads: the 180 triangles' planes as a uniform block (bind it to
    the ``Planes`` block), the candidate table as a texture (bind it to the unit of the
    ``cand_tex`` sampler), and the defines the shader needs.

    Returns
    -------
    planes buffer, candidate texture, ``{"CAND_RES": ..., "CAND_TEXELS": ...}``
    """
    import moderngl  # optional (the gl extra)

    planes, faces = sphere.face_planes(torch.float32, torch.device("cpu"))
    pl = torch.cat([planes.T.reshape(180, 3, 3), faces.reshape(180, 3, 1).float()], -1)
    ubo = ctx.buffer(pl.reshape(540, 4).numpy().astype(np.float32).tobytes())
    cand = sphere.triangle_candidates(CAND_RES)  # (6, R, R, K)
    texels = -(-cand.shape[-1] // 4)
    cand = torch.nn.functional.pad(cand, (0, 4 * texels - cand.shape[-1]), value=-1)
    img = cand.reshape(6 * CAND_RES, CAND_RES * texels, 4).float().numpy()
    tex = ctx.texture((img.shape[1], img.shape[0]), 4, img.tobytes(), dtype="f4")
    tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
    return ubo, tex, {"CAND_RES": CAND_RES, "CAND_TEXELS": texels}


def set_uniforms(prog, values: dict) -> None:
    """Set a program's uniforms: numpy arrays are written as bytes, the rest by value."""
    for k, v in values.items():
        if isinstance(v, np.ndarray):
            prog[k].write(v.astype(np.float32).tobytes())
        else:
            prog[k].value = v


class GLRenderer:
    """Shader implementation behind :class:`lobelight.render.Renderer` (``backend="gl"``).

    ``offsets`` ``(S, 2)``: the sub-pixel sample positions in ``[0, 1)`` (x right, y down) of
    each frame (:func:`lobelight.render.sample_offsets`); default the pixel centre. With more
    than one, each sample is a pass with the image shifted by its offset (the ``jitter``
    uniform), added into :attr:`color` with weight ``1 / S``: the frame is the box-filtered
    average of the samples and its alpha the fraction of them on the object.
    """

    def __init__(
        self, model, lighting: Lighting, width: int, height: int, *, ctx=None, offsets=None
    ):
        import moderngl  # optional (the gl extra)

        self.ctx = ctx if ctx is not None else create_context()
        self.own_ctx = ctx is None
        self.width, self.height = int(width), int(height)
        ctx = self.ctx
        ctx.enable_direct(_GL_TEXTURE_CUBE_MAP_SEAMLESS)
        n_gaussians = model.n_gaussians
        n_sh = int(model.diffuse.shape[1])
        if n_sh != lighting.sh.shape[0]:
            raise InputError(
                "lighting", f"has {lighting.sh.shape[0]} SH coefficients, the model {n_sh}"
            )
        # the sun's glossy reflection per pixel where the BRDF allows (render/_sun_glossy.py);
        # the Gaussians then integrate the map without the sun
        spec = model.materials.specular
        self.sun_glossy = lighting.sun is not None and sun_glossy_supported(spec)
        pf = lighting.rest_prefiltered if self.sun_glossy else lighting.prefiltered
        self.n_levels = len(pf.levels)
        self.planes_ubo, self.cand_tex, geo_defines = upload_geodesic(ctx)
        self.prog = _program(
            ctx,
            "prt",
            {
                "N_GAUSSIANS": n_gaussians,
                "N_INDIRECT": model.indirect_gaussians,
                "N_SH": n_sh,
                "MAX_LEVELS": self.n_levels,
                "FLOOR": f"{model_module.LIVE_FLOOR:.6e}",
                "MIN_SAY": f"{model_module.MIN_SAY:.6e}",
                "HAS_BOUNCE": int(model.bounce is not None and lighting.sun is not None),
                **geo_defines,
            },
            include=("prefiltered",),
            vertex_include=("geodesic",),
        )
        self.bg_prog = _program(ctx, "background")
        self.tm_prog = _program(ctx, "tonemap")
        self.acc_prog = _program(ctx, "accumulate")

        # Gaussians: record (v, j, k) -> texels 2r, 2r + 1 with r = (v J + j) N + k
        g = model.gaussians
        sigma = g.lam.rsqrt()[..., None]
        # the light each lobe carries (prt.glsl blends it, not the peak weight)
        e = (g.w.double() * sg.integral(g.lam.double())[..., None]).float()
        a = torch.cat([e, sigma], -1).reshape(-1, 4)  # (V J N, 4)
        # .w: the record's view is above the vertex's horizon (model.horizon_scale)
        above = ((model.views[None] * model.mesh.normals[:, None]).sum(-1) > 0).float()  # (V, J)
        above = above[:, :, None, None].expand(-1, -1, g.lam.shape[-1], 1)
        m = torch.cat([g.mu, above], -1).reshape(-1, 4)
        rec = torch.stack([a, m], 1).reshape(-1, 4).detach().cpu().numpy()
        img, tw = _wrap(rec)
        dimg, tw2 = _wrap(
            torch.cat([model.diffuse, torch.zeros_like(model.diffuse[..., :1])], -1)
            .reshape(-1, 4)
            .detach()
            .cpu()
            .numpy(),
            tw,
        )
        if tw2 != tw:  # both share one width uniform; wrap again at the larger width
            img, tw = _wrap(rec, tw2)
        self.gauss_tex = self._data_texture(img)
        self.diff_tex = self._data_texture(dimg)
        # the interreflected part of the transfer, lit by the sun as well (Model.bounce)
        self.has_bounce = model.bounce is not None and lighting.sun is not None
        bounce = model.bounce if self.has_bounce else torch.zeros_like(model.diffuse[:1])
        bimg, tw3 = _wrap(
            torch.cat([bounce, torch.zeros_like(bounce[..., :1])], -1)
            .reshape(-1, 4)
            .detach()
            .cpu()
            .numpy(),
            tw,
        )
        if tw3 != tw:
            raise InputError("model", "the bounce table exceeds the texture size")
        self.bounce_tex = self._data_texture(bimg)
        self.atlas, atlas_uniforms = upload_prefiltered(ctx, pf)
        cube = lighting.env.to_cubemap(BACKGROUND_RES).detach().cpu().numpy().astype(np.float32)
        self.env_cube = ctx.texture_cube((BACKGROUND_RES,) * 2, 3, cube.tobytes(), dtype="f4")
        self.env_cube.filter = (moderngl.LINEAR, moderngl.LINEAR)

        p = self.prog
        p["tex_width"].value = tw
        set_uniforms(p, atlas_uniforms)
        p["Planes"].binding = 0
        units = (
            ("gauss_tex", 0),
            ("diff_tex", 1),
            ("cand_tex", 2),
            ("atlas", 3),
            ("bounce_tex", 8),
        )
        for name, unit in units:
            if p.get(name, None) is not None:  # bounce_tex is compiled out without a bounce
                p[name].value = unit
        self.bg_prog["env"].value = 4
        self.lighting = lighting

        verts = model.mesh.vertices.detach().cpu().numpy().astype(np.float32)
        faces_np = model.mesh.faces.cpu().numpy().astype(np.uint32)
        self.vbo = ctx.buffer(verts.tobytes())
        self.ibo = ctx.buffer(faces_np.tobytes())
        normals = model.mesh.normals.detach().cpu().numpy().astype(np.float32)
        albedo = model.materials.diffuse.detach().cpu().numpy().astype(np.float32)
        self.nbo = ctx.buffer(normals.tobytes())
        self.abo = ctx.buffer(albedo.tobytes())
        v = model.mesh.n_vertices
        if self.sun_glossy:
            sb = sun_glossy_vertex_params(sun_widened(spec, lighting.sun.spread), v)
            set_uniforms(p, sun_glossy_uniforms(spec))
            if p.get("sun_spread", None) is not None:  # compiled out without indirect lobes
                p["sun_spread"].value = float(lighting.sun.spread)
        else:
            sb = np.zeros((v, 10), np.float32)
        p["sun_glossy"].value = float(self.sun_glossy)
        self.sbo = ctx.buffer(sb.tobytes())
        self.vao = ctx.vertex_array(
            p,
            [
                (self.vbo, "3f", "in_pos"),
                (self.nbo, "3f", "in_normal"),
                (self.abo, "3f", "in_albedo"),
                (self.sbo, "4f 3f 3f", "in_sb0", "in_eta", "in_k"),
            ],
            self.ibo,
            4,
        )
        # the sun's shadow map (a 1-texel stand-in without a sun: the sampler stays valid)
        self.shadow_res = SHADOW_RES if lighting.sun is not None else 1
        self.shadow_prog = _program(ctx, "shadow")
        self.shadow_tex = ctx.depth_texture((self.shadow_res,) * 2)
        self.shadow_tex.compare_func = "<="
        self.shadow_tex.filter = (moderngl.LINEAR, moderngl.LINEAR)  # 2x2 PCF
        self.shadow_tex.repeat_x = self.shadow_tex.repeat_y = False
        self.shadow_fbo = ctx.framebuffer(depth_attachment=self.shadow_tex)
        self.shadow_vao = ctx.vertex_array(
            self.shadow_prog, [(self.vbo, "3f", "in_pos")], self.ibo, 4
        )
        p["shadow_map"].value = 6
        self._shadow_key = None  # the sun frame the shadow map was last rendered for
        quad = np.array([-1, -1, 1, -1, -1, 1, 1, 1], np.float32)
        self.quad = ctx.buffer(quad.tobytes())
        self.bg_vao = ctx.vertex_array(self.bg_prog, [(self.quad, "2f", "in_xy")])
        self.tm_vao = ctx.vertex_array(self.tm_prog, [(self.quad, "2f", "in_xy")])
        self.acc_vao = ctx.vertex_array(self.acc_prog, [(self.quad, "2f", "in_xy")])
        # a texture (not a renderbuffer) so that the window's tone-mapping pass can read it
        self.color = ctx.texture((self.width, self.height), 4, dtype="f4")
        self.depth = ctx.depth_renderbuffer((self.width, self.height))
        self.fbo = ctx.framebuffer([self.color], self.depth)
        # the per-sample pass's target when there are several samples (made on first use)
        self._pass_color = self._pass_fbo = None
        self.set_offsets(offsets)
        center = model.mesh.vertices.mean(0)
        self.center = center.detach().cpu().numpy()
        self.radius = float((model.mesh.vertices - center).norm(dim=-1).max())

    def set_offsets(self, offsets=None) -> None:
        """The sub-pixel sample positions ``(S, 2)`` of the next frames (None: the centre)."""
        off = np.full((1, 2), 0.5) if offsets is None else np.asarray(offsets, np.float64)
        if off.ndim != 2 or off.shape[1] != 2 or off.shape[0] < 1:
            raise InputError("offsets", f"expected (S, 2) sub-pixel positions, got {off.shape}")
        if not bool(np.all((off >= 0) & (off < 1))):
            raise InputError("offsets", "sub-pixel positions must lie in [0, 1)")
        self.offsets = off
        if off.shape[0] > 1 and self._pass_fbo is None:
            self._pass_color = self.ctx.texture((self.width, self.height), 4, dtype="f4")
            self._pass_fbo = self.ctx.framebuffer([self._pass_color], self.depth)

    def _jitter(self, offset) -> tuple[float, float]:
        """The NDC shift that puts the sample at ``offset`` (x right, y down) under the pixel
        centre (GL's y runs up)."""
        return (2.0 * (0.5 - offset[0]) / self.width, 2.0 * (offset[1] - 0.5) / self.height)

    def _data_texture(self, img: np.ndarray):
        import moderngl  # optional (the gl extra)

        t = self.ctx.texture(
            (img.shape[1], img.shape[0]), 4, img.astype(np.float32).tobytes(), dtype="f4"
        )
        t.filter = (moderngl.NEAREST, moderngl.NEAREST)
        return t

    def _camera_uniforms(self, prog, camera: Camera) -> None:
        f = camera.frame(dtype=torch.float64).numpy()
        tx, ty = camera.tan_half(self.width, self.height)
        prog["cam_left"].value = tuple(f[0])
        prog["cam_up"].value = tuple(f[1])
        prog["cam_dir"].value = tuple(f[2])
        prog["tan_half"].value = (tx, ty)

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

        ctx = self.ctx
        out = fbo or self.fbo
        r = rot.detach().cpu().numpy().astype(np.float32)
        rt_bytes = r.tobytes()  # row-major R is column-major R^T: the shaders' rot_t
        if background:
            self._camera_uniforms(self.bg_prog, camera)
            self.bg_prog["rot_t"].write(rt_bytes)
        p = self.prog
        self._camera_uniforms(p, camera)
        eye = np.asarray(camera.origin, np.float64)
        dist = float(np.linalg.norm(eye - self.center))
        near = max(dist - 1.01 * self.radius, 1e-3 * self.radius)
        p["depth_range"].value = (near, dist + 1.01 * self.radius)
        p["eye"].value = tuple(float(x) for x in eye)
        p["rot_t"].write(rt_bytes)
        p["sh_light"].write(
            self.lighting.sh_rotated(rot).cpu().numpy().astype(np.float32).tobytes()
        )
        if self.has_bounce:
            p["sh_sun"].write(
                self.lighting.sun_sh_rotated(rot).numpy().astype(np.float32).tobytes()
            )
        p["parts"].value = (float(diffuse), float(glossy))
        self._sun_pass(rot, on=diffuse or (glossy and self.sun_glossy))
        n = self.offsets.shape[0]
        if n == 1:
            self._draw_sample(out, self._jitter(self.offsets[0]), background)
            return
        out.use()
        ctx.viewport = (0, 0, self.width, self.height)
        out.clear(0.0, 0.0, 0.0, 0.0)
        self.acc_prog["image"].value = 7
        self.acc_prog["weight"].value = 1.0 / n
        for offset in self.offsets:
            self._draw_sample(self._pass_fbo, self._jitter(offset), background)
            out.use()
            ctx.viewport = (0, 0, self.width, self.height)
            ctx.disable(moderngl.DEPTH_TEST)
            ctx.enable(moderngl.BLEND)
            ctx.blend_func = moderngl.ONE, moderngl.ONE
            ctx.blend_equation = moderngl.FUNC_ADD
            self._pass_color.use(7)
            self.acc_vao.render(moderngl.TRIANGLE_STRIP)
            ctx.disable(moderngl.BLEND)

    def _draw_sample(self, fbo, jitter: tuple[float, float], background: bool) -> None:
        """One sample of every pixel into ``fbo``: background, then the object (the uniforms
        but ``jitter`` are set by :meth:`draw`)."""
        import moderngl  # optional (the gl extra)

        ctx = self.ctx
        fbo.use()
        ctx.viewport = (0, 0, self.width, self.height)
        if background:  # the background pass writes every pixel: clear the depth alone
            # (moderngl applies a framebuffer's colour mask when it is bound)
            fbo.color_mask = (False, False, False, False)
            fbo.use()
            fbo.clear(depth=1.0)
            fbo.color_mask = (True, True, True, True)
            fbo.use()
            ctx.disable(moderngl.DEPTH_TEST)
            self.bg_prog["jitter"].value = jitter
            self.env_cube.use(4)
            self.bg_vao.render(moderngl.TRIANGLE_STRIP)
        else:
            fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        ctx.enable(moderngl.DEPTH_TEST)
        self.prog["jitter"].value = jitter
        self.shadow_tex.use(6)
        self.gauss_tex.use(0)
        self.diff_tex.use(1)
        self.cand_tex.use(2)
        self.bounce_tex.use(8)
        self.planes_ubo.bind_to_uniform_block(0)
        self.atlas.use(3)
        self.vao.render(moderngl.TRIANGLES)

    def _sun_pass(self, rot: torch.Tensor, *, on: bool) -> None:
        """Set the sun's uniforms and render its shadow map (when the lighting has a sun)."""
        import moderngl  # optional (the gl extra)

        p = self.prog
        sun = self.lighting.sun
        p["sun_on"].value = float(on and sun is not None)
        if not (on and sun is not None):
            return
        l = self.lighting.sun_direction(rot).detach().cpu().double().numpy()
        l = l / np.linalg.norm(l)
        a = np.array([1.0, 0.0, 0.0]) if abs(l[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        u = np.cross(l, a)
        u /= np.linalg.norm(u)
        v = np.cross(l, u)
        frame = np.stack([u, v, l]).astype(np.float32)  # rows; GLSL mat3 is column-major
        scale = 1.0 / (1.02 * self.radius)
        texel = 2.0 / (scale * self.shadow_res)  # world size of a shadow-map texel
        for prog in (p, self.shadow_prog):
            prog["shadow_frame"].write(frame.T.copy().tobytes())
            prog["shadow_center"].value = tuple(float(x) for x in self.center)
            prog["shadow_scale"].value = scale
        p["sun_dir"].value = tuple(float(x) for x in l)
        p["sun_e"].value = tuple(float(x) for x in sun.irradiance)
        p["shadow_offset"].value = 1.5 * texel
        p["shadow_bias"].value = 1.0 / self.shadow_res
        key = frame.tobytes()
        if key == self._shadow_key:  # the map depends on the sun's direction alone
            return
        self._shadow_key = key
        ctx = self.ctx
        self.shadow_fbo.use()
        ctx.viewport = (0, 0, self.shadow_res, self.shadow_res)
        self.shadow_fbo.clear(depth=1.0)
        ctx.enable(moderngl.DEPTH_TEST)
        self.shadow_vao.render(moderngl.TRIANGLES)

    def present(self, screen, *, exposure: float = 0.0, curve: str = "srgb") -> None:
        """Tone-map the last frame onto ``screen`` (a window's framebuffer)."""
        import moderngl  # optional (the gl extra)

        screen.use()
        self.ctx.disable(moderngl.DEPTH_TEST)
        self.color.use(5)
        self.tm_prog["image"].value = 5
        self.tm_prog["scale"].value = float(2.0**exposure)
        self.tm_prog["curve"].value = 1 if curve == "aces" else 0
        self.tm_vao.render(moderngl.TRIANGLE_STRIP)

    def read(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The float framebuffer as ``(H, W, 3)`` radiance and ``(H, W)`` float32 coverage (the
        fraction of the pixel's samples on the object)."""
        raw = self.fbo.read(components=4, dtype="f4")
        img = np.frombuffer(raw, np.float32).reshape(self.height, self.width, 4)[::-1]
        img = torch.from_numpy(img.copy())
        return img[..., :3].contiguous(), img[..., 3].contiguous()

    def release(self) -> None:
        for o in (self._pass_fbo, self._pass_color):
            if o is not None:
                o.release()
        for o in (
            self.vao,
            self.shadow_vao,
            self.shadow_fbo,
            self.shadow_tex,
            self.shadow_prog,
            self.nbo,
            self.abo,
            self.sbo,
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
            self.planes_ubo,
            self.cand_tex,
            self.atlas,
            self.env_cube,
            self.prog,
            self.bg_prog,
            self.tm_prog,
            self.acc_prog,
        ):
            o.release()
        if self.own_ctx:
            self.ctx.release()
