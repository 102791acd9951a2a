"""Calibration of the visibility weights of eq. (39), once, on one scene (paper 5.3).

The paper: "Weights can be adjusted manually once with a single scene (one plane, one object
and one light source is enough) so as to obtain smooth shadows ... This process is performed
only once and the resulting weights can be used with any scene." Its manual procedure sets the
first level so that the umbra is dark and each further level so that shadows keep their
smoothness, for ``dist`` in ``{0.25, 0.5, 1, ..., 10}``.

Here the same scene and the same unknowns, solved by least squares instead of by eye. The
rendered radiance is linear in the weights::

    L_o(x) = U(x) - sum_{d, n} W[d, n] F_{d, n}(x),
    F_{d, n}(x) = sum_{leaves k of depth d} phi_n(dist(x)) ∫ m c_k

(``U`` unoccluded, ``phi_n`` the hat functions of the linear interpolation in ``dist``), so
``W`` of one ``(mode, max depth)`` minimises ``sum_x (L_o(x) - L_MC(x))^2`` with ``W >= 0``
(non-negative least squares), plus a small penalty on second differences along ``dist`` and
towards 1 (for nodes that the data barely constrain). ``L_MC`` is the independent Monte Carlo
reference (:func:`~._reference.direct_mc`). The scene: a diffuse plane, a torus of 64
spheres lying above it, a spherical light 12 units above the plane with the radius that puts
the plane's points at each ``dist`` node in turn, moved sideways a little so that umbra,
penumbra and light all get samples. The result is stored in :mod:`._weights`
(:func:`write_weights`).
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np
import torch
import trimesh
from scipy.optimize import nnls

from .. import brdf as _brdf
from .._io import atomic_writer
from ..cosine import SphereLight, get_tables, sphere_set
from ..cosine._shade import _shade_chunk
from ..cosine._tables import _cpu_threads
from ..cosine._visibility import DIST_NODES, MODES
from ..reference.cosine import direct_mc

__all__ = ["calibrate_weights", "calibration_scene", "write_weights"]

_HEIGHT = 12.0


def _cluster(seed: int, count: int = 14) -> torch.Tensor:
    """A random cluster of ``count`` spheres 0.6-1.3 above the plane (fragmented shadows)."""
    g = torch.Generator().manual_seed(1000 + seed)
    c = torch.rand(count, 3, generator=g) * torch.tensor([1.4, 0.5, 1.4])
    c = c + torch.tensor([-0.7, 0.6, -0.7])
    return torch.cat([c, 0.12 + 0.15 * torch.rand(count, 1, generator=g)], -1)


def calibration_scene(*, points_per_light: int = 600, seed: int = 0):
    """The calibration scenes: a plane, one object, one light per configuration.

    Objects: the torus of 64 spheres of :func:`~._scene.default_scene`'s kind (lying flat)
    and two random sphere clusters (fragmented shadows, where many small leaves add up). For
    each ``dist`` node the light is 12 units up with the radius that puts the plane at that
    node, and is shifted sideways once.

    Returns
    -------
    dict with ``configs``: a list of ``(light, points (m, 3) on the plane y = 0, spheres)``
    """
    torus = trimesh.creation.torus(0.9, 0.3, major_sections=24, minor_sections=12)
    # lying flat, its lowest point 0.25 above the plane
    ring = sphere_set(torus, 64, samples=12000, seed=seed).transformed(
        rotation=[[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]], translation=[0.0, 0.55, 0.0]
    )
    objects = [ring.spheres, _cluster(seed), _cluster(seed + 1)]
    gen = torch.Generator().manual_seed(seed)
    configs = []
    for dist in DIST_NODES:
        theta = math.atan(0.5 / dist)
        radius = _HEIGHT * math.sin(theta)
        for k, spheres in enumerate(objects):
            shift = 1.5 * (k % 2)
            light = SphereLight((shift, _HEIGHT, 0.4 * shift), radius, (1.0, 1.0, 1.0))
            # the shadow's extent grows with the light: penumbra width ~ 0.55 tan(theta) + 1.2
            reach = 1.3 + 0.8 * math.tan(theta)
            r = reach * torch.sqrt(torch.rand(points_per_light, generator=gen))
            a = 2 * math.pi * torch.rand(points_per_light, generator=gen)
            pts = torch.stack([r * torch.cos(a), torch.zeros_like(r), r * torch.sin(a)], -1)
            pts = pts - torch.tensor([0.05 * shift, 0.0, 0.02 * shift])
            configs.append((light, pts, spheres))
    return {"configs": configs}


def calibrate_weights(
    *,
    depths: tuple[int, ...] = (3, 4, 5),
    modes: tuple[str, ...] = MODES,
    points_per_light: int = 600,
    mc_samples: int = 256,
    smooth: float = 0.02,
    prior: float = 1e-3,
    margin: float = 1.0,
    seed: int = 0,
) -> dict:
    """Fit the eq. (39) weights for each ``(mode, depth)`` (module docstring).

    Returns
    -------
    dict: ``weights`` {"mode:depth": (depth + 1) x 12 nested lists}, per key the rms and max
    error (relative to each light's largest unoccluded radiance) on the calibration points
    before (all weights 1) and after, and seconds
    """
    t0 = time.perf_counter()
    tables = get_tables()
    scene = calibration_scene(points_per_light=points_per_light, seed=seed)
    model = _brdf.Lambert(1.0)
    up = torch.tensor([0.0, 1.0, 0.0])
    wo = torch.nn.functional.normalize(torch.tensor([0.0, 1.0, 1.0]), dim=0)
    refs = []
    with _cpu_threads(1):
        for light, pts, spheres in scene["configs"]:
            n = up.expand_as(pts)
            ref, _ = direct_mc(
                pts,
                n,
                wo.expand_as(pts),
                model,
                light,
                spheres=spheres,
                samples=mc_samples,
                seed=seed,
            )
            refs.append(ref[:, 0].float())
    out: dict = {"weights": {}, "report": {}}
    K = len(DIST_NODES)
    for mode in modes:
        for depth in depths:
            rows, ys = [], []
            for (light, pts, spheres), ref in zip(scene["configs"], refs, strict=True):
                n = up.expand_as(pts)
                with _cpu_threads(1), torch.no_grad():
                    rad, _, _, feats = _shade_chunk(
                        pts,
                        n,
                        wo.expand_as(pts),
                        model,
                        [light],
                        spheres,
                        None,
                        None,
                        tables,
                        depth=depth,
                        mode=mode,
                        threshold=0.0,
                        margin=margin,
                        cosine="product",
                        preserve=True,
                        features=True,
                    )
                A = torch.zeros(pts.shape[0], depth + 1, K)
                for pt, dep, i0, i1, lam, val in feats:
                    v = val[:, 0]
                    A.index_put_((pt, dep, i0), (1 - lam) * v, accumulate=True)
                    A.index_put_((pt, dep, i1), lam * v, accumulate=True)
                # errors relative to the light's unoccluded radiance, so that every dist node
                # counts (a small light's radiance is 100x below a large one's)
                norm = rad[:, 0].max().clamp_min(1e-12)
                rows.append(A.reshape(pts.shape[0], -1) / norm)
                ys.append((rad[:, 0] - ref) / norm)  # what the shadow lobes must remove
            A = torch.cat(rows).double().numpy()
            y = torch.cat(ys).double().numpy()
            scale = max(float(np.abs(y).max()), 1e-12)
            ncol = A.shape[1]
            # regularisers: second differences along dist (per depth) and a weak pull to 1
            reg = []
            for d in range(depth + 1):
                for k in range(1, K - 1):
                    r = np.zeros(ncol)
                    r[d * K + k - 1], r[d * K + k], r[d * K + k + 1] = 1, -2, 1
                    reg.append(r * smooth * scale)
            eye = np.eye(ncol) * prior * scale
            A_aug = np.concatenate([A, np.array(reg), eye])
            y_aug = np.concatenate([y, np.zeros(len(reg)), prior * scale * np.ones(ncol)])
            w, _ = nnls(A_aug, y_aug, maxiter=50 * ncol)
            before = A @ np.ones(ncol) - y
            after = A @ w - y
            key = f"{mode}:{depth}"
            out["weights"][key] = np.round(w.reshape(depth + 1, K), 5).tolist()
            out["report"][key] = {
                "rms_before": float(np.sqrt((before**2).mean())),
                "max_before": float(np.abs(before).max()),
                "rms_after": float(np.sqrt((after**2).mean())),
                "max_after": float(np.abs(after).max()),
                "points": int(A.shape[0]),
            }
    out["seconds"] = time.perf_counter() - t0
    return out


def write_weights(result: dict, path: str | Path | None = None) -> Path:
    """Write :mod:`._weights` (a plain Python literal, no pickles) atomically."""
    path = Path(path) if path is not None else Path(__file__).with_name("_weights.py")
    body = json.dumps(result["weights"], indent=1)
    report = json.dumps(result["report"], indent=1).replace("\n", "\n# ")
    text = (
        '"""Eq. (39) visibility weights, calibrated by :func:`~._calibrate.calibrate_weights`.\n\n'
        "Keys ``mode:max_depth``; rows: leaf depth 0..max_depth; columns: ``dist`` in\n"
        "``DIST_NODES``. Regenerate with ``write_weights(calibrate_weights())``.\n"
        '"""\n\n'
        f"# calibration errors (relative to each light's unoccluded maximum):\n# {report}\n\n"
        f"WEIGHTS = {body}\n"
    )
    with atomic_writer(path) as f:
        f.write(text.encode())
    return path
