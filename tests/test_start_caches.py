"""What a render's start reads back from disk instead of computing: the geodesic candidate table
and resampled cube maps. A cached entry gives the very arrays a fresh computation gives; a
damaged or foreign entry is computed again and rewritten, never an error. And the start's
benchmark accounts for its whole wall time."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest
import scipy.special
import torch

from lobelight.bench.start import PHASES, phases
from lobelight.envmap import EnvMap
from lobelight.errors import InputError
from lobelight.geometry import sphere
from lobelight.lobes import sh
from lobelight.render import gl_available


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """A private cache folder, and the candidate table's memory cache emptied around the test."""
    monkeypatch.setenv("LOBELIGHT_CACHE", str(tmp_path))
    sphere.triangle_candidates.cache_clear()
    yield tmp_path
    sphere.triangle_candidates.cache_clear()


def _entry(folder, pattern):
    found = sorted(folder.rglob(pattern))
    assert len(found) == 1, found
    return found[0]


# a small table (res 8, 4 grid steps per texel) computes in well under a second
RES, SUB = 8, 4


def test_candidate_table_from_the_cache_is_the_fresh_table(cache):
    fresh = sphere.triangle_candidates(RES, sub=SUB, cache=False)
    first = sphere.triangle_candidates(RES, sub=SUB)  # computed and written
    entry = _entry(cache, "triangle-candidates-*.npz")
    sphere.triangle_candidates.cache_clear()
    again = sphere.triangle_candidates(RES, sub=SUB)  # read back
    assert again.dtype == torch.int64 and again.shape == fresh.shape
    assert torch.equal(first, fresh) and torch.equal(again, fresh)
    # the entry is what was read: a changed value in it (with its hash updated) is what comes back
    with np.load(entry) as z:
        table, head = z["table"].copy(), json.loads(str(z["header"][()]))
    table[0, 0, 0, 0] = 179
    head["values"] = sphere._values_digest(table)
    np.savez(entry, header=np.array(json.dumps(head)), table=table)
    sphere.triangle_candidates.cache_clear()
    assert int(sphere.triangle_candidates(RES, sub=SUB)[0, 0, 0, 0]) == 179


def _damage_truncate(path):
    path.write_bytes(path.read_bytes()[:300])


def _damage_garbage(path):
    path.write_bytes(b"not a zip file at all" * 10)


def _damage_flip_value(path):
    # a valid archive whose values no longer match the hash stored with them
    with np.load(path) as z:
        table, header = z["table"].copy(), z["header"].copy()
    table[1, 2, 3, 0] = (table[1, 2, 3, 0] + 1) % 180
    np.savez(path, header=header, table=table)


def _damage_wrong_key(path):
    with np.load(path) as z:
        table = z["table"].copy()
    head = {"key": "0" * 64, "values": sphere._values_digest(table)}
    np.savez(path, header=np.array(json.dumps(head)), table=table)


def _damage_bare_array(path):
    with open(path, "wb") as f:
        np.save(f, np.zeros(3))


@pytest.mark.parametrize(
    "damage",
    [_damage_truncate, _damage_garbage, _damage_flip_value, _damage_wrong_key, _damage_bare_array],
)
def test_a_damaged_candidate_entry_is_rebuilt(cache, damage):
    fresh = sphere.triangle_candidates(RES, sub=SUB, cache=False)
    sphere.triangle_candidates(RES, sub=SUB)
    entry = _entry(cache, "triangle-candidates-*.npz")
    damage(entry)
    sphere.triangle_candidates.cache_clear()
    assert torch.equal(sphere.triangle_candidates(RES, sub=SUB), fresh)
    # and the entry was rewritten whole: the next process reads the right table
    sphere.triangle_candidates.cache_clear()
    assert torch.equal(sphere._read_candidates(entry, sphere._candidates_key(RES, SUB), RES), fresh)


def _map(seed: int) -> EnvMap:
    """A small lat-long map with a bright spot (so the resampling splats a spike)."""
    g = torch.Generator().manual_seed(seed)
    data = torch.rand(16, 32, 3, generator=g) + 0.1
    data[3, 5] = 500.0
    return EnvMap(data, layout="latlong", name=f"test{seed}")


def test_cube_map_from_the_cache_is_the_fresh_cube(tmp_path):
    env = _map(1)
    fresh = env.to_cubemap(8)
    first = env.to_cubemap(8, cache=tmp_path)
    entry = _entry(tmp_path, "cube-*.npz")
    again = env.to_cubemap(8, cache=tmp_path)
    assert again.dtype == torch.float32 and again.shape == (6, 8, 8, 3)
    assert torch.equal(first, fresh) and torch.equal(again, fresh)
    # what was read is the entry: another map's cube is not taken for this one's
    other = _map(2)
    assert torch.equal(other.to_cubemap(8, cache=tmp_path), other.to_cubemap(8))
    assert len(list(tmp_path.glob("cube-*.npz"))) == 2
    assert entry.exists()
    # a cache argument that is neither a bool nor a folder is refused by name
    with pytest.raises(InputError, match="cache"):
        env.to_cubemap(8, cache=3)


def test_sh_projection_through_the_cube_cache_is_the_fresh_projection(tmp_path):
    env = _map(3)
    fresh = sh.project_envmap(env, 3, res=8)
    assert torch.equal(sh.project_envmap(env, 3, res=8, cache=tmp_path), fresh)
    assert torch.equal(sh.project_envmap(env, 3, res=8, cache=tmp_path), fresh)  # read back
    assert len(list(tmp_path.glob("cube-*.npz"))) == 1


def _cube_wrong_shape(path):
    with np.load(path) as z:
        header = z["header"].copy()
    np.savez(path, header=header, cube=np.zeros((6, 4, 4, 3), np.float32))


def _cube_nan(path):
    with np.load(path) as z:
        header, cube = z["header"].copy(), z["cube"].copy()
    cube[0, 0, 0, 0] = np.nan
    np.savez(path, header=header, cube=cube)


@pytest.mark.parametrize(
    "damage", [_damage_truncate, _damage_garbage, _cube_wrong_shape, _cube_nan]
)
def test_a_damaged_cube_entry_is_rebuilt(tmp_path, damage):
    env = _map(4)
    fresh = env.to_cubemap(8)
    env.to_cubemap(8, cache=tmp_path)
    entry = _entry(tmp_path, "cube-*.npz")
    damage(entry)
    assert torch.equal(env.to_cubemap(8, cache=tmp_path), fresh)
    with np.load(entry) as z:  # rewritten whole
        assert np.array_equal(z["cube"], fresh.numpy())


def test_vmf_band_factors_match_scipys_bessel_functions():
    # a_l = i_l(lam) / i_0(lam) = I_{l+1/2}(lam) / I_{1/2}(lam); scipy's exponentially scaled
    # Bessel functions are the independent reference. The continued fraction is exact to
    # rounding and a_l is a product of l ratios, so a few hundred ulps (1e-13) bound the
    # difference for every value scipy itself does not lose to underflow.
    from lobelight.envmap._convolve import vmf_band_factors

    for lam in (1e-6, 0.01, 0.7, 3.0, 41.0, 655.0, 10486.0):
        for order in (1, 6, 33):
            l = np.arange(order)
            ref = scipy.special.ive(l + 0.5, lam) / scipy.special.ive(0.5, lam)
            got = vmf_band_factors(lam, order)
            keep = ref > 1e-250
            np.testing.assert_allclose(got[keep], ref[keep], rtol=1e-12, atol=0)
            assert got[0] == 1.0 and np.all(np.diff(got) <= 0)


def test_the_start_benchmarks_phases_add_up_to_the_wall_time():
    # a child's record as _start_child.py writes it: seconds after the child's start
    record = {
        "parent_t0": 100.0,
        "start": 100.05,
        "end": 102.4,
        "torch_imported": 0.9,
        "library_imported": 1.2,
        "finished": 2.35,
        "timers": {
            "model_read": {"seconds": 0.2, "calls": 1, "first": 1.3},
            "map_read": {"seconds": 0.05, "calls": 1, "first": 1.5},
            "renderer_setup": {"seconds": 0.5, "calls": 1, "first": 1.6},
            "lighting": {"seconds": 0.1, "calls": 1, "first": 1.6},
            "chain": {"seconds": 0.05, "calls": 1, "first": 1.7},
            "background": {"seconds": 0.02, "calls": 1, "first": 1.8},
            "gl_context": {"seconds": 0.08, "calls": 1, "first": 1.6},
            "frame": {"seconds": 0.3, "calls": 1, "first": 2.0},
            "save": {"seconds": 0.04, "calls": 1, "first": 2.3},
            "exposure": {"seconds": 0.01, "calls": 1, "first": 2.3},
        },
    }
    wall = 2.6
    got, parts = phases(record, wall)
    assert tuple(got) == PHASES
    assert math.isclose(sum(got.values()), wall)
    assert math.isclose(got["process_start"], 0.05)
    assert math.isclose(got["command_start"], 0.1)  # from the library's import to the read
    assert math.isclose(got["exit"], 0.2)  # 100 + 2.6 - 102.4
    assert math.isclose(got["save"], 0.05)
    assert math.isclose(parts["rest"], 0.5 - 0.1 - 0.05 - 0.02 - 0.08)


def test_render_modules_import_without_trimesh_or_scipy():
    # the geometry, lobes and envmap layers a render needs load neither (trimesh is imported
    # when rays are first cast; the chain's Bessel factors need no scipy)
    code = (
        "import sys, lobelight.geometry.raycast, lobelight.geometry.sphere, lobelight.lobes, "
        "lobelight.envmap; print(sorted(m for m in ('trimesh', 'scipy', 'networkx') "
        "if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_the_commands_import_without_the_gltf_library():
    # pygltflib (and dataclasses-json's schemas under it) is imported when a glTF file is read
    # or written, not by every command's start
    code = "import sys, lobelight.cli._commands; print('pygltflib' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


@pytest.mark.slow  # five renders in new processes: about a minute on a busy 2-core machine
@pytest.mark.skipif(not gl_available(), reason="no headless OpenGL context (EGL)")
def test_bench_start_runs_the_command_and_accounts_for_each_run(tmp_path):
    from lobelight.bench import bench_start

    rec = bench_start(vertices=300, runs=2, size=32, env="builtin", folder=tmp_path)
    assert rec["benchmark"] == "start" and rec["model"]["vertices"] > 200
    for run in (rec["cold"], *rec["warm"]):
        assert tuple(run["phases"]) == PHASES
        assert math.isclose(sum(run["phases"].values()), run["wall"], rel_tol=1e-9)
        assert run["phases"]["model_read"] > 0 and run["phases"]["frame"] > 0
    assert len(rec["warm"]) == 2 and rec["plain_wall"] > 0
    # the cold run wrote what the warm ones read: the candidate table and the chain
    assert list((tmp_path / "cache" / "geometry").glob("triangle-candidates-*.npz"))
    assert list((tmp_path / "cache" / "prefilter").glob("*.npz"))


def test_bench_start_children_keep_the_bytecode_cache(tmp_path, monkeypatch):
    """A start is measured as an installed package starts: a PYTHONDONTWRITEBYTECODE set
    around the benchmark would make every child compile lobelight's modules again."""
    from lobelight.bench import start

    seen = []

    def fake_run(python, args, env, work, *, timed):
        seen.append(dict(env))
        names = ("lighting", "sun", "sh_projection", "chain", "background", "candidates")
        parts = dict.fromkeys((*names, "sharp_lobe", "gl_context", "gl_programs", "rest"), 0.0)
        parts.update(sh_cube=0.0, chain_cube=0.0)
        return {"wall": 1.0, "cpu": 1.0, "load_1min_before": 0.0,
                "phases": dict.fromkeys(PHASES, 0.1), "setup_parts": parts}  # fmt: skip

    monkeypatch.setenv("PYTHONDONTWRITEBYTECODE", "1")
    monkeypatch.setattr(start, "_run", fake_run)
    monkeypatch.setattr(start, "_model", lambda folder, vertices: (folder / "m.npz", 0.0))
    monkeypatch.setattr(start, "_vertices", lambda model: 300)
    (tmp_path / "m.npz").write_bytes(b"x")
    start.bench_start(vertices=300, runs=1, size=32, env="builtin", folder=tmp_path)
    assert len(seen) == 3
    assert all("PYTHONDONTWRITEBYTECODE" not in env for env in seen)
    assert all(env["LOBELIGHT_CACHE"] == str(tmp_path / "cache") for env in seen)
