"""SG-BRDF shading in OpenGL shaders (moderngl, headless EGL), and its FIS baseline.

The GLSL twin of :func:`lobelight.sgbrdf.shade` (the EM paper's sec. V): per pixel the
shader builds the tangent frame, expresses the view in it, interpolates the fitted lobes
between the fixed views exactly as :meth:`lobelight.sgbrdf.SGBRDF.lobes` does (elevation
layout: linear in ``theta`` and turned by the azimuth; geodesic layout: barycentric in the
geodesic triangle, found by the same 180-plane test as
:func:`lobelight.geometry.sphere.locate_views`), turns each lobe to the world frame and integrates
it against the lighting with ``integrate()`` of ``prefiltered.glsl`` (the exact
Gaussian-prefiltered chain of :class:`lobelight.envmap.Prefiltered`), then sums. The fitted table
lives in a float texture written once (:func:`lobe_table`; one texel per view and lobe for grey
materials, two otherwise); nothing is repacked per frame (per frame the CPU sets the camera only).
The geodesic triangle search is ``geodesic.glsl``'s, shared with the PRT renderer: the few
candidates of the view's cube-map texel (:func:`lobelight.geometry.sphere.triangle_candidates`)
rather than all 180 triangles.

``method="fis"`` is the baseline the paper times against: filtered importance sampling
(:func:`lobelight.sgbrdf.shade_fis`) with 40 Hammersley samples of Ward's importance sampling,
each read with ``textureLod`` from a mip-mapped GL cube map at the level of Colbert &
Křivánek's rule. The mip levels are built by the driver (``glGenerateMipmap``: plain 2 x 2
means, not the solid-angle weighted ones of :func:`lobelight.sgbrdf.mip_chain`);
:func:`gl_mip_chain` builds the same levels in torch, so ``shade_fis`` on it is this shader's
reference. The frame-rate comparison is then shader against shader (the ``sgbrdf_gl``
benchmark, :mod:`lobelight.bench.sgbrdf_gl`).

Geometry: by default the unit sphere at the origin, ray cast per pixel on a full-screen quad
with the rays of :func:`lobelight.sgbrdf.sphere_hits` (orthographic from +Z, or a
:class:`lobelight.geometry.camera.Camera`), so images are pixel-comparable with
:func:`lobelight.sgbrdf.render_sphere`; or a triangle mesh (positions, normals, optional
tangents per vertex) rasterised with interpolated normals.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import torch

from .._tol import DIVISOR_F64
from ..brdf import BRDF, Ward
from ..brdf import from_dict as brdf_from_dict
from ..envmap import EnvMap, Prefiltered, prefilter
from ..errors import InputError
from ..geometry.camera import Camera
from ..lobes.sg import integral
from ..sgbrdf import FIS_SAMPLES, KAPPA_MIN, SGBRDF, MipChain, hammersley
from ._gl import (
    _GL_TEXTURE_CUBE_MAP_SEAMLESS,
    _program,
    create_context,
    make_current,
    upload_geodesic,
    upload_prefiltered,
)
from ._lighting import Lighting

__all__ = [
    "METHODS",
    "GLSGBRDFRenderer",
    "gl_mip_chain",
    "is_grey",
    "lobe_table",
]

#: What the renderer can draw: our lobes, or filtered importance sampling.
METHODS = ("ours", "fis")
#: Face resolution of the FIS cube map when nothing sets it (the Prefiltered's, else this).
FIS_BASE_RES = 256


def gl_mip_chain(env: Any, /, *, base_res: int = FIS_BASE_RES) -> MipChain:
    """The mip chain ``glGenerateMipmap`` builds from a cube map, as a torch :class:`MipChain`.

    GL's mipmap generation averages 2 x 2 texels with equal weights (a box filter in texture
    space), where :func:`lobelight.sgbrdf.mip_chain` weights them by solid angle; near cube
    corners the two differ by a few per cent at coarse levels.
    :func:`~lobelight.sgbrdf.shade_fis` on this chain is what :class:`GLSGBRDFRenderer` with
    ``method="fis"`` computes.

    Parameters
    ----------
    env : :class:`lobelight.envmap.EnvMap` (resampled to ``base_res``), or a ``(6, R, R, 3)``
        cube map with ``R`` a power of two (used as it is)
    base_res : face resolution of level 0 for an EnvMap (a power of two)

    Returns
    -------
    MipChain with ``log2(R) + 1`` levels, ``(6, R >> k, R >> k, 3)`` float32 each
    """
    cube = _base_cube(env, base_res)
    levels = [cube]
    while levels[-1].shape[1] > 1:
        c = levels[-1]
        h = c.shape[1] // 2
        levels.append(c.reshape(6, h, 2, h, 2, 3).mean((2, 4)))
    return MipChain(levels=levels)


def _base_cube(env: Any, base_res: int) -> torch.Tensor:
    """``(6, R, R, 3)`` float32 CPU cube map of an EnvMap / MipChain / cube array."""
    if not isinstance(base_res, int) or base_res < 1 or base_res & (base_res - 1):
        raise InputError("base_res", f"must be a power of two, got {base_res!r}")
    if isinstance(env, MipChain):
        cube = env.levels[0]
    elif hasattr(env, "to_cubemap"):
        cube = env.to_cubemap(base_res)
    else:
        cube = torch.as_tensor(env)
    cube = cube.detach().to("cpu", torch.float32)
    r = cube.shape[1] if cube.ndim == 4 else 0
    if cube.ndim != 4 or cube.shape[0] != 6 or cube.shape[2] != r or cube.shape[3] != 3:
        raise InputError("chain", f"must be a (6, R, R, 3) cube map, got {tuple(cube.shape)}")
    if r & (r - 1):
        raise InputError("chain", f"face resolution must be a power of two, got {r}")
    return cube.contiguous()


def _ward_params(brdf: BRDF) -> tuple[tuple[float, float, float], tuple[float, float]]:
    """``ks`` RGB and ``(alpha_x, alpha_y)`` of a Ward with scalar parameters (FIS in GLSL
    implements Ward's sampling only: the comparison's material)."""
    if not isinstance(brdf, Ward):
        raise InputError(
            "brdf", f"method='fis' in GLSL implements Ward only, got {type(brdf).__name__}"
        )
    p = brdf.params
    ks = p["specular"].detach().to("cpu", torch.float32).reshape(-1)
    ax, ay = p["alpha_x"].detach().reshape(-1), p["alpha_y"].detach().reshape(-1)
    if ks.numel() not in (1, 3) or ax.numel() != 1 or ay.numel() != 1:
        raise InputError("brdf", "method='fis' needs scalar Ward parameters (one material)")
    ks3 = ks.expand(3) if ks.numel() == 1 else ks
    return tuple(float(v) for v in ks3), (float(ax), float(ay))  # type: ignore[return-value]


def _mesh_arrays(mesh: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """Checked float32 ``positions (V, 3)``, ``normals (V, 3)``, uint32 ``faces (F, 3)`` and
    optional ``tangents (V, 3)`` of a mesh mapping."""
    if not isinstance(mesh, Mapping):
        raise InputError(
            "mesh", "must be a mapping with positions, normals, faces (and optional tangents)"
        )
    for key in ("positions", "normals", "faces"):
        if key not in mesh:
            raise InputError("mesh", f"is missing {key!r}")

    def arr(key: str, dtype) -> np.ndarray:
        v = mesh[key]
        v = v.detach().cpu().numpy() if isinstance(v, torch.Tensor) else np.asarray(v)
        if v.ndim != 2 or v.shape[1] != 3:
            raise InputError(f"mesh[{key!r}]", f"must be (n, 3), got {tuple(v.shape)}")
        if key != "faces" and not np.isfinite(v).all():
            raise InputError(f"mesh[{key!r}]", "must be finite")
        return np.ascontiguousarray(v, dtype=dtype)

    pos, nrm = arr("positions", np.float32), arr("normals", np.float32)
    faces = mesh["faces"]
    faces = faces.cpu().numpy() if isinstance(faces, torch.Tensor) else np.asarray(faces)
    if faces.ndim != 2 or faces.shape[1] != 3 or faces.shape[0] < 1:
        raise InputError("mesh['faces']", f"must be (F, 3), F >= 1, got {tuple(faces.shape)}")
    if not np.issubdtype(faces.dtype, np.integer):
        raise InputError("mesh['faces']", f"must be integers, got {faces.dtype}")
    if faces.min() < 0 or faces.max() >= pos.shape[0]:
        raise InputError("mesh['faces']", f"indices must lie in [0, {pos.shape[0]})")
    if nrm.shape != pos.shape:
        raise InputError("mesh['normals']", f"must be {pos.shape}, got {nrm.shape}")
    tan = None
    if mesh.get("tangents") is not None:
        tan = arr("tangents", np.float32)
        if tan.shape != pos.shape:
            raise InputError("mesh['tangents']", f"must be {pos.shape}, got {tan.shape}")
    return pos, nrm, np.ascontiguousarray(faces, dtype=np.uint32), tan


@functools.cache
def _oct_encode(mu: torch.Tensor) -> torch.Tensor:
    """Octahedral coordinates ``(..., 2)`` in ``[-1, 1]^2`` of unit vectors ``(..., 3)``
    (float64 in, the shader's ``oct_decode`` inverts it to ~1e-7)."""
    p = mu[..., :2] / mu.abs().sum(-1, keepdim=True).clamp_min(DIVISOR_F64)
    sgn = torch.where(p >= 0, 1.0, -1.0).to(p.dtype)
    folded = (1 - p.flip(-1).abs()) * sgn
    return torch.where(mu[..., 2:] < 0, folded, p)


def lobe_table(model: SGBRDF, *, grey: bool | None = None) -> np.ndarray:
    """The texture of the fitted table, float32.

    Per view ``j`` and lobe ``k`` the quantities :meth:`SGBRDF.lobes` blends: the mass ``w
    Z(kappa)`` (RGB), ``log kappa`` (``kappa`` clamped to ``KAPPA_MIN`` first) and the mean,
    computed here once by the same torch operations, so the shader's blend starts from
    identical numbers.

    Parameters
    ----------
    model : the fitted material;  grey : pack one texel per lobe (masses equal in R, G, B);
        default: when the model's masses are grey

    Returns
    -------
    ``(M, 2 N, 4)``: texel ``(j, 2 k)`` = (mass RGB, log kappa), ``(j, 2 k + 1)`` = (mu, 0);
    grey: ``(M, N, 4)``, texel ``(j, k)`` = (mass, log kappa, octahedral mu)
    """
    p = model.params.detach().to("cpu", torch.float32)
    kap = p[..., 6].clamp_min(KAPPA_MIN)  # (M, N)
    mass = p[..., 0:3] * integral(kap).unsqueeze(-1)  # (M, N, 3)
    if grey is None:
        grey = is_grey(model)
    if grey:
        oct_mu = _oct_encode(p[..., 3:6].double()).float()  # (M, N, 2)
        return torch.cat([mass[..., :1], kap.log().unsqueeze(-1), oct_mu], -1).numpy()
    a = torch.cat([mass, kap.log().unsqueeze(-1)], -1)  # (M, N, 4)
    m = torch.cat([p[..., 3:6], torch.zeros_like(kap).unsqueeze(-1)], -1)
    return torch.stack([a, m], 2).reshape(p.shape[0], 2 * p.shape[1], 4).numpy()


def is_grey(model: SGBRDF) -> bool:
    """Whether every lobe weight of ``model`` is the same in R, G and B."""
    w = model.params[..., 0:3]
    return bool((w == w[..., :1]).all())


class GLSGBRDFRenderer:
    """Render an object made of a fitted SG-BRDF (or FIS of its BRDF) with OpenGL shaders.

    Parameters
    ----------
    model : :class:`lobelight.sgbrdf.SGBRDF` (from :func:`lobelight.sgbrdf.fit`)
    lighting : :class:`lobelight.render.Lighting`, :class:`lobelight.envmap.Prefiltered` (its
        blend must be "l2", the shader's) or :class:`lobelight.envmap.EnvMap` (prefiltered here
        at ``base_res`` 128). ``method="fis"`` reads the map itself: a Lighting or an EnvMap,
        unless ``chain`` is given
    width, height : image size in pixels
    ctx : an existing moderngl context (default: a new headless one, released with this)
    method : "ours" (the lobes, prefiltered lookups) or "fis" (40-sample FIS)
    mesh : None for the unit sphere at the origin (ray cast per pixel as
        :func:`lobelight.sgbrdf.sphere_hits`), or a mapping with ``positions (V, 3)``,
        ``normals (V, 3)``, ``faces (F, 3)`` int and optional ``tangents (V, 3)`` (the
        material's ``x`` axis; default the tangent of :func:`lobelight.geometry.sphere.frame`, as
        :func:`lobelight.sgbrdf.shade`)
    brdf : the material FIS samples (default the one the model was fitted to,
        ``model.material``); Ward with scalar parameters
    chain : FIS only: a ``(6, R, R, 3)`` cube map or a :class:`MipChain` whose level 0 becomes
        the GL cube map's base level (GL builds the rest: :func:`gl_mip_chain`)
    fis_res : FIS only: face resolution when the cube map is made from an EnvMap (default
        the Prefiltered's base resolution, else ``FIS_BASE_RES``)
    samples : FIS samples per pixel (40, the paper's comparison)
    """

    def __init__(
        self,
        model: SGBRDF,
        lighting: Any,
        width: int,
        height: int,
        *,
        ctx=None,
        method: str = "ours",
        mesh: Any = None,
        brdf: BRDF | None = None,
        chain: Any = None,
        fis_res: int | None = None,
        samples: int = FIS_SAMPLES,
    ):
        if not isinstance(model, SGBRDF):
            raise InputError("model", f"must be an SGBRDF (from fit), got {type(model).__name__}")
        if method not in METHODS:
            raise InputError("method", f"must be one of {', '.join(METHODS)}, got {method!r}")
        for name, v in (("width", width), ("height", height)):
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or not 1 <= v <= 16384:
                raise InputError(name, f"must be an integer in [1, 16384], got {v!r}")
        if not isinstance(samples, int) or isinstance(samples, bool) or not 1 <= samples <= 256:
            raise InputError("samples", f"must be an integer in [1, 256], got {samples!r}")
        self.method = method
        self.width, self.height = int(width), int(height)
        self.mesh = None if mesh is None else _mesh_arrays(mesh)
        self.samples = samples
        defines: dict[str, int] = {
            "SPHERE": int(self.mesh is None),
            "HAS_TANGENT": int(self.mesh is not None and self.mesh[3] is not None),
            "METHOD_FIS": int(method == "fis"),
        }
        # everything that can fail on bad input is checked before a context is made
        if method == "ours":
            pf = self._prefiltered(lighting)
            if model.layout not in ("elevation", "geodesic"):
                raise InputError("model", f"unknown view layout {model.layout!r}")
            geo = model.layout == "geodesic"
            if geo and model.params.shape[0] != 92:
                raise InputError("model", "a geodesic model must have 92 views")
            defines.update(
                GREY=int(is_grey(model)),
                GEODESIC=int(geo),
                NL=model.n_lobes,
                N_VIEWS=int(model.params.shape[0]),
                MAX_LEVELS=len(pf.levels),
            )
            # the geodesic layout locates views among the triangles of geodesic.glsl
            self._include: tuple[str, ...] = ("prefiltered",) + (("geodesic",) if geo else ())
        else:
            b = brdf if brdf is not None else brdf_from_dict(model.material)
            self.ks, self.alpha = _ward_params(b)
            if chain is None:
                env = lighting.env if isinstance(lighting, Lighting) else lighting
                if not isinstance(env, EnvMap):
                    raise InputError(
                        "lighting", "method='fis' needs a Lighting or an EnvMap (or chain=)"
                    )
                if fis_res is None:
                    fis_res = lighting.base_res if isinstance(lighting, Lighting) else FIS_BASE_RES
                chain = env
            cube = _base_cube(chain, fis_res or FIS_BASE_RES)
            defines.update(NS=samples)
            self._include = ()
        self.defines = defines

        self.ctx = ctx if ctx is not None else create_context()  # InputError without GL
        import moderngl  # optional: the gl extra (importable once a context exists)

        self.own_ctx = ctx is None
        ctx = self.ctx
        ctx.enable_direct(_GL_TEXTURE_CUBE_MAP_SEAMLESS)
        self._progs: dict[bool, Any] = {}
        self._vaos: dict[bool, Any] = {}
        self._textures: list[Any] = []
        self._buffers: list[Any] = []
        self._uniforms: dict[str, Any] = {}
        self.planes_ubo = None

        if method == "ours":
            self.atlas, atlas_uniforms = upload_prefiltered(ctx, pf)
            self._uniforms.update(atlas_uniforms)
            self._uniforms["atlas"] = 3
            table = lobe_table(model, grey=bool(defines["GREY"]))  # (M, N or 2N, 4)
            self.lobe_tex = ctx.texture(
                (table.shape[1], table.shape[0]), 4, table.tobytes(), dtype="f4"
            )
            self.lobe_tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
            self._uniforms["lobe_tex"] = 0
            self._textures += [self.atlas, self.lobe_tex]
            if geo:
                self.planes_ubo, self.cand_tex, geo_defines = upload_geodesic(ctx)
                self.defines.update(geo_defines)
                self._buffers.append(self.planes_ubo)
                self._textures.append(self.cand_tex)
                self._uniforms["cand_tex"] = 1
            else:
                v = model.views.detach().to("cpu", torch.float32)
                # the same float32 elevations as _elevation_weights
                th = torch.atan2(torch.linalg.vector_norm(v[:, :2], dim=-1), v[:, 2])
                self._uniforms["view_theta"] = th.numpy().astype(np.float32)
        else:
            r = cube.shape[1]
            rgba = torch.cat([cube, torch.ones_like(cube[..., :1])], -1)  # as the atlas
            self.env_cube = ctx.texture_cube((r, r), 4, rgba.numpy().tobytes(), dtype="f4")
            self.env_cube.build_mipmaps()
            self.env_cube.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
            self._textures.append(self.env_cube)
            self._uniforms.update(
                env_mip=2,
                ham=hammersley(samples, dtype=torch.float32).numpy(),
                ks=self.ks,
                alpha=self.alpha,
                base_res=float(r),
                max_lod=float(math.log2(r)),
                lod_bias=1.0,
            )

        if self.mesh is None:
            quad = np.array([-1, -1, 1, -1, -1, 1, 1, 1], np.float32)
            self.vbo = ctx.buffer(quad.tobytes())
            self._buffers.append(self.vbo)
            self.ibo = None
        else:
            pos, nrm, faces, tan = self.mesh
            cols = [pos, nrm] + ([tan] if tan is not None else [])
            self.vbo = ctx.buffer(np.concatenate(cols, 1).astype(np.float32).tobytes())
            self.ibo = ctx.buffer(faces.tobytes())
            self._buffers += [self.vbo, self.ibo]
            self.center = pos.mean(0).astype(np.float64)
            self.radius = float(np.linalg.norm(pos - self.center, axis=1).max()) + 1e-6
        self.color = ctx.texture((self.width, self.height), 4, dtype="f4")
        self.depth = ctx.depth_renderbuffer((self.width, self.height))
        self.fbo = ctx.framebuffer([self.color], self.depth)

    @staticmethod
    def _prefiltered(lighting: Any) -> Prefiltered:
        if isinstance(lighting, Lighting):
            pf = lighting.prefiltered
        elif isinstance(lighting, Prefiltered):
            pf = lighting
        elif isinstance(lighting, EnvMap):
            pf = prefilter(lighting, base_res=128)
        else:
            raise InputError(
                "lighting",
                f"must be a Lighting, Prefiltered or EnvMap, got {type(lighting).__name__}",
            )
        if pf.blend != "l2":
            raise InputError("lighting", f"the shader blends levels by 'l2', not {pf.blend!r}")
        if len(pf.levels) < 2:
            raise InputError("lighting", "the prefiltered chain needs at least two levels")
        return pf

    def _program(self, ortho: bool):
        """The program (and its vertex array) for a camera kind, built on first use."""
        if ortho in self._progs:
            return self._progs[ortho], self._vaos[ortho]
        prog = _program(self.ctx, "sgbrdf", {**self.defines, "ORTHO": int(ortho)}, self._include)
        for k, v in self._uniforms.items():
            if k not in prog:  # unused by this variant: the compiler removed it
                continue
            if isinstance(v, np.ndarray):
                prog[k].write(v.astype(np.float32).tobytes())
            else:
                prog[k].value = v
        if self.planes_ubo is not None:
            prog["Planes"].binding = 0
        if self.mesh is None:
            vao = self.ctx.vertex_array(prog, [(self.vbo, "2f", "in_xy")])
        else:
            fmt = "3f 3f 3f" if self.mesh[3] is not None else "3f 3f"
            names = ["in_pos", "in_nrm"] + (["in_tan"] if self.mesh[3] is not None else [])
            # attributes the compiler dropped are skipped by their byte size ("3x4")
            parts, used = fmt.split(), []
            for i, nm in enumerate(names):
                if nm in prog:
                    used.append(nm)
                else:
                    parts[i] = "3x4"
            vao = self.ctx.vertex_array(prog, [(self.vbo, " ".join(parts), *used)], self.ibo)
        self._progs[ortho], self._vaos[ortho] = prog, vao
        return prog, vao

    def _set(self, prog, name: str, value: Any) -> None:
        if name in prog:
            prog[name].value = value

    def draw(self, camera: Camera | None = None) -> None:
        """Render one frame into the renderer's float framebuffer (asynchronous: nothing is
        read back; :meth:`read` or ``ctx.finish()`` waits for it).

        Parameters
        ----------
        camera : None for :func:`lobelight.sgbrdf.sphere_hits`' orthographic view from +Z
            (``[-1, 1]^2`` of the ``xy`` plane fills the image), or a
            :class:`lobelight.geometry.camera.Camera`
        """
        import moderngl  # optional: the gl extra

        if camera is not None and not isinstance(camera, Camera):
            raise InputError("camera", f"must be a Camera or None, got {type(camera).__name__}")
        make_current(self.ctx, self.own_ctx)
        ctx = self.ctx
        prog, vao = self._program(camera is None)
        self.fbo.use()
        ctx.viewport = (0, 0, self.width, self.height)
        self.fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        self._set(prog, "viewport", (float(self.width), float(self.height)))
        if camera is not None:
            f = camera.frame(dtype=torch.float64).numpy()
            tx, ty = camera.tan_half(self.width, self.height)
            eye = np.asarray(camera.origin, np.float64)
            self._set(prog, "cam_left", tuple(f[0]))
            self._set(prog, "cam_up", tuple(f[1]))
            self._set(prog, "cam_dir", tuple(f[2]))
            self._set(prog, "tan_half", (tx, ty))
            self._set(prog, "eye", tuple(float(x) for x in eye))
            self._set(prog, "eye_c", float(eye @ eye - 1.0))
            if self.mesh is not None:
                dist = float(np.linalg.norm(eye - self.center))
                near = max(dist - 1.01 * self.radius, 1e-3 * self.radius)
                self._set(prog, "depth_range", (near, dist + 1.01 * self.radius))
        elif self.mesh is not None:
            self._set(prog, "depth_range", (float(self.center[2]), 1.01 * self.radius))
        if self.method == "ours":
            self.lobe_tex.use(0)
            self.atlas.use(3)
            if self.planes_ubo is not None:
                self.planes_ubo.bind_to_uniform_block(0)
                self.cand_tex.use(1)
        else:
            self.env_cube.use(2)
        if self.mesh is None:
            ctx.disable(moderngl.DEPTH_TEST)
            vao.render(moderngl.TRIANGLE_STRIP)
        else:
            ctx.enable(moderngl.DEPTH_TEST)
            vao.render(moderngl.TRIANGLES)

    def read(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The framebuffer as ``(H, W, 3)`` float32 radiance (row 0 at the top, as
        :func:`lobelight.sgbrdf.render_sphere`) and the ``(H, W)`` bool object mask."""
        make_current(self.ctx, self.own_ctx)
        raw = self.fbo.read(components=4, dtype="f4")
        img = np.frombuffer(raw, np.float32).reshape(self.height, self.width, 4)[::-1]
        img = torch.from_numpy(img.copy())
        return img[..., :3].contiguous(), img[..., 3] > 0.5

    def render(self, camera: Camera | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Draw and read back one frame: ``(H, W, 3)`` float32 image, ``(H, W)`` bool mask
        (0 off the object; on it, 0 where the viewer is below the shading normal)."""
        self.draw(camera)
        return self.read()

    def release(self) -> None:
        """Free the GL objects (and the context when this renderer made it)."""
        make_current(self.ctx, self.own_ctx)
        objs = [*self._vaos.values(), *self._progs.values(), *self._textures, *self._buffers]
        for o in (*objs, self.fbo, self.color, self.depth):
            o.release()
        self._vaos.clear()
        self._progs.clear()
        self._textures.clear()
        self._buffers.clear()
        if self.own_ctx:
            self.ctx.release()

    def __enter__(self) -> GLSGBRDFRenderer:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.release()
