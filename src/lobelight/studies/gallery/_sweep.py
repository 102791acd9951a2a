"""Equal quality: the samples per pixel and seconds Mitsuba 3 needs to match our score.

:func:`mitsuba_sweep` renders a scene with Mitsuba as its reference was rendered (the same
variant, integrator, depth and size; its own seeds, none of the reference's passes') at 1, 2,
4, ... samples per pixel up to ``max_spp``, stopping at the first render that scores at least
ours; each render is timed alone (the scene loaded and its kernels compiled by an untimed
1-spp render before) and scored against the reference with our displayed PSNR over our
mask (:func:`lobelight.studies.score.psnr_display`). Renders of the sweep and the reference
share no noise, so both images' errors hold the reference's noise alike.

:func:`equal_quality` reads the crossing off the sweep: the two renders either side of our
score, interpolated linearly in ``log2 spp`` (the PSNR of a noise-limited render grows by
about 3 dB per doubling, a line in ``log2 spp``), their seconds interpolated at the same point
in ``log seconds``; ``speedup`` is those seconds over our frame's. Past the sweep's last render
it extrapolates with the law of Monte Carlo error against a noisy reference, ``MSE(N) = a / N
+ b``, ``b`` the reference's own noise (flagged ``"~"``).
"""

from __future__ import annotations

import math
import tempfile
import time
from typing import Any

import numpy as np
import torch

from ...errors import InputError
from ...reference.mitsuba import scene_dict
from ...scene import Scene
from ..score import psnr_display
from . import _references
from ._settings import SWEEP_MAX_SPP

__all__ = ["equal_quality", "mitsuba_sweep", "spp_levels"]


def spp_levels(max_spp: int) -> list[int]:
    """``[1, 2, 4, ...]`` up to ``max_spp`` (included, also when it is no power of two)."""
    if isinstance(max_spp, bool) or not isinstance(max_spp, int) or max_spp < 1:
        raise InputError("--sweep-max-spp", f"must be an integer >= 1, got {max_spp!r}")
    out = [1]
    while out[-1] * 2 <= max_spp:
        out.append(out[-1] * 2)
    return out if out[-1] == max_spp else [*out, max_spp]


def equal_quality(
    target: float | None,
    sweep: list[dict[str, float]],
    frame_seconds: float,
    *,
    noise_mse: float | None = None,
    cap_spp: float | None = None,
) -> dict[str, Any]:
    """Where a sweep (``[{"spp", "seconds", "psnr_display"}, ...]`` by rising ``spp``) first
    reaches ``target`` dB.

    Returns ``spp`` and ``seconds`` at the crossing, ``speedup`` (``seconds /
    frame_seconds``), and ``bound``:

    - ``"="``: a crossing between two renders, interpolated;
    - ``"<="``: the first render already reaches the target (its figures are upper bounds);
    - ``"~"``: no render reaches it, and ``noise_mse`` (the displayed MSE the reference's own
      noise adds to any image's, ``10^(-reference_noise_psnr_display / 10)``) is given:
      extrapolated past the last render with the Monte Carlo error's law ``MSE(N) = a / N +
      noise_mse`` (``a`` from the last render) and its seconds in proportion to ``N``, up to
      ``cap_spp`` (the reference's own samples per pixel: past them a render would be better
      than the reference it is scored against);
    - ``">="``: no render reaches it and there is no extrapolation (no ``noise_mse``, the
      target lies at or under the reference's noise floor, or past ``cap_spp``): the last
      render's figures, or ``cap_spp``'s by the law, lower bounds.

    All None for no target (an identical image) or an empty sweep.
    """
    none = {"spp": None, "seconds": None, "speedup": None, "bound": None}
    if target is None or not math.isfinite(target) or not sweep:
        return none
    psnr = [r["psnr_display"] for r in sweep]
    hit = next((i for i, p in enumerate(psnr) if p >= target), None)
    if hit is None:
        spp, seconds, bound = _extrapolate(target, sweep[-1], noise_mse, cap_spp)
    elif hit == 0:
        spp, seconds, bound = sweep[0]["spp"], sweep[0]["seconds"], "<="
    else:
        a, b = sweep[hit - 1], sweep[hit]
        t = (target - a["psnr_display"]) / (b["psnr_display"] - a["psnr_display"])  # in [0, 1]
        spp = 2 ** (math.log2(a["spp"]) + t * (math.log2(b["spp"]) - math.log2(a["spp"])))
        seconds = math.exp(
            math.log(a["seconds"]) + t * (math.log(b["seconds"]) - math.log(a["seconds"]))
        )
        bound = "="
    speedup = seconds / frame_seconds if frame_seconds > 0 else None
    return {"spp": spp, "seconds": seconds, "speedup": speedup, "bound": bound}


def _extrapolate(
    target: float, last: dict[str, float], noise_mse: float | None, cap_spp: float | None
) -> tuple[float, float, str]:
    """``(spp, seconds, bound)`` past the sweep's ``last`` render (:func:`equal_quality`)."""
    if noise_mse is None or not math.isfinite(noise_mse) or noise_mse < 0:
        return last["spp"], last["seconds"], ">="
    cap = math.inf if cap_spp is None else max(float(cap_spp), float(last["spp"]))
    want = 10 ** (-target / 10)
    a = last["spp"] * (10 ** (-last["psnr_display"] / 10) - noise_mse)
    spp = a / (want - noise_mse) if a > 0 and want > noise_mse else math.inf
    if math.isinf(spp) or spp > cap:
        if math.isinf(cap):
            return last["spp"], last["seconds"], ">="
        return cap, last["seconds"] * cap / last["spp"], ">="
    return spp, last["seconds"] * spp / last["spp"], "~"


def _mitsuba(variant: str | None):
    """``(mi, variant, note)``: the reference's ``variant`` where it runs, else the first of
    the gallery's variants that does."""
    if variant:
        try:
            return _references._mitsuba(variant)
        except InputError as exc:
            mi, v, note = _references._mitsuba(None)
            return mi, v, f"the reference's {variant} does not run here ({exc.problem}); {note}"
    return _references._mitsuba(None)


def mitsuba_sweep(
    scene: Scene,
    reference,
    mask: torch.Tensor,
    exposure: float,
    target: float | None,
    *,
    max_spp: int = SWEEP_MAX_SPP,
    progress=None,
) -> dict[str, Any]:
    """Render ``scene`` with Mitsuba at rising samples per pixel until a render's
    :func:`~lobelight.studies.score.psnr_display` against ``reference`` (a loaded
    :class:`~lobelight.studies.gallery.Reference`) over ``mask`` ``(H, W)`` at ``exposure``
    reaches ``target`` (None: every level), or ``max_spp``.

    Returns ``variant`` (the reference's, else the first that runs, with ``note`` saying
    why), ``seed`` (the first level's; each level adds one), ``sweep`` (``[{"spp", "seconds",
    "psnr_display"}]``) and ``warmup_seconds`` (the untimed first render: loading, compiling).
    """
    settings = reference.entry.get("settings") or {}
    h, w = reference.mask.shape
    mi, variant, note = _mitsuba(reference.entry.get("variant"))
    n_pass = max(int(settings.get("spp", 1)) // max(int(settings.get("pass_spp", 1)), 1), 1)
    # the reference's passes used seeds seed * n .. seed * n + n - 1: start past them
    seed0 = (int(settings.get("seed", 0)) + 1) * n_pass
    levels = spp_levels(max_spp)
    rows: list[dict[str, float]] = []
    with tempfile.TemporaryDirectory(prefix="lobelight-sweep-") as work:
        d = scene_dict(
            scene,
            scene.environment,
            scene.camera,
            width=w,
            height=h,
            spp=1,
            max_depth=int(settings.get("max_depth", 8)),
            seed=seed0,
            workdir=work,
            variant=variant,
        )
        t = time.perf_counter()
        s = mi.load_dict(d)
        np.asarray(mi.render(s, spp=1, seed=seed0 + len(levels)))  # compile the kernels
        warmup = time.perf_counter() - t
        for i, spp in enumerate(levels):
            t = time.perf_counter()
            img = np.asarray(mi.render(s, spp=spp, seed=seed0 + i), dtype=np.float32)  # (H, W, 3)
            seconds = time.perf_counter() - t
            p = psnr_display(torch.from_numpy(img), reference.image, mask, exposure)
            rows.append({"spp": spp, "seconds": seconds, "psnr_display": p})
            if progress is not None:
                progress("sweep", i + 1, len(levels))
            if target is not None and p >= target:
                break
        del s
    return {
        "variant": variant,
        "note": note,
        "seed": seed0,
        "sweep": rows,
        "warmup_seconds": warmup,
    }
