"""ChainBuilder: the prefiltered chain rebuilt from one map after another.

Its levels must be the ones ``prefilter`` makes (the same code on the same device: equal to
the bit). Its CUDA path captures the build in a CUDA graph, which cannot run here; what makes a
capture possible can: a build with its plans in memory reads no value back to the host, makes
no tensor from host data and builds no new plan. That is checked by running the build on the
``meta`` device, which has shapes and no values (any read of a value fails there) and which
takes the non-CPU forms of every operator, the ones CUDA takes.
"""

from __future__ import annotations

import pytest
import torch
from torch.utils._python_dispatch import TorchDispatchMode

from lobelight.envmap import ChainBuilder, builtin, prefilter
from lobelight.envmap import _convolve as C
from lobelight.envmap import _prefilter as P
from lobelight.errors import InputError
from lobelight.geometry import cubemap


def _map(seed: int, res: int = 64) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    cube = builtin().to_cubemap(res) * (1 + torch.rand(6, res, res, 3, generator=g))
    cube[seed % 6, 5, 7] = 1e4  # a bright texel, different in each map
    return cube


def _same_chain(got, want) -> None:
    assert len(got.levels) == len(want.levels)
    for a, b, pa, pb in zip(got.levels, want.levels, got._padded, want._padded, strict=True):
        assert torch.equal(a, b)
        assert torch.equal(pa, pb)
    assert torch.equal(got.lambdas, want.lambdas)


def test_each_call_gives_prefilters_chain_of_that_map():
    builder = ChainBuilder(base_res=32)
    first = builder(_map(0))
    _same_chain(first, prefilter(_map(0), base_res=32, cache=False))
    # a second map: the same object, now holding the second map's chain, nothing of the first
    second = builder(_map(1))
    assert second is first
    _same_chain(second, prefilter(_map(1), base_res=32, cache=False))


def test_envmaps_and_finer_cubes_are_taken_as_prefilter_takes_them():
    env = builtin()
    builder = ChainBuilder(base_res=16, phases=2, blend="moment")
    got = builder(env)
    _same_chain(got, prefilter(env, base_res=16, phases=2, cache=False))
    assert got.name == env.name and got.blend == "moment" and got.phases == 2
    finer = _map(2, res=64)
    _same_chain(builder(finer.numpy()), prefilter(finer, base_res=16, phases=2, cache=False))
    # lookups read the rebuilt levels (the padded copies are rebuilt with them)
    dirs = torch.nn.functional.normalize(torch.randn(50, 3, generator=torch.Generator()), dim=-1)
    ref = prefilter(finer, base_res=16, phases=2, blend="moment", cache=False)
    torch.testing.assert_close(got.lookup(dirs, 30.0), ref.lookup(dirs, 30.0), rtol=0, atol=0)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"base_res": 48}, "base_res"),
        ({"phases": 0}, "phases"),
        ({"blend": "max"}, "blend"),
        ({"graph": True}, "graph"),  # no CUDA device here
        ({"device": "not-a-device"}, "device"),
    ],
)
def test_bad_settings_are_refused_by_name(kwargs, name):
    with pytest.raises(InputError, match=name):
        ChainBuilder(**kwargs)


def test_bad_maps_are_refused_and_the_chain_kept():
    builder = ChainBuilder(base_res=16)
    good = builder(_map(3, res=16))
    kept = [lv.clone() for lv in good.levels]
    bad = _map(4, res=16)
    bad[1, 2, 3, 0] = float("nan")
    with pytest.raises(InputError, match="NaN"):
        builder(bad)
    with pytest.raises(InputError, match=r"\(6, 16, 16, 3\)"):
        builder(torch.ones(6, 8, 8, 3))
    with pytest.raises(InputError, match=r"\(6, 16, 16, 3\)"):
        builder(torch.ones(6, 16, 16, 4))
    assert all(torch.equal(a, b) for a, b in zip(good.levels, kept, strict=True))
    # unchecked, a NaN map gives NaN levels rather than an error
    unchecked = ChainBuilder(base_res=16, check_finite=False)(bad)
    assert bool(unchecked.levels[0].isnan().any())


class _Watch(TorchDispatchMode):
    """Records every operator that reads a tensor's value on the host or takes a host tensor."""

    READS = ("_local_scalar_dense", "item", "nonzero", "is_nonzero", "equal")

    def __init__(self) -> None:
        super().__init__()
        self.kernels = 0
        self.faults: list[str] = []

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        name = func.__name__.split(".")[0]
        if name in self.READS:
            self.faults.append(f"{func} reads a value")
        for a in torch.utils._pytree.tree_leaves((args, kwargs)):
            if isinstance(a, torch.Tensor) and a.device.type != "meta":
                self.faults.append(f"{func} takes a {a.device} tensor {tuple(a.shape)}")
        return func(*args, **(kwargs or {}))


_PLANS = (
    C._halo_plan,
    C._unfold_plan,
    C._basis,
    C._anisotropic_plan,
    C._windowed_plan,
    C._sh_plan,
    P._downsample_weights,
    P._schedule,
    cubemap.seamless_pad_plan,
)


@pytest.mark.parametrize("base_res", [512, 64])
def test_a_warm_build_can_be_captured_in_a_cuda_graph(base_res):
    cube = torch.empty(6, base_res, base_res, 3, device="meta")
    P._build(cube, base_res, 4)  # makes the plans, as the builder's warm-up does
    misses = [fn.cache_info().misses for fn in _PLANS]
    watch = _Watch()
    with watch:
        levels, padded = P._build(cube, base_res, 4)
    assert watch.faults == []
    # every plan came from memory: building one would copy host data to the device
    assert [fn.cache_info().misses for fn in _PLANS] == misses
    assert [lv.shape[1] for lv in levels] == P._resolutions(base_res, 4)
    assert [p.shape[1] for p in padded] == [r + 2 for r in P._resolutions(base_res, 4)]
    assert all(lv.device.type == "meta" for lv in levels + padded)


def _clear_plans() -> None:
    for fn in _PLANS:
        fn.cache_clear()


def test_the_gpu_forms_of_every_operator_give_the_same_chain(monkeypatch):
    # A CUDA build takes other forms of four operators (kept gather indices, one padded window
    # group, the gathered halo, levels stacked per resolution); here they run on the CPU against
    # the CPU's forms: the same sums in another order, so float32 rounding apart. Each level
    # sums hundreds of window taps through several passes, and the CPU's vector code changes
    # the order again (1.1e-6 of a level's peak on a Xeon with AVX-512, under 1e-6 on an
    # EPYC): 1e-5 (about 80 float32 epsilons), where a wrong index or weight errs by order 1. The
    # stacked sharpening and padding are equal to the bit
    # (test_stacked_levels_are_sharpened_and_padded_as_single_ones).
    cube = _map(6, res=64)
    cpu = prefilter(cube, base_res=64, cache=False)
    _clear_plans()
    monkeypatch.setattr(C, "_keep_indices", lambda device: True)
    monkeypatch.setattr(C, "_one_window_group", lambda device: True)
    monkeypatch.setattr(C, "_sparse_halo", lambda device: False)
    monkeypatch.setattr(P, "_stack_levels", lambda device: True)
    try:
        gpu = prefilter(cube, base_res=64, cache=False)
    finally:
        _clear_plans()
    for a, b in zip(gpu.levels + gpu._padded, cpu.levels + cpu._padded, strict=True):
        assert a.shape == b.shape and a.is_contiguous()
        assert float((a - b).abs().max()) <= 1e-5 * float(b.abs().max())


def test_stacked_levels_are_sharpened_and_padded_as_single_ones(monkeypatch):
    levels = [_map(s, res=r) for s, r in ((7, 16), (8, 16), (9, 16), (10, 8), (11, 8))]
    levels.append(torch.rand(6, 2, 2, 3, generator=torch.Generator().manual_seed(12)))
    single = P._per_resolution(levels, sharpen=True)
    monkeypatch.setattr(P, "_stack_levels", lambda device: True)
    stacked = P._per_resolution(levels, sharpen=True)
    for a, b in zip(stacked[0] + stacked[1], single[0] + single[1], strict=True):
        assert torch.equal(a, b)
    # levels below SHARPEN_MIN_RES are padded only
    assert torch.equal(stacked[0][-1], levels[-1])
