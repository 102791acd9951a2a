"""``fit_model``: from a scene to a :class:`lobelight.model.Model` in one call."""

from __future__ import annotations

import contextlib
import os
import platform
import time
from collections.abc import Callable

import torch

from .. import __version__
from ..model import Model, per_unit_albedo
from ..progress import resolve
from ..scene import Scene
from ..transport import BOUNCES, INDIRECT_PATHS, vertex_origins
from ._auto import choose_gaussians
from ._cluster import cluster
from ._floodfill import fit_mesh
from ._memory import MEMORY_GB
from ._objective import Weights
from ._refine import REFINE_ROUNDS, refine_scene

__all__ = ["fit_model"]


def fit_model(
    scene: Scene,
    n_gaussians: int | str = "auto",
    *,
    device=None,
    views: torch.Tensor | None = None,
    weights: Weights | None = None,
    batch: int | None = None,
    indirect_paths: int = INDIRECT_PATHS,
    bounces: int = BOUNCES,
    relax: bool = True,
    progress: bool | Callable[[str, int, int], None] | None = True,
    seed: int = 0,
    checkpoint: str | os.PathLike | None = None,
    checkpoint_every: float = 30.0,
    shadows: bool = True,
    memory_gb: float = MEMORY_GB,
    client=None,
    refine: int = REFINE_ROUNDS,
    threads: int | None = None,
):
    """Fit the glossy transport of every vertex with ``n_gaussians`` Gaussians per view, and its
    SH diffuse transfer (:func:`fit_mesh`), and wrap the result as a model.

    ``n_gaussians``: 1, 2 or 3, or ``"auto"`` (the default): chosen from the material's specular
    lobe (:func:`lobelight.fit.choose_gaussians`: two for long-tailed lobes of moderate
    roughness that carry most of the reflected light, GGX metals of alpha 0.08 to about 0.35,
    one otherwise); the choice and its reason are in the provenance.

    ``memory_gb``: the bake's budget of resident memory (GB, the whole process), from which
    every stage's batch sizes are derived (:func:`fit_mesh`); the provenance records the budget,
    the batch, the chunks that ran side by side and each stage's peak.

    Interreflection is baked by default: ``indirect_paths`` paths per vertex and view of
    indirect glossy, and ``bounces`` bounces of diffuse interreflection in the SH transfer
    (:data:`lobelight.transport.INDIRECT_PATHS`, :data:`lobelight.transport.BOUNCES`); 0 turns
    either off.

    ``checkpoint``: a file the bake's state is saved to, at most every ``checkpoint_every``
    seconds and after each stage; a bake that finds one of the same scene and settings resumes
    from it to the same model (:func:`fit_mesh`).

    ``client``: a ``distributed.Client``, or the address of a Dask scheduler
    (``tcp://HOST:8786``; :func:`lobelight.fit.cluster`): the chunks of the bake run on the
    cluster's workers, the result streaming back into this process's state and checkpoint
    (:func:`fit_mesh`); the model is the one-process bake's, bit for bit.

    ``threads``: without a ``client``, how many chunks run at once in this process (default
    torch's thread count on the CPU, 1 on a GPU; :func:`fit_mesh`); each chunk runs on one
    torch thread, so the model does not depend on it.

    ``refine``: rounds of splitting the mesh's edges whose ends see the environment
    differently (:func:`lobelight.fit.refine_scene`; 0: the scene's mesh as it is); the model
    holds the refined mesh, and the provenance what was split.

    ``progress``: True reports each stage on stderr (bars on a terminal, plain lines
    elsewhere: :mod:`lobelight.progress`), None or False is silent, a callable
    ``progress(stage, done, total)`` is called after each chunk.

    Returns
    -------
    lobelight.model.Model, with provenance holding the settings, the mean relative data error,
    flip counts and timings
    """
    asked = n_gaussians
    scene, refinement = refine_scene(scene, rounds=refine)
    if n_gaussians == "auto":
        n_gaussians, reason = choose_gaussians(scene.materials)
    elif isinstance(n_gaussians, bool) or n_gaussians not in (1, 2, 3):
        raise ValueError(f"n_gaussians must be 1, 2, 3 or 'auto', got {n_gaussians!r}")
    else:
        reason = f"asked for {n_gaussians}"
    t0 = time.perf_counter()
    with contextlib.ExitStack() as stack:
        if isinstance(client, str):
            client = stack.enter_context(cluster(client))
        mf = fit_mesh(
            scene,
            n=n_gaussians,
            views=views,
            weights=weights,
            batch=batch,
            indirect_paths=indirect_paths,
            bounces=bounces,
            relax=relax,
            device=device,
            progress=resolve(progress),
            seed=seed,
            checkpoint=checkpoint,
            checkpoint_every=checkpoint_every,
            shadows=shadows,
            memory_gb=memory_gb,
            client=client,
            threads=threads,
        )
    seconds = {**mf.seconds, "total": time.perf_counter() - t0}
    live = mf.gaussians.w.amax((-1, -2, -3)) > 0  # vertices with any glossy weight
    err = mf.data_error[live] if bool(live.any()) else mf.data_error
    w = weights or Weights()
    prov = {
        "scene": scene.name,
        "camera": scene.camera.to_dict(),
        "environment": scene.environment,
        "n_gaussians": n_gaussians,
        "n_gaussians_choice": {"asked": asked, "reason": reason},
        "weights": {"alpha": w.alpha, "beta": w.beta, "gamma": w.gamma, "delta": w.delta},
        "indirect_paths": int(indirect_paths),
        "bounces": int(bounces),
        "relax": relax,
        "shadows": shadows,
        "seed": seed,
        # vertices whose rays start at an exposed point of their faces (cached: no new rays)
        "exposed_vertices": int(vertex_origins(scene.mesh.to(mf.gaussians.w.device)).n_exposed),
        "refinement": refinement,
        **({} if client is None else {"cluster": _order(n_gaussians)}),
        "relative_l2_error_mean": float(err.clamp_min(0).sqrt().mean()) if err.numel() else 0.0,
        "flips_before": mf.flips_before,
        "flips_after": mf.flips_after,
        "separated_flips_before": mf.separated_flips_before,
        "separated_flips_after": mf.separated_flips_after,
        "seconds": seconds,
        "memory": {
            "budget_gb": float(memory_gb),
            "batch": mf.batch,
            "chunks_at_once": mf.chunks_at_once,
            "peak_gb": {k: round(b / 2**30, 3) for k, b in mf.peak_bytes.items()},
        },
        "device": str(mf.gaussians.w.device),
        "torch": torch.__version__,
        "python": platform.python_version(),
        "lobelight": __version__,
    }
    mesh = scene.mesh.to(mf.gaussians.w.device)
    mats = scene.materials.to(mesh.vertices.device)
    diffuse, bounce, albedo = mf.diffuse, mf.bounce, scene.albedo
    if albedo is not None:  # the texture is read per pixel: its average comes out
        albedo = albedo.to(mesh.vertices.device)
        diffuse = per_unit_albedo(diffuse, mats.diffuse)
        bounce = None if bounce is None else per_unit_albedo(bounce, mats.diffuse)
    return Model(
        mesh,
        mf.views,
        mf.gaussians,
        diffuse,
        mats,
        prov,
        bounce=bounce,
        indirect_gaussians=mf.indirect_gaussians,
        albedo=albedo,
    )


def _order(n: int) -> dict[str, str]:
    """Where a bake on a cluster ran its chunks (:mod:`lobelight.fit._cluster`), and in what
    order (:mod:`lobelight.fit._runner`: the same as in one process)."""
    if n == 1:
        return {"chunks": "on Dask workers, in any order: independent, as in one process"}
    return {
        "chunks": "on Dask workers, a wavefront's at once, reading earlier wavefronts only, "
        "as in one process"
    }
