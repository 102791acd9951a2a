"""``Renderer``: one front for the shader path and the torch path, and their pixel samples."""

from __future__ import annotations

import math

import numpy as np
import torch

from ..envmap import ChainBuilder, EnvMap
from ..errors import InputError
from ..geometry.camera import Camera
from ..geometry.raycast import RayCaster
from ._gl import GLRenderer
from ._lighting import Lighting, as_rotation, auto_base_res
from ._torch import render_torch

__all__ = ["Renderer", "sample_offsets"]

BACKENDS = ("gl", "torch")
#: Most samples per pixel a Renderer takes.
MAX_SAMPLES = 256


def sample_offsets(n: int) -> np.ndarray:
    """``(n, 2)`` sub-pixel sample positions in ``(0, 1)`` (x right, y down) for ``n`` samples
    per pixel; both backends shade at these, so that their images agree sample for sample.

    A stratified n-rooks pattern: for ``n = c r`` (``c`` the largest divisor of ``n`` up to
    ``sqrt(n)``) one sample in each of ``c x r`` cells, and every sample alone in its column
    and in its row of the ``n x n`` sub-grid, so an edge near the horizontal or the vertical
    gets ``n + 1`` coverage levels; 4 is the usual rotated grid. Prime ``n`` takes the rank-1
    lattice ``((k g mod n) + 1/2, k + 1/2) / n`` with ``g = round(sqrt(n))``; 1 is the pixel
    centre. The mean position is the pixel centre exactly.
    """
    n = int(n)
    if n < 1:
        raise InputError("samples", f"must be a positive integer, got {n}")
    cols = max(a for a in range(1, math.isqrt(n) + 1) if n % a == 0)
    rows = n // cols
    if cols > 1:
        i, j = np.meshgrid(np.arange(cols), np.arange(rows), indexing="ij")
        x = (i * rows + (rows - 1 - j) + 0.5) / n
        y = (j * cols + i + 0.5) / n
    else:  # n prime (or 1): one row of cells would put every sample on a diagonal
        k = np.arange(n)
        x = ((k * max(1, round(math.sqrt(n)))) % n + 0.5) / n
        y = (k + 0.5) / n
    return np.stack([x.ravel(), y.ravel()], -1)


class Renderer:
    """Render a fitted model under an environment.

    Parameters
    ----------
    model : lobelight.model.Model
    env : EnvMap or Lighting
    width, height : image size in pixels
    backend : ``"gl"`` (shaders through moderngl/EGL) or ``"torch"`` (the same stages in torch)
    base_res : face resolution of the sharpest prefiltered level (when ``env`` is an EnvMap),
        or ``"auto"``: the one the model's sharpest lobes need under that map
        (:func:`lobelight.render.auto_base_res`)
    sun : shade the map's sun per pixel with shadows (when ``env`` is an EnvMap; see
        :class:`Lighting`)
    device : torch device of the torch path and of the prefiltering
    ctx : an existing moderngl context (a window's), for ``"gl"``
    samples : samples per pixel (anti-aliasing), 1..256; 1 shades the pixel centre alone.
        Each pixel is the mean of its samples at :func:`sample_offsets` (a box filter over
        the pixel): silhouettes, shadow edges and highlights are smoothed alike. Both backends
        shade the same sample points, one frame-sized pass per sample (the cost grows about
        linearly in ``samples``; memory does not).

    Images are linear radiance, clamped at 0 per pixel: the SH diffuse term can ring below
    zero in creases, and radiance is never negative.
    """

    def __init__(
        self,
        model,
        env,
        width: int = 512,
        height: int = 512,
        *,
        backend: str = "gl",
        base_res: int | str = "auto",
        device=None,
        ctx=None,
        sun: bool = False,
        samples: int = 4,
    ):
        if backend not in BACKENDS:
            raise InputError("backend", f"must be one of {BACKENDS}, got {backend!r}")
        if not (1 <= int(width) <= 16384 and 1 <= int(height) <= 16384):
            raise InputError("resolution", f"must be 1..16384 pixels, got {width}x{height}")
        if (
            isinstance(samples, bool)
            or not isinstance(samples, (int, np.integer))
            or not 1 <= samples <= MAX_SAMPLES
        ):
            raise InputError("samples", f"must be an integer 1..{MAX_SAMPLES}, got {samples!r}")
        if device is not None:
            model = model.to(device)
        self.model = model
        self._builders: tuple[ChainBuilder, ChainBuilder] | None = None  # set_environment's
        self.lighting = self._as_lighting(env, base_res, sun)
        self.width, self.height = int(width), int(height)
        self.backend = backend
        self.samples = int(samples)
        #: (S, 2) the sub-pixel sample positions both backends shade
        self.offsets = sample_offsets(self.samples)
        self._gl = None
        self._caster = None  # the torch path's BVH, built on first use and kept
        if backend == "gl":
            self._gl = GLRenderer(
                model, self.lighting, self.width, self.height, ctx=ctx, offsets=self.offsets
            )

    @property
    def gl(self) -> GLRenderer | None:
        """The shader path's renderer (its ``draw``, ``read``, ``present``, GL context and
        timer queries), for code that drives frames itself, as the benchmarks do; None on the
        torch path. It changes when :meth:`set_environment` rebuilds it."""
        return self._gl

    def set_environment(self, env) -> None:
        """Light the next frames by another environment: relighting without a new renderer.

        Parameters
        ----------
        env : EnvMap, prepared as the current lighting was (its base resolution, SH order and
            ``sun``) with the chains built by two :class:`lobelight.envmap.ChainBuilder` the
            renderer keeps (no disk cache; on CUDA one graph launch per chain), or a
            :class:`Lighting` with the model's SH order.

        The shader path writes the new chain, background, SH and sun into its textures and
        uniforms in place, keeping its programs, the model's data and its targets; only when
        the map's sun appears or disappears (a sun is found in one map and not the other), or
        a Lighting of another base resolution is given, does it make them again. The torch path
        reads the lighting at each frame. A Lighting made here from an EnvMap holds until the
        next call, which rebuilds its chains in the same buffers.
        """
        old = self.lighting
        lighting = self._as_lighting(env, old.base_res, old.sun_split, rebuilt=True)
        if self._gl is not None and not self._gl.set_lighting(lighting):
            gl = self._gl
            gl.make_current()  # the new renderer's objects go into the old one's context
            self._gl = GLRenderer(
                self.model,
                lighting,
                self.width,
                self.height,
                ctx=gl.ctx,
                offsets=self.offsets,
                hdr_dtype=gl.hdr_dtype,
            )
            self._gl.own_ctx, gl.own_ctx = gl.own_ctx, False  # the context passes to the new
            gl.release()
        self.lighting = lighting

    def _as_lighting(
        self, env, base_res: int | str, sun: bool, *, rebuilt: bool = False
    ) -> Lighting:
        """``env`` as the model's Lighting: a Lighting as it is, an EnvMap prepared at
        ``base_res`` (``"auto"``: :func:`auto_base_res`) with ``sun`` on the model's device
        (``rebuilt``: its chains by the renderer's ChainBuilders); InputError unless its SH
        order is the model's."""
        model = self.model
        if isinstance(env, Lighting):
            lighting = env
        elif isinstance(env, EnvMap):
            if base_res == "auto":
                base_res = auto_base_res(model, env)
            if rebuilt and (self._builders is None or self._builders[0].base_res != base_res):
                self._builders = tuple(
                    ChainBuilder(base_res=base_res, device=model.device) for _ in range(2)
                )
            lighting = Lighting(
                env,
                base_res=base_res,
                device=model.device,
                sun=sun,
                sh_order=model.sh_order,
                builders=self._builders if rebuilt else None,
            )
        else:
            raise InputError("env", f"expected an EnvMap or Lighting, got {type(env).__name__}")
        if lighting.sh.shape[0] != model.diffuse.shape[1]:
            raise InputError(
                "env",
                f"lighting projected to {lighting.sh.shape[0]} SH coefficients, the model's "
                f"diffuse transfer has {model.diffuse.shape[1]}",
            )
        return lighting

    def render(
        self,
        camera: Camera,
        light_rotation=None,
        *,
        diffuse: bool = True,
        glossy: bool = True,
        background: bool = True,
        return_mask: bool | str = False,
    ):
        """Linear radiance ``(H, W, 3)`` float32, non-negative (and the ``(H, W)`` mask).

        Parameters
        ----------
        camera : Camera (Mitsuba's perspective conventions)
        light_rotation : None, a (3, 3) rotation, or degrees about +y; the environment turns
            (radiance from ``d`` becomes ``L(R^T d)``)
        diffuse, glossy : which parts to include;  background : show the environment
        return_mask : ``True``: also the ``(H, W)`` bool mask of the pixels entirely on the
            object (every sample hit it: no background mixed in; with ``samples=1``, the pixel
            centre hit it); ``"coverage"``: the ``(H, W)`` float32 fraction of the samples
            that hit it (0 .. 1, in steps of ``1 / samples``)
        """
        if not isinstance(camera, Camera):
            raise InputError("camera", f"expected a Camera, got {type(camera).__name__}")
        if return_mask not in (False, True, "coverage"):
            raise InputError(
                "return_mask", f"must be False, True or 'coverage', got {return_mask!r}"
            )
        rot = as_rotation(light_rotation)
        if self._gl is not None:
            self._gl.draw(camera, rot, diffuse=diffuse, glossy=glossy, background=background)
            img, cov = self._gl.read()
        else:
            img, cov = render_torch(
                self.model,
                self.lighting,
                camera,
                self.width,
                self.height,
                rot=rot,
                diffuse=diffuse,
                glossy=glossy,
                background=background,
                caster=self._ray_caster(),
                offsets=self.offsets,
            )
        img = img.clamp_min(0)
        if return_mask == "coverage":
            return img, cov
        return (img, self._full(cov)) if return_mask else img

    def render_pixels(self, camera: Camera, pixels, light_rotation=None, **parts):
        """The torch path at ``pixels (P, 2)`` (row, column), with the renderer's samples:
        ``(P, 3)`` radiance (non-negative) and ``(P,)`` bool mask (as ``render``'s)."""
        img, cov = render_torch(
            self.model,
            self.lighting,
            camera,
            self.width,
            self.height,
            rot=as_rotation(light_rotation),
            pixels=pixels,
            caster=self._ray_caster(),
            offsets=self.offsets,
            **parts,
        )
        return img.clamp_min(0), self._full(cov)

    def _full(self, coverage: torch.Tensor) -> torch.Tensor:
        """Pixels whose every sample hit the object (half a sample's weight of slack for the
        float sums of the shader path)."""
        return coverage > 1.0 - 0.5 / self.samples

    def _ray_caster(self) -> RayCaster:
        if self._caster is None:
            self._caster = RayCaster(self.model.mesh, offset=0.0)
        return self._caster

    def close(self) -> None:
        if self._gl is not None:
            self._gl.release()
            self._gl = None

    def __enter__(self) -> Renderer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
