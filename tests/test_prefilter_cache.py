"""The disk cache of prefiltered chains (lobelight.envmap._chain_cache via prefilter(cache=...)).

Small maps (16^2 faces) keep every test fast; what is tested does not depend on the size:
the key, the round trip, recovery from damaged entries and the file handling.
"""

from __future__ import annotations

import multiprocessing
import os
import shutil

import numpy as np
import pytest
import torch

from conftest import DEVICES
from lobelight import _cache, _io
from lobelight.cosine import _tables
from lobelight.envmap import EnvMap, _chain_cache, _convolve, _prefilter, prefilter
from lobelight.errors import InputError

RES = 16


@pytest.fixture
def cache_root(tmp_path, monkeypatch):
    """``$LOBELIGHT_CACHE`` in a temporary folder; HOME and XDG_CACHE_HOME moved aside too, so a
    write anywhere else would land in ``tmp_path / "elsewhere"``, which must stay empty."""
    root = tmp_path / "cache"
    monkeypatch.setenv("LOBELIGHT_CACHE", str(root))
    monkeypatch.setenv("HOME", str(tmp_path / "elsewhere" / "home"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "elsewhere" / "xdg"))
    return root


def _env(res: int = RES, seed: int = 0, name: str = "test-map") -> EnvMap:
    g = torch.Generator().manual_seed(seed)
    return EnvMap(torch.rand(6, res, res, 3, generator=g) + 0.05, layout="cubemap", name=name)


def _entries(root) -> list:
    folder = root / "prefilter"
    return sorted(folder.iterdir()) if folder.exists() else []


def _key(data: torch.Tensor, kind: str = "envmap:cubemap", base_res=RES, phases=4) -> str:
    return _chain_cache.chain_key(data, _prefilter._description(kind, base_res, phases))


def _same_chain(a, b) -> None:
    # exact: the entry holds the float32 levels and float64 sharpness as computed
    assert len(a.levels) == len(b.levels)
    for x, y in zip(a.levels, b.levels, strict=True):
        assert x.dtype == y.dtype == torch.float32 and torch.equal(x.cpu(), y.cpu())
    assert a.lambdas.dtype == b.lambdas.dtype == torch.float64
    assert torch.equal(a.lambdas.cpu(), b.lambdas.cpu())


def _no_build(monkeypatch) -> None:
    def fail(*args, **kwargs):
        raise AssertionError("the chain was computed instead of read from the cache")

    monkeypatch.setattr(_prefilter, "_build", fail)


# -- the key ---------------------------------------------------------------------------------


def test_key_changes_with_one_texel_and_each_setting(monkeypatch):
    data = _env().data
    key = _key(data)
    assert _key(data.clone()) == key  # the values, not the tensor object
    assert len(key) == 64 and int(key, 16) >= 0
    one = data.clone()
    one[3, 5, 7, 1] = torch.nextafter(one[3, 5, 7, 1], torch.tensor(2.0))  # one ulp, one texel
    assert _key(one) != key
    assert _key(data, kind="cube") != key  # a raw cube map, or another layout
    assert _key(data, kind="envmap:latlong") != key
    assert _key(data.double()) != key  # the same values in another dtype
    assert _key(data.reshape(6, RES, RES // 2, 6)) != key  # the same bytes in another shape
    assert _key(data, base_res=2 * RES) != key
    assert _key(data, phases=3) != key
    monkeypatch.setattr(_prefilter, "CHAIN_VERSION", _prefilter.CHAIN_VERSION + 1)
    assert _key(data) != key
    monkeypatch.undo()
    monkeypatch.setattr(_convolve, "WINDOW_SIGMAS", _convolve.WINDOW_SIGMAS + 0.1)
    assert _key(data) != key
    monkeypatch.undo()
    monkeypatch.setattr(_chain_cache, "FORMAT_VERSION", _chain_cache.FORMAT_VERSION + 1)
    assert _key(data) != key
    monkeypatch.undo()
    assert _key(data) == key


def test_name_blend_and_device_share_one_entry(cache_root):
    # the levels depend on none of them: one entry, and each chain keeps its own blend and name
    env = _env()
    a = prefilter(env, base_res=RES)
    b = prefilter(_env(name="other"), base_res=RES, blend="moment", device="cpu")
    assert len(_entries(cache_root)) == 1
    assert (a.blend, a.name) == ("l2", "test-map") and (b.blend, b.name) == ("moment", "other")
    _same_chain(a, b)
    prefilter(env, base_res=RES, phases=3)
    prefilter(_env(seed=1), base_res=RES)
    assert len(_entries(cache_root)) == 3


# -- the round trip --------------------------------------------------------------------------


@pytest.mark.parametrize("device", DEVICES)
def test_cached_chain_equals_fresh(cache_root, monkeypatch, device):
    env = _env()
    fresh = prefilter(env, base_res=RES, device=device, cache=False)
    assert _entries(cache_root) == []  # cache=False writes nothing
    first = prefilter(env, base_res=RES, device=device)
    (entry,) = _entries(cache_root)
    assert entry.name.endswith(".npz") and entry.parent == cache_root / "prefilter"
    _no_build(monkeypatch)
    again = prefilter(env, base_res=RES, device=device)
    assert again.device.type == torch.device(device).type
    assert again.phases == fresh.phases and again.blend == fresh.blend
    _same_chain(first, fresh)
    _same_chain(again, fresh)
    mu = torch.nn.functional.normalize(torch.randn(50, 3), dim=-1).to(device)
    lam = torch.full((50,), 30.0, device=device)
    assert torch.equal(again.integrate(mu, lam), fresh.integrate(mu, lam))


def test_entry_is_plain_arrays(cache_root):
    prefilter(_env(), base_res=RES)
    (entry,) = _entries(cache_root)
    with np.load(entry, allow_pickle=False) as z:  # no pickles needed to read it
        assert z["header"].dtype.kind == "U" and z["lambdas"].dtype == np.float64
        assert z["level_00"].dtype == np.float32 and z["level_00"].shape == (6, RES, RES, 3)


def test_raw_cube_maps_are_cached_only_when_asked(cache_root, tmp_path, monkeypatch):
    cube = torch.rand(6, RES, RES, 3) + 0.05
    prefilter(cube, base_res=RES)
    assert _entries(cache_root) == []
    fresh = prefilter(cube, base_res=RES, cache=True)
    assert len(_entries(cache_root)) == 1
    folder = tmp_path / "mine"
    prefilter(cube, base_res=RES, cache=folder)
    assert len(list(folder.iterdir())) == 1
    _no_build(monkeypatch)
    _same_chain(prefilter(cube, base_res=RES, cache=True), fresh)
    _same_chain(prefilter(cube.numpy(), base_res=RES, cache=folder), fresh)
    with pytest.raises(InputError, match="cache"):
        prefilter(cube, base_res=RES, cache=3)


# -- damaged entries and file handling -------------------------------------------------------


def _garbage(path) -> None:
    path.write_bytes(np.random.default_rng(0).bytes(4096))


def _truncate(path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _flip_a_byte(path) -> None:  # inside a level: the zip CRC catches it
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x10
    path.write_bytes(bytes(data))


def _empty(path) -> None:
    path.write_bytes(b"")


def _bare_npy(path) -> None:
    with open(path, "wb") as f:
        np.save(f, np.zeros(3))


def _other_key(path) -> None:  # a whole, readable entry, but of another chain
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["header"] = np.array('{"key": "0"}')
    with open(path, "wb") as f:
        np.savez(f, **arrays)


def _nan_level(path) -> None:
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["level_03"][0, 0, 0, 0] = np.nan
    with open(path, "wb") as f:
        np.savez(f, **arrays)


def _missing_level(path) -> None:
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files if k != "level_05"}
    with open(path, "wb") as f:
        np.savez(f, **arrays)


@pytest.mark.parametrize(
    "damage", [_garbage, _truncate, _flip_a_byte, _empty, _bare_npy, _other_key, _nan_level,
               _missing_level],
)  # fmt: skip
def test_damaged_entry_is_recomputed_and_rewritten(cache_root, monkeypatch, damage):
    env = _env()
    fresh = prefilter(env, base_res=RES)
    (entry,) = _entries(cache_root)
    damage(entry)
    _same_chain(prefilter(env, base_res=RES), fresh)  # no error, the right chain
    (entry,) = _entries(cache_root)
    _no_build(monkeypatch)  # and the entry is whole again
    _same_chain(prefilter(env, base_res=RES), fresh)


def test_deleting_the_folder_is_harmless(cache_root):
    env = _env()
    fresh = prefilter(env, base_res=RES)
    shutil.rmtree(cache_root)
    _same_chain(prefilter(env, base_res=RES), fresh)
    assert len(_entries(cache_root)) == 1


def test_an_unwritable_cache_only_costs_time(cache_root):
    cache_root.parent.mkdir(parents=True, exist_ok=True)
    cache_root.write_text("a file where the folder should be")
    env = _env()
    _same_chain(prefilter(env, base_res=RES), prefilter(env, base_res=RES, cache=False))


def test_writes_only_under_lobelight_cache(cache_root, tmp_path):
    assert _cache.cache_dir() == cache_root
    assert _tables.cache_dir() == cache_root  # the cosine tables use the same folder
    assert _chain_cache.default_folder() == cache_root / "prefilter"
    prefilter(_env(), base_res=RES)
    written = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*") if p.is_file())
    assert len(written) == 1 and written[0].parts[:2] == ("cache", "prefilter")
    assert not (tmp_path / "elsewhere").exists()


def test_default_folder_is_the_platform_cache(monkeypatch, tmp_path):
    monkeypatch.delenv("LOBELIGHT_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    got = _cache.cache_dir()
    assert got.name == "lobelight"
    if got.is_relative_to(tmp_path):  # Linux (XDG); other platforms have their own folder
        assert got == tmp_path / "xdg" / "lobelight"


def _write_many(path, key, levels, lambdas, barrier, times) -> None:
    barrier.wait()  # both processes start writing at once
    for _ in range(times):
        _chain_cache.write_chain(path, key, {"test": True}, lambdas, levels)


def test_concurrent_writers_leave_one_whole_entry(tmp_path):
    pf = prefilter(_env(), base_res=RES, cache=False)
    path = tmp_path / "entry.npz"
    # fork where there is one: the writers only copy arrays to a file (no torch thread pool in
    # the child) and start at once, where spawn would first import torch in each
    methods = multiprocessing.get_all_start_methods()
    ctx = multiprocessing.get_context("fork" if "fork" in methods else "spawn")
    barrier = ctx.Barrier(2)
    args = (path, "k", pf.levels, pf.lambdas, barrier, 20)
    procs = [ctx.Process(target=_write_many, args=args) for _ in range(2)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(120)
    assert [p.exitcode for p in procs] == [0, 0]
    assert sorted(tmp_path.iterdir()) == [path]  # no temporary files left
    got = _chain_cache.read_chain(path, "k", [lv.shape[1] for lv in pf.levels])
    assert got is not None
    assert np.array_equal(got[0], pf.lambdas.numpy())
    assert all(np.array_equal(a, b.numpy()) for a, b in zip(got[1], pf.levels, strict=True))


def test_atomic_writer_leaves_nothing_on_error(tmp_path):
    target = tmp_path / "x.bin"
    target.write_bytes(b"old")
    with pytest.raises(RuntimeError), _io.atomic_writer(target) as f:
        f.write(b"half of the new")
        raise RuntimeError("interrupted")
    assert target.read_bytes() == b"old"
    assert sorted(tmp_path.iterdir()) == [target]


def test_the_folder_stays_under_its_cap_least_recently_used_first(cache_root, monkeypatch):
    """With room for two entries, a third evicts the one used longest ago (a read counts as a
    use), never the one just written."""
    maps = [_env(seed=s) for s in range(3)]
    prefilter(maps[0], base_res=RES)
    size = _entries(cache_root)[0].stat().st_size
    monkeypatch.setenv("LOBELIGHT_CACHE_MAX_MB", str(2.5 * size / 2**20))
    prefilter(maps[1], base_res=RES)
    first, second = sorted(_entries(cache_root), key=lambda p: p.stat().st_mtime)
    os_times = {first: 1_000_000.0, second: 2_000_000.0}  # map 0 older than map 1
    for p, t in os_times.items():
        os.utime(p, (t, t))
    prefilter(maps[0], base_res=RES)  # a read: map 0 is now the more recently used
    prefilter(maps[2], base_res=RES)  # a write past the cap: map 1 goes
    left = {p.name for p in _entries(cache_root)}
    assert len(left) == 2 and second.name not in left and first.name in left
