"""Kernel fusion of cosine-lobe shading (``shade_points(fused=True)``, ``torch.compile``).

Fusion must change speed only: the compiled kernels run the same arithmetic as the eager code,
so the two agree to float32 rounding (the compiler may reorder and contract operations). The
references here are the eager results of the same call; the eager path itself is tested against
closed forms and Monte Carlo in ``test_cosine_lighting.py``. One compile of every kernel costs
about a minute on the 2-core CI machine (100 s measured with a cold inductor cache), so all fused
checks share one module fixture, and the tests that use it run in the slow stage (``-m slow``).
"""

from __future__ import annotations

import pytest
import torch

from lobelight import brdf as B
from lobelight import cosine as C
from lobelight.cosine import _fused


def _scene(n: int, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    xz = (torch.rand(n, 2, generator=g) * 2 - 1) * 1.6
    x = torch.stack([xz[:, 0], torch.zeros(n), xz[:, 1]], -1)
    up = torch.tensor([0.0, 1.0, 0.0]).expand(n, 3).contiguous()
    wo = torch.nn.functional.normalize(torch.tensor([0.4, 3.0, 2.5]) - x, dim=-1)
    centres = torch.rand(12, 3, generator=g) * torch.tensor([1.2, 0.3, 1.2])
    centres = centres + torch.tensor([-0.6, 0.8, -0.6])
    spheres = torch.cat([centres, 0.18 + 0.1 * torch.rand(12, 1, generator=g)], -1)
    u = (x[:, 0] + 1.6) / 3.2
    model = B.Sum(
        B.Lambert(torch.stack([0.2 + 0.6 * u, 0.5 + 0 * u, 0.6 - 0.4 * u], -1)),
        B.Phong(0.3, 5.0 + 200.0 * u),
    )
    light = C.SphereLight((0.3, 3.0, 0.2), 0.4, (5.0, 5.0, 5.0))
    return x, up, wo, model, light, spheres


@pytest.fixture(scope="module")
def runs():
    """Eager and fused shading of two point sets (two sizes: the kernels take dynamic shapes)
    with occluders in both visibility modes, and without occluders."""
    tables = C.get_tables()
    out = []
    for n, mode, occluded in ((300, "aggressive", True), (700, "conservative", True), (500, "", 0)):
        x, n_, wo, model, light, spheres = _scene(n, seed=n)
        kw = dict(spheres=spheres if occluded else None, tables=tables, threshold=1e-3)
        if mode:
            kw["mode"] = mode
        eager = C.shade_points(x, n_, wo, model, light, fused=False, **kw)
        fused = C.shade_points(x, n_, wo, model, light, fused=True, **kw)
        again = C.shade_points(x, n_, wo, model, light, fused=True, **kw)  # cached kernels
        out.append((eager, fused, again))
    return out


@pytest.mark.slow
def test_fused_shading_equals_eager(runs):
    """Radiance to float32 rounding of the scene's scale (1e-5 of the maximum, absolute, and a
    1e-4 relative allowance); products and leaves exactly (integer decisions on the same
    numbers can only differ where a test sits on its threshold to within rounding: a handful
    of cells of thousands at most)."""
    assert not _fused._broken, _fused._broken  # the compiler worked here (else eager ran)
    for eager, fused, again in runs:
        scale = float(eager.radiance.max())
        assert scale > 0.1
        torch.testing.assert_close(fused.radiance, eager.radiance, rtol=1e-4, atol=1e-5 * scale)
        torch.testing.assert_close(again.radiance, fused.radiance, rtol=0, atol=0)
        assert int((fused.products != eager.products).sum()) <= 3
        assert int((fused.leaves != eager.leaves).sum()) <= 3


@pytest.mark.slow
def test_occluded_runs_are_not_vacuous(runs):
    for eager, _, _ in runs[:2]:
        assert int((eager.leaves > 0).sum()) > 30


def test_fusion_is_off_by_default_and_scoped():
    assert not _fused.fusion_enabled()
    with _fused.fusion(True):
        assert _fused.fusion_enabled() or _fused._broken
        with _fused.fusion(False):
            assert not _fused.fusion_enabled()
    assert not _fused.fusion_enabled()


def test_compiler_failure_falls_back_to_eager(monkeypatch):
    """A compiler that cannot build (no C++ toolchain, say) gives one warning and the eager
    result, never an exception; an error of the function itself still propagates."""

    class FakeInductorError(RuntimeError):
        pass

    FakeInductorError.__module__ = "torch._inductor.exc"

    def broken_compile(fn, **_kw):
        def run(*a, **k):
            if fn.__name__ == "double":
                raise FakeInductorError("no compiler")
            return fn(*a, **k)

        return run

    monkeypatch.setattr(torch, "compile", broken_compile)
    monkeypatch.setattr(_fused, "_broken", [])

    @_fused.kernel
    def double(x):
        return 2 * x

    @_fused.kernel
    def bad(x):
        raise ValueError("bad input")

    with _fused.fusion(True):
        with pytest.raises(ValueError, match="bad input"):
            bad(torch.ones(3))
        assert _fused.fusion_enabled()  # not a compiler failure
        with pytest.warns(RuntimeWarning, match="fusion .* failed"):
            assert torch.equal(double(torch.ones(3)), torch.full((3,), 2.0))
        assert not _fused.fusion_enabled()  # one failure turns fusion off for the process
