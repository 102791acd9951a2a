"""Monte Carlo ground truth: a path tracer for the same scenes, materials and lighting.

Distant environment lighting, the per-vertex materials of :mod:`lobelight.scene` (Lambert plus
one specular model, interpolated across triangles with barycentric weights, as the renderer
interpolates), smooth shading normals, shadows and interreflection. Each path vertex combines
two strategies with the power heuristic (multiple importance sampling): a light sample drawn
from the environment's luminance (piecewise constant over a cube map) and a BRDF sample, whose
escape also collects the environment. Russian roulette starts at ``rr_depth``.

Path length follows Mitsuba 3's ``max_depth``: 1 sees only the environment, 2 is direct
lighting, 3 adds one bounce, -1 is unbounded (roulette ends paths). With the same scene, camera
(:class:`lobelight.geometry.camera.Camera`), environment file and ``max_depth`` the result agrees
with Mitsuba's ``path`` integrator to Monte Carlo noise (``tests/test_reference.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from .._tol import DIVISOR_F32
from ..errors import InputError
from ..geometry import cubemap
from ..geometry.camera import Camera
from ..geometry.raycast import RayCaster
from ..scene import Materials, Scene

__all__ = ["EnvSampler", "radiance_at", "render"]

#: Cube-map face resolution of the environment's importance-sampling table.
ENV_SAMPLING_RES = 128
#: Added to every texel's luminance in the sampling table: an all-black map (mean 0, so no
#: floor from the mean) still gives every direction a positive density.
_LUMINANCE_FLOOR = 1e-12


class EnvSampler:
    """Importance sampling of an environment map by luminance.

    The table is the luminance of a ``res`` cube map (area-averaged) times texel solid angle, plus
    a floor of 1e-3 of the mean so that no direction has zero density. A sample picks a texel by
    its share and a point uniform in the texel's face coordinates; its solid-angle density is
    ``P(texel) / A_uv * (1 + u^2 + v^2)^(3/2)`` (the gnomonic Jacobian), exact for every direction.
    """

    def __init__(self, env, *, res: int = ENV_SAMPLING_RES):
        self.env = env
        self.res = res
        dev = env.device
        cube = env.to_cubemap(res)  # (6, R, R, 3)
        lum = (cube * torch.tensor([0.2126, 0.7152, 0.0722], device=dev)).sum(-1).clamp_min(0)
        om = cubemap.texel_solid_angles(res, device=dev)
        w = (lum + 1e-3 * float(lum.mean()) + _LUMINANCE_FLOOR) * om
        self.prob = (w / w.sum()).reshape(-1).to(torch.float64)  # (6 R^2,)
        self.cdf = torch.cumsum(self.prob, 0)
        self.cdf[-1] = 1.0
        self.area = (2.0 / res) ** 2

    def sample(self, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Directions from ``u`` (..., 3) uniforms: ``dirs (..., 3)`` and their ``pdf (...)``."""
        r = self.res
        k = torch.searchsorted(self.cdf, u[..., 0].to(torch.float64).contiguous()).clamp(
            max=self.prob.numel() - 1
        )
        face = k // (r * r)
        row = (k // r) % r
        col = k % r
        uu = 2 * (col.to(u.dtype) + u[..., 1]) / r - 1
        vv = 2 * (row.to(u.dtype) + u[..., 2]) / r - 1
        d = torch.nn.functional.normalize(cubemap.face_uv_to_direction(face, uu, vv), dim=-1)
        return d, self.pdf(d)

    def pdf(self, d: torch.Tensor) -> torch.Tensor:
        """Solid-angle density of directions ``d`` (..., 3)."""
        r = self.res
        f, u, v = cubemap.direction_to_face_uv(d)
        col = ((u + 1) * r / 2).floor().long().clamp(0, r - 1)
        row = ((v + 1) * r / 2).floor().long().clamp(0, r - 1)
        p = self.prob[(f * r + row) * r + col].to(d.dtype)
        return p / self.area * (1 + u * u + v * v) ** 1.5


@dataclass
class _Hits:
    point: torch.Tensor  # (n, 3)
    normal: torch.Tensor  # (n, 3) shading normal, on the side of the incoming ray
    materials: Materials  # per hit


def _surface(scene: Scene, tri: torch.Tensor, bary: torch.Tensor, wo: torch.Tensor) -> _Hits:
    mesh = scene.mesh
    corners = mesh.faces[tri]  # (n, 3)
    w = bary[..., None]
    p = (mesh.vertices[corners] * w).sum(1)
    ns = torch.nn.functional.normalize((mesh.normals[corners] * w).sum(1), dim=-1)
    ns = torch.where(((ns * wo).sum(-1) < 0)[:, None], -ns, ns)
    return _Hits(p, ns, scene.materials.interpolate(corners, bary))


def _power(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    a2, b2 = a * a, b * b
    return torch.where(a2 + b2 > 0, a2 / (a2 + b2).clamp_min(DIVISOR_F32), torch.zeros_like(a))


def _trace(
    scene: Scene,
    caster: RayCaster,
    env,
    sampler: EnvSampler,
    hits: _Hits,
    wo: torch.Tensor,
    *,
    max_depth: int,
    depth0: int,
    rr_depth: int,
    gen: torch.Generator,
    first_brdf=None,
) -> torch.Tensor:
    """Radiance leaving surface points toward ``wo`` (n, 3), by MIS path tracing.

    ``depth0`` is the path length already used (1 after a camera ray); ``first_brdf`` overrides
    the material at the first vertex (e.g. only the specular lobe).
    """
    dev = wo.device
    n_all = wo.shape[0]
    out = torch.zeros(n_all, 3, device=dev)
    idx = torch.arange(n_all, device=dev)
    thr = torch.ones(n_all, 3, device=dev)
    depth = depth0
    brdf = first_brdf if first_brdf is not None else hits.materials.brdf()
    p, ns = hits.point, hits.normal

    def rand(*shape):
        return torch.rand(*shape, generator=gen).to(dev)

    while idx.numel() and (max_depth < 0 or depth < max_depth):
        m = idx.numel()
        # light sample (next event estimation)
        dl, pdf_l = sampler.sample(rand(m, 3))
        cos_l = (dl * ns).sum(-1)
        f_l = brdf.eval(dl, wo, ns)
        ok = (cos_l > 0) & (f_l.amax(-1) > 0)
        if bool(ok.any()):
            o = caster.spawn(p[ok], ns[ok], dl[ok])
            vis = ~caster.occluded(o, dl[ok])
            pb = brdf.pdf(dl, wo, ns)[ok]
            contrib = f_l[ok] * (cos_l[ok] / pdf_l[ok])[:, None] * env.radiance(dl[ok])
            contrib = contrib * (_power(pdf_l[ok], pb) * vis)[:, None]
            out.index_add_(0, idx[ok], thr[ok] * contrib)
        # BRDF sample
        wi, weight, pdf_b = brdf.sample(wo, ns, rand(m, 3))
        thr = thr * weight
        alive = thr.amax(-1) > 0
        o = caster.spawn(p, ns, wi)
        tri, _, bary = caster.first_hit(o[alive], wi[alive])
        sel = alive.nonzero().squeeze(-1)
        esc = tri < 0
        if bool(esc.any()):
            e = sel[esc]
            w_mis = _power(pdf_b[e], sampler.pdf(wi[e]))
            out.index_add_(0, idx[e], thr[e] * env.radiance(wi[e]) * w_mis[:, None])
        depth += 1
        hit = ~esc
        sel = sel[hit]
        if not sel.numel() or (max_depth >= 0 and depth >= max_depth):
            break
        wo = -wi[sel]
        hits = _surface(scene, tri[hit], bary[hit], wo)
        thr, idx = thr[sel], idx[sel]
        p, ns = hits.point, hits.normal
        brdf = hits.materials.brdf()
        if depth >= rr_depth:
            q = thr.amax(-1).clamp(0.05, 0.95)
            live = rand(q.numel()) < q
            thr = (thr / q[:, None])[live]
            idx, p, ns, wo = idx[live], p[live], ns[live], wo[live]
            brdf = brdf.take(live.nonzero().squeeze(-1))
    return out


def render(
    scene: Scene,
    env=None,
    camera: Camera | None = None,
    *,
    width: int = 128,
    height: int = 96,
    spp: int = 64,
    max_depth: int = 4,
    rr_depth: int = 5,
    seed: int = 0,
    batch_spp: int | None = None,
    return_stderr: bool = False,
    jitter: bool = True,
    progress=None,
):
    """Render an image by path tracing.

    Parameters
    ----------
    scene : Scene;  env : EnvMap (default the scene's);  camera : default the scene's
    width, height : pixels;  spp : samples per pixel (box filter over the pixel)
    max_depth : Mitsuba's convention (2 = direct lighting only, -1 = unbounded)
    return_stderr : also return the per-pixel standard error of the mean
    jitter : spread each pixel's samples over the pixel (box filter); False traces every
        sample through the pixel centre, as a rasteriser shades (for pixel-exact comparisons)
    progress : optional ``progress(stage, done, total)`` called after each batch of samples
        (``stage`` "reference", counting samples per pixel)

    Returns
    -------
    (H, W, 3) float32 linear radiance [, (H, W, 3) standard error]
    """
    if spp < 1:
        raise InputError("spp", f"must be >= 1, got {spp}")
    env = scene.load_environment() if env is None else env
    camera = scene.camera if camera is None else camera
    dev = scene.mesh.device
    env = env.to(dev)
    caster = RayCaster(scene.mesh)
    sampler = EnvSampler(env)
    gen = torch.Generator().manual_seed(int(seed))
    npix = width * height
    bs = batch_spp or max(1, min(spp, (1 << 18) // npix))
    s1 = torch.zeros(npix, 3, device=dev)
    s2 = torch.zeros(npix, 3, device=dev)
    done = 0
    while done < spp:
        k = min(bs, spp - done)
        off = torch.rand(k, height, width, 2, generator=gen).to(dev)
        if not jitter:
            off = torch.full_like(off, 0.5)
        o, d = camera.rays(width, height, offsets=off, device=dev)
        o, d = o.reshape(-1, 3), d.reshape(-1, 3)
        tri, _, bary = caster.first_hit(o, d)
        val = torch.zeros(o.shape[0], 3, device=dev)
        miss = tri < 0
        if bool(miss.any()):
            val[miss] = env.radiance(d[miss])
        hit = ~miss
        if bool(hit.any()) and max_depth != 1:
            wo = -d[hit]
            hits = _surface(scene, tri[hit], bary[hit], wo)
            val[hit] = _trace(
                scene,
                caster,
                env,
                sampler,
                hits,
                wo,
                max_depth=max_depth,
                depth0=1,
                rr_depth=rr_depth,
                gen=gen,
            )
        val = val.reshape(k, npix, 3)
        s1 += val.sum(0)
        s2 += (val * val).sum(0)
        done += k
        if progress is not None:
            progress("reference", done, spp)
    mean = s1 / spp
    img = mean.reshape(height, width, 3)
    if not return_stderr:
        return img
    var = (s2 / spp - mean * mean).clamp_min(0) * spp / max(spp - 1, 1)
    return img, (var / spp).sqrt().reshape(height, width, 3)


def radiance_at(
    scene: Scene,
    env,
    vertices: torch.Tensor,
    views: torch.Tensor,
    *,
    spp: int = 1024,
    max_depth: int = -1,
    rr_depth: int = 5,
    part: str = "all",
    seed: int = 0,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Radiance leaving mesh vertices toward view directions, by path tracing.

    Parameters
    ----------
    vertices : (B,) vertex ids;  views : (J, 3) directions toward the viewer
    max_depth : counted from the vertex as if a camera ray had reached it (2 = direct only)
    part : "all" (full material), or "specular" (only the specular lobe at the vertex; later
        bounces use the full material): the glossy transport's share, to compare with
        :mod:`lobelight.transport`

    Returns
    -------
    mean, stderr : (B, J, 3) each
    """
    dev = scene.mesh.device
    env = env.to(dev)
    caster = RayCaster(scene.mesh)
    sampler = EnvSampler(env)
    gen = torch.Generator().manual_seed(int(seed))
    vidx = torch.as_tensor(vertices, dtype=torch.int64, device=dev).reshape(-1)
    views = torch.as_tensor(views, dtype=torch.float32, device=dev).reshape(-1, 3)
    b, j = vidx.numel(), views.shape[0]
    v = vidx.repeat_interleave(j)
    wo = views.repeat(b, 1)  # (B J, 3)
    mats = scene.materials.take(v)
    if part == "specular":
        if mats.specular is None:
            raise InputError("part", "the scene has no specular lobe")
        first = mats.specular
    elif part == "all":
        first = None
    else:
        raise InputError("part", f"must be 'all' or 'specular', got {part!r}")
    hits = _Hits(scene.mesh.vertices[v], scene.mesh.normals[v], mats)
    s1 = torch.zeros(b * j, 3, device=dev)
    s2 = torch.zeros(b * j, 3, device=dev)
    chunk = max(1, (1 << 18) // (b * j))
    done = 0
    while done < spp:
        k = min(chunk, spp - done)
        rep = torch.arange(b * j, device=dev).repeat(k)
        h = _Hits(hits.point[rep], hits.normal[rep], mats.take(rep))
        fb = first.take(rep) if first is not None else None
        val = _trace(
            scene,
            caster,
            env,
            sampler,
            h,
            wo[rep],
            max_depth=max_depth,
            depth0=1,
            rr_depth=rr_depth,
            gen=gen,
            first_brdf=fb,
        ).reshape(k, b * j, 3)
        s1 += val.sum(0)
        s2 += (val * val).sum(0)
        done += k
    mean = s1 / spp
    var = (s2 / spp - mean * mean).clamp_min(0) * spp / max(spp - 1, 1)
    return mean.reshape(b, j, 3), (var / spp).sqrt().reshape(b, j, 3)
