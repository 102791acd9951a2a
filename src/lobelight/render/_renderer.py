"""``Renderer``: one front for the shader path and the torch path."""

from __future__ import annotations

from ..camera import Camera
from ..envmap import EnvMap
from ..errors import InputError
from ..raycast import RayCaster
from ._lighting import Lighting, as_rotation
from ._torch import render_torch

__all__ = ["Renderer"]

BACKENDS = ("gl", "torch")


class Renderer:
    """Render a fitted model under an environment.

    Parameters
    ----------
    model : lobelight.model.Model
    env : EnvMap or Lighting
    width, height : image size in pixels
    backend : ``"gl"`` (shaders through moderngl/EGL) or ``"torch"`` (the same stages in torch)
    base_res : face resolution of the sharpest prefiltered level (when ``env`` is an EnvMap)
    sun : shade the map's sun per pixel with shadows (when ``env`` is an EnvMap; see
        :class:`Lighting`)
    device : torch device of the torch path and of the prefiltering
    ctx : an existing moderngl context (a window's), for ``"gl"``
    """

    def __init__(
        self,
        model,
        env,
        width: int = 512,
        height: int = 512,
        *,
        backend: str = "gl",
        base_res: int = 128,
        device=None,
        ctx=None,
        sun: bool = False,
    ):
        if backend not in BACKENDS:
            raise InputError("backend", f"must be one of {BACKENDS}, got {backend!r}")
        if not (1 <= int(width) <= 16384 and 1 <= int(height) <= 16384):
            raise InputError("resolution", f"must be 1..16384 pixels, got {width}x{height}")
        if device is not None:
            model = model.to(device)
        self.model = model
        if isinstance(env, Lighting):
            self.lighting = env
        elif isinstance(env, EnvMap):
            self.lighting = Lighting(env, base_res=base_res, device=model.device, sun=sun)
        else:
            raise InputError("env", f"expected an EnvMap or Lighting, got {type(env).__name__}")
        if model.diffuse.shape[1] != self.lighting.sh.shape[0]:
            raise InputError(
                "env",
                f"lighting projected to {self.lighting.sh.shape[0]} SH coefficients, the "
                f"model's diffuse transfer has {model.diffuse.shape[1]}",
            )
        self.width, self.height = int(width), int(height)
        self.backend = backend
        self._gl = None
        self._caster = None  # the torch path's BVH, built on first use and kept
        if backend == "gl":
            from ._gl import GLRenderer

            self._gl = GLRenderer(model, self.lighting, self.width, self.height, ctx=ctx)

    def render(
        self,
        camera: Camera,
        light_rotation=None,
        *,
        diffuse: bool = True,
        glossy: bool = True,
        background: bool = True,
        return_mask: bool = False,
    ):
        """Linear radiance ``(H, W, 3)`` float32 (and the ``(H, W)`` object mask).

        Parameters
        ----------
        camera : Camera (Mitsuba's perspective conventions)
        light_rotation : None, a (3, 3) rotation, or degrees about +y; the environment turns
            (radiance from ``d`` becomes ``L(R^T d)``)
        diffuse, glossy : which parts to include;  background : show the environment
        """
        if not isinstance(camera, Camera):
            raise InputError("camera", f"expected a Camera, got {type(camera).__name__}")
        rot = as_rotation(light_rotation)
        if self._gl is not None:
            self._gl.draw(camera, rot, diffuse=diffuse, glossy=glossy, background=background)
            img, mask = self._gl.read()
        else:
            img, mask = render_torch(
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
            )
        return (img, mask) if return_mask else img

    def render_pixels(self, camera: Camera, pixels, light_rotation=None, **parts):
        """The torch path at ``pixels (P, 2)`` (row, column): ``(P, 3)`` and ``(P,)`` mask."""
        return render_torch(
            self.model,
            self.lighting,
            camera,
            self.width,
            self.height,
            rot=as_rotation(light_rotation),
            pixels=pixels,
            caster=self._ray_caster(),
            **parts,
        )

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
