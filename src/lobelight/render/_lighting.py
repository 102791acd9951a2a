"""Lighting for rendering: the prefiltered chain, the SH projection and the map itself.

A lighting rotation ``R`` turns the environment: radiance from ``d`` becomes ``L(R^T d)``.
Nothing is re-prefiltered for it (the paper, section 5): a Gaussian with mean ``mu`` sees the
rotated lighting as the original seen by ``R^T mu``, the SH diffuse term rotates its 25
coefficients, and the background looks up ``R^T d``.

With ``sun=True`` a compact bright source (a sun, a lamp, a window: found by its concentration,
:func:`lobelight.envmap.extract_sun`) is taken out of the map for the diffuse part: the SH
projection is of the map without it, and renderers add its diffuse light per pixel times the
visible fraction of its disc, a soft shadow of its angular size (:mod:`._sun_shadow`: shadow
rays over the disc in the torch path, percentage-closer soft shadows in the shader); the sun
turns with the lighting, to ``R d``. Where the
model's specular BRDF can be evaluated per pixel (:mod:`._sun_glossy`), the glossy part too
takes the sun per pixel and its Gaussians integrate the map without it
(:attr:`Lighting.rest_prefiltered`); otherwise the glossy part keeps the whole map. The
background always shows the whole map.
"""

from __future__ import annotations

import math

import torch

from .._memory import max_base_res
from ..envmap import (
    TEXELS_PER_SIGMA,
    ChainBuilder,
    EnvMap,
    Prefiltered,
    Sun,
    extract_sun,
    prefilter,
)
from ..errors import InputError
from ..fit import lobe_shape
from ..lobes import sh

__all__ = [
    "AUTO_BASE_BLUR",
    "AUTO_BASE_RES_MAX",
    "AUTO_BASE_RES_MIN",
    "AUTO_SHARP_QUANTILE",
    "Lighting",
    "as_rotation",
    "auto_base_res",
]

#: The chain's base resolution for every model whose lobes it resolves there: the GGX alpha
#: 0.03 teapot and bunny score the same at 1024 (docs/method.md); rough and plastic lobes are
#: wider still.
AUTO_BASE_RES_MIN = 256
#: The largest base resolution chosen by default (a chain of 403 MB at 1024: four phases of
#: six 1024² RGB float32 faces and the mips below; with a sun two chains); larger ones only
#: when asked for.
AUTO_BASE_RES_MAX = 1024
#: The share of a model's glossy vertices whose lobe the chain must resolve: the sharpest
#: tenth decides (a mirror-like visor on a rough helmet).
AUTO_SHARP_QUANTILE = 0.1
#: The base level's Gaussian at most this share of the sharp lobe's (:func:`auto_base_res`).
AUTO_BASE_BLUR = 0.5
# Vertices measured (evenly spread), as the Gaussians' rule measures them.
_AUTO_VERTICES = 256


def as_rotation(r, *, device=None) -> torch.Tensor:
    """A ``(3, 3)`` float32 rotation from ``None`` (identity), a matrix, or an angle in degrees
    about +y (the vertical of the lat-long maps: a turn of the sky)."""
    if r is None:
        return torch.eye(3, device=device)
    if isinstance(r, (int, float)):
        a = math.radians(float(r))
        c, s = math.cos(a), math.sin(a)
        return torch.tensor([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]], device=device)
    m = torch.as_tensor(r, dtype=torch.float32, device=device)
    if m.shape != (3, 3) or not bool(torch.isfinite(m).all()):
        raise InputError("light_rotation", f"must be a finite 3x3 matrix, got {tuple(m.shape)}")
    if (
        float((m @ m.T - torch.eye(3, device=m.device)).abs().max()) > 1e-4
        or float(torch.det(m)) < 0
    ):
        raise InputError("light_rotation", "must be a rotation (orthogonal, determinant +1)")
    return m


def auto_base_res(model, env: EnvMap) -> int:
    """The chain's base resolution that resolves ``model``'s sharp lobes under ``env``.

    A lobe sharper than the chain's base level is read there, widened by the base level's own
    Gaussian (standard deviation ``sigma_0 = 2.5`` texels, ``5 / res`` radians at a face's
    centre): a mirror-like surface (GGX alpha 0.001-0.01) reflects a soft copy of the map. Each
    glossy vertex's lobe, for a view along its normal, is taken as the Gaussian of the same peak
    density ``p`` (the BRDF times the cosine at the mirror direction over the lobe's albedo,
    :func:`lobelight.fit.lobe_shape`): ``sigma = 1 / sqrt(2 pi p)``, exactly ``sqrt(2) alpha``
    for GGX and ``1 / sqrt(e)`` for a Phong lobe. The sharpest tenth of the vertices
    (:data:`AUTO_SHARP_QUANTILE`) decides: the answer is the smallest power of two from
    :data:`AUTO_BASE_RES_MIN` whose ``sigma_0`` is at most :data:`AUTO_BASE_BLUR` of their
    ``sigma`` (the lobe's peak lowered by at most ``1 - 1 / (1 + 0.5^2) = 20 %``), within a
    cap: at most :data:`AUTO_BASE_RES_MAX`, at most the largest whose chain fits this machine's
    memory share (:func:`lobelight._memory.max_base_res`, as ``--base-res``'s maximum), and at
    most four texels per texel of the map's own (a lat-long map ``W`` wide has about ``W / 4``
    per cube face; a small map's cap may be below :data:`AUTO_BASE_RES_MIN`, and is then the
    answer). Past the map's pixels a finer chain still follows the bilinear interpolant the path
    tracer reads, and stops gaining soon after (docs/method.md). A material without a glossy
    lobe takes the smallest.

    Parameters
    ----------
    model : lobelight.model.Model;  env : the EnvMap to prefilter
    """
    native = env.data.shape[-2] // 4 if env.layout == "latlong" else env.data.shape[1]
    cap = 2 ** int(math.log2(max(8, min(AUTO_BASE_RES_MAX, max_base_res(), 4 * native))))
    res = min(AUTO_BASE_RES_MIN, cap)
    mats = model.materials
    v = mats.n_vertices
    if mats.specular is None or v == 0:
        return res
    count = min(v, _AUTO_VERTICES)
    vidx = torch.div(torch.arange(count) * v, count, rounding_mode="floor")
    vidx = vidx.to(mats.diffuse.device)
    albedo = lobe_shape(mats, vidx)["albedo"]
    n = torch.tensor([0.0, 0.0, 1.0], device=vidx.device).expand(count, 3)
    peak = mats.specular.take(vidx).eval(n, n, n).mean(-1)  # (B,) f cos at the mirror
    glossy = (albedo > 0) & (peak > 0)
    if not bool(glossy.any()):
        return res
    sigma = (2 * math.pi * peak[glossy] / albedo[glossy]).rsqrt()
    sigma = float(torch.quantile(sigma.float(), AUTO_SHARP_QUANTILE))
    # sigma_0 = 2 TEXELS_PER_SIGMA / res (lam_0 = (res / (2 TEXELS_PER_SIGMA))^2)
    while res < cap and 2 * TEXELS_PER_SIGMA / res > AUTO_BASE_BLUR * sigma:
        res *= 2
    return res


class Lighting:
    """An environment ready to render with.

    Parameters
    ----------
    env : EnvMap
    base_res : face resolution of the sharpest prefiltered level (power of two): lobes up to
        ``lam = (base_res / 5)**2`` are resolved (655 at 128, 10486 at 512)
    sh_order : order of the diffuse SH projection (5 = 25 coefficients, the transfer's order)
    device : torch device
    sun : take a compact bright source out of the diffuse lighting and shade it per pixel with
        its soft shadow (module docstring); a map without one
        (:func:`lobelight.envmap.extract_sun`) is used whole, and ``self.sun`` is None
    builders : None, or two :class:`lobelight.envmap.ChainBuilder` at ``base_res`` on
        ``device`` that build the chains (the whole map's, the map's without its sun) instead
        of :func:`lobelight.envmap.prefilter` and its disk cache: for lighting that changes
        every frame. A builder's chain is overwritten when it builds again, so such a Lighting
        holds until the next one made with the same builders builds its chains.

    Attributes
    ----------
    prefiltered : Prefiltered (built on first use);  sh : (sh_order**2, 3) float32;  env : EnvMap
    sun : Sun or None;  sun_split : the ``sun`` asked for
    rest_prefiltered : the prefiltered chain of the map without its sun (built on first use)
    """

    def __init__(
        self,
        env: EnvMap,
        *,
        base_res: int = 128,
        sh_order: int = 5,
        device=None,
        prefiltered: Prefiltered | None = None,
        sun: bool = False,
        builders: tuple[ChainBuilder, ChainBuilder] | None = None,
    ):
        if not isinstance(env, EnvMap):
            raise InputError("env", f"expected an EnvMap, got {type(env).__name__}")
        self.env = env.to(device) if device is not None else env
        self.device = self.env.device
        if builders is not None:
            if len(builders) != 2 or any(
                not isinstance(b, ChainBuilder) or b.base_res != base_res or b.device != self.device
                for b in builders
            ):
                raise InputError(
                    "builders", f"must be two ChainBuilders at base_res {base_res} on {self.device}"
                )
        self._builders = builders
        self.sun_split = bool(sun)
        # both chains are built on first use: a renderer that shades the sun's glossy part
        # per pixel needs only the one without the sun (a fine chain is costly to build)
        self._pf = prefiltered
        self._base_res = prefiltered.base_res if prefiltered is not None else base_res
        self.sun: Sun | None = None
        diffuse_env = self.env
        if sun:
            self.sun, diffuse_env = extract_sun(self.env)
        self._rest_env = diffuse_env
        self._rest_pf: Prefiltered | None = None
        # a static map's resampled cube is kept on disk (read back by the next process)
        cube_cache = builders is None
        self.sh = sh.project_envmap(diffuse_env, sh_order, res=64, cache=cube_cache)
        self.sh = self.sh.to(torch.float32)
        self.name = env.name
        self._rotator = sh.Rotator(self.sh)

    @property
    def base_res(self) -> int:
        """Face resolution of the chains' sharpest level."""
        return self._base_res

    @property
    def prefiltered(self) -> Prefiltered:
        """The prefiltered chain of the whole map."""
        if self._pf is None:
            self._pf = self._chain(self.env, 0)
        return self._pf

    @property
    def rest_prefiltered(self) -> Prefiltered:
        """The prefiltered chain of the map without its sun (the whole map's without a sun)."""
        if self.sun is None:
            return self.prefiltered
        if self._rest_pf is None:
            self._rest_pf = self._chain(self._rest_env, 1)
        return self._rest_pf

    def _chain(self, env: EnvMap, which: int) -> Prefiltered:
        """The chain of ``env``: from builder ``which`` when there are builders, else from
        :func:`lobelight.envmap.prefilter` (and its disk cache)."""
        if self._builders is not None:
            return self._builders[which](env)
        return prefilter(env, base_res=self._base_res, device=self.device)

    def sun_sh_rotated(self, rot: torch.Tensor) -> torch.Tensor:
        """The sun alone as SH of the transfer's order, turned by ``rot``: ``E Y_lm(R s)`` (its
        disc as a point of irradiance ``E``), ``(n, 3)``; zeros without a sun. What lights a
        model's interreflected transfer (:attr:`lobelight.model.Model.bounce`) besides the
        map, since the sun's direct light is shaded per pixel."""
        n = self.sh.shape[0]
        if self.sun is None:
            return torch.zeros(n, 3)
        d = self.sun_direction(rot).to(torch.float32).cpu()
        y = sh.basis(d[None], math.isqrt(n))[0]  # (n,)
        return (y[:, None] * self.sun.irradiance.to(torch.float32).cpu()[None]).float()

    def sh_rotated(self, rot: torch.Tensor) -> torch.Tensor:
        """``(n, 3)`` float32 SH coefficients of the rotated lighting ``L(R^T w)`` (on the CPU:
        it is computed there once per frame, see :class:`lobelight.lobes.sh.Rotator`)."""
        return self._rotator.rotate(rot).to(torch.float32)

    def integrate(self, mu: torch.Tensor, lam: torch.Tensor, rot: torch.Tensor) -> torch.Tensor:
        """``int G(w; mu, lam) L(R^T w) dw``, ``(..., 3)``: the lookup at ``R^T mu``."""
        return self.prefiltered.integrate(mu @ rot.to(mu.device, mu.dtype), lam)

    def lookup(
        self, mu: torch.Tensor, lam: torch.Tensor, rot: torch.Tensor, *, rest: bool = False
    ) -> torch.Tensor:
        """The lighting averaged under the normalised Gaussian, ``integrate / int G``: (..., 3);
        ``rest``: of the map without its sun (:attr:`rest_prefiltered`)."""
        pf = self.rest_prefiltered if rest else self.prefiltered
        return pf.lookup(mu @ rot.to(mu.device, mu.dtype), lam)

    def sun_direction(self, rot: torch.Tensor) -> torch.Tensor:
        """``(3,)`` the sun's direction in the rotated lighting, ``R d`` (requires a sun)."""
        return rot.to(self.sun.direction.device) @ self.sun.direction

    def background(self, dirs: torch.Tensor, rot: torch.Tensor) -> torch.Tensor:
        """Radiance seen along ``dirs (..., 3)`` in the rotated environment, ``(..., 3)``."""
        return self.env.radiance(dirs @ rot.to(dirs.device, dirs.dtype))
