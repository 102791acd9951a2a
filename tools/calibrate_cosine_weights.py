"""Calibrate the cosine lobes' visibility weights of eq. (39), once, on one scene (paper 5.3).

    python tools/calibrate_cosine_weights.py            # writes src/lobelight/cosine/weights.json

The paper: "Weights can be adjusted manually once with a single scene (one plane, one object
and one light source is enough) so as to obtain smooth shadows ... This process is performed
only once and the resulting weights can be used with any scene." Its manual procedure sets the
first level so that the umbra is dark and each further level so that shadows keep their
smoothness, for ``dist`` in ``{0.25, 0.5, 1, ..., 10}``.

Here the same scene and the same unknowns, solved by least squares instead of by eye. The
rendered radiance is linear in the weights::

    L_o(x) = U(x) - sum_{d, n} W[d, n] F_{d, n}(x),
    F_{d, n}(x) = sum_{leaves k of depth d} phi_n(dist(x)) ∫ m c_k

(``U`` unoccluded, ``phi_n`` the hat functions of the linear interpolation in ``dist``;
:func:`lobelight.cosine.shadow_features` gives ``U`` and each leaf's ``∫ m c_k``), so ``W`` of
one ``(mode, max depth)`` minimises ``sum_x (L_o(x) - L_MC(x))^2`` with ``W >= 0``
(non-negative least squares), plus a small penalty on second differences along ``dist`` and
towards 1 (for nodes that the data barely constrain). ``L_MC`` is the independent Monte Carlo
reference (:func:`lobelight.reference.cosine.direct_mc`). The scene: a diffuse plane, a torus of
64 spheres lying above it, a spherical light 12 units above the plane with the radius that puts
the plane's points at each ``dist`` node in turn, moved sideways a little so that umbra,
penumbra and light all get samples. The result is the package data file
``lobelight/cosine/weights.json`` (:func:`write_weights`), which the library reads.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch
import trimesh
from scipy.optimize import nnls

from lobelight import brdf
from lobelight._io import atomic_writer
from lobelight._tol import SMALL
from lobelight.cosine import (
    DIST_NODES,
    FLAT_ROTATION,
    MASK_MODES,
    SphereLight,
    cpu_threads,
    get_tables,
    shadow_features,
    sphere_set,
)
from lobelight.reference.cosine import direct_mc

__all__ = ["calibrate_weights", "calibration_scene", "main", "weights_text", "write_weights"]

ROOT = Path(__file__).resolve().parents[1]

#: Where the library reads the weights from, in the source tree.
WEIGHTS_PATH = ROOT / "src" / "lobelight" / "cosine" / "weights.json"

_HEIGHT = 12.0

_ABOUT = (
    "Eq. (39) visibility weights of the cosine lobes, calibrated by "
    "tools/calibrate_cosine_weights.py. Keys mode:max_depth; rows: leaf depth 0..max_depth; "
    "columns: dist in dist_nodes (linear interpolation between them). report: the "
    "calibration's errors relative to each light's unoccluded maximum."
)


def _cluster(seed: int, count: int = 14) -> torch.Tensor:
    """A random cluster of ``count`` spheres 0.6-1.3 above the plane (fragmented shadows)."""
    g = torch.Generator().manual_seed(1000 + seed)
    c = torch.rand(count, 3, generator=g) * torch.tensor([1.4, 0.5, 1.4])
    c = c + torch.tensor([-0.7, 0.6, -0.7])
    return torch.cat([c, 0.12 + 0.15 * torch.rand(count, 1, generator=g)], -1)


def calibration_scene(*, points_per_light: int = 600, seed: int = 0):
    """The calibration scenes: a plane, one object, one light per configuration.

    Objects: the torus of 64 spheres of :func:`lobelight.cosine.default_scene`'s kind (lying
    flat) and two random sphere clusters (fragmented shadows, where many small leaves add up).
    For each ``dist`` node the light is 12 units up with the radius that puts the plane at that
    node, and is shifted sideways once.

    Returns
    -------
    dict with ``configs``: a list of ``(light, points (m, 3) on the plane y = 0, spheres)``
    """
    torus = trimesh.creation.torus(0.9, 0.3, major_sections=24, minor_sections=12)
    # lying flat, its lowest point 0.25 above the plane
    ring = sphere_set(torus, 64, samples=12000, seed=seed).transformed(
        rotation=FLAT_ROTATION, translation=[0.0, 0.55, 0.0]
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


def _design(scene: dict, refs: list, model, up, wo, tables, *, depth: int, mode: str, margin):
    """The least-squares system of one ``(mode, depth)``: rows ``A`` (points, (depth + 1) K)
    of each point's features ``F_{d, n}`` and ``y`` (points,) the radiance its shadow lobes
    must remove, both relative to each light's unoccluded maximum."""
    K = len(DIST_NODES)
    rows, ys = [], []
    for (light, pts, spheres), ref in zip(scene["configs"], refs, strict=True):
        n = up.expand_as(pts)
        with cpu_threads(1):
            rad, feats = shadow_features(
                pts,
                n,
                wo.expand_as(pts),
                model,
                [light],
                spheres,
                depth=depth,
                mode=mode,
                margin=margin,
                tables=tables,
            )
        A = torch.zeros(pts.shape[0], depth + 1, K)
        for pt, dep, i0, i1, lam, val in feats:
            v = val[:, 0]
            A.index_put_((pt, dep, i0), (1 - lam) * v, accumulate=True)
            A.index_put_((pt, dep, i1), lam * v, accumulate=True)
        # errors relative to the light's unoccluded radiance, so that every dist node
        # counts (a small light's radiance is 100x below a large one's)
        norm = rad[:, 0].max().clamp_min(SMALL)
        rows.append(A.reshape(pts.shape[0], -1) / norm)
        ys.append((rad[:, 0] - ref) / norm)  # what the shadow lobes must remove
    return torch.cat(rows).double().numpy(), torch.cat(ys).double().numpy()


def _solve(A: np.ndarray, y: np.ndarray, depth: int, *, smooth: float, prior: float):
    """Non-negative least squares of ``A w = y`` with the regularisers (module docstring):
    second differences along ``dist`` per depth, and a weak pull towards 1. Returns ``w``."""
    K = len(DIST_NODES)
    scale = max(float(np.abs(y).max()), SMALL)
    ncol = A.shape[1]
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
    return w


def calibrate_weights(
    *,
    depths: tuple[int, ...] = (3, 4, 5),
    modes: tuple[str, ...] = MASK_MODES,
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
    model = brdf.Lambert(1.0)
    up = torch.tensor([0.0, 1.0, 0.0])
    wo = torch.nn.functional.normalize(torch.tensor([0.0, 1.0, 1.0]), dim=0)
    refs = []
    with cpu_threads(1):
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
    for mode in modes:
        for depth in depths:
            A, y = _design(
                scene, refs, model, up, wo, tables, depth=depth, mode=mode, margin=margin
            )
            w = _solve(A, y, depth, smooth=smooth, prior=prior)
            before = A @ np.ones(A.shape[1]) - y
            after = A @ w - y
            key = f"{mode}:{depth}"
            out["weights"][key] = np.round(w.reshape(depth + 1, len(DIST_NODES)), 5).tolist()
            out["report"][key] = {
                "rms_before": float(np.sqrt((before**2).mean())),
                "max_before": float(np.abs(before).max()),
                "rms_after": float(np.sqrt((after**2).mean())),
                "max_after": float(np.abs(after).max()),
                "points": int(A.shape[0]),
            }
    out["seconds"] = time.perf_counter() - t0
    return out


def weights_text(result: dict) -> str:
    """The data file's JSON text of :func:`calibrate_weights`' ``result``: ``about``,
    ``dist_nodes``, ``weights`` (one line per leaf depth) and ``report``.

    JSON writes each float as Python's shortest ``repr`` that reads back as the same float, so
    the library reads exactly the values calibrated.
    """
    tables = []
    for key, rows in result["weights"].items():
        body = ",\n".join(f"   {json.dumps(row)}" for row in rows)
        tables.append(f"  {json.dumps(key)}: [\n{body}\n  ]")
    report = json.dumps(result["report"], indent=1).replace("\n", "\n ")
    text = (
        "{\n"
        f' "about": {json.dumps(_ABOUT)},\n'
        f' "dist_nodes": {json.dumps(list(DIST_NODES))},\n'
        ' "weights": {\n' + ",\n".join(tables) + "\n },\n"
        f' "report": {report}\n'
        "}\n"
    )
    doc = json.loads(text)  # the layout above is hand-made: it must read back as the data
    if doc["weights"] != result["weights"] or doc["report"] != result["report"]:
        raise AssertionError("the weights' JSON text does not read back as the weights")
    return text


def write_weights(result: dict, path: str | Path | None = None) -> Path:
    """Write the weights as JSON (:func:`weights_text`) atomically; default
    :data:`WEIGHTS_PATH`, the file the library reads."""
    path = Path(path) if path is not None else WEIGHTS_PATH
    with atomic_writer(path) as f:
        f.write(weights_text(result).encode())
    return path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--depths", type=int, nargs="+", default=[3, 4, 5], help="masks' max depths")
    ap.add_argument("--modes", nargs="+", default=list(MASK_MODES), choices=MASK_MODES)
    ap.add_argument("--points-per-light", type=int, default=600)
    ap.add_argument("--mc-samples", type=int, default=256, help="reference samples per point")
    ap.add_argument("--smooth", type=float, default=0.02, help="second-difference penalty")
    ap.add_argument("--prior", type=float, default=1e-3, help="pull of each weight towards 1")
    ap.add_argument("--margin", type=float, default=1.0, help="visibility square / light cap")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "-o", "--output", type=Path, default=WEIGHTS_PATH, help="the JSON file to write"
    )
    args = ap.parse_args(argv)
    result = calibrate_weights(
        depths=tuple(args.depths),
        modes=tuple(args.modes),
        points_per_light=args.points_per_light,
        mc_samples=args.mc_samples,
        smooth=args.smooth,
        prior=args.prior,
        margin=args.margin,
        seed=args.seed,
    )
    path = write_weights(result, args.output)
    print(json.dumps(result["report"], indent=1))
    print(f"wrote {path} in {result['seconds']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
