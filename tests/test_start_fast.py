"""A render's start without waste: the model file read on two threads with its checks decided in
float32 where that is plain, the sharp lobe's measurement kept on disk, and the command line's
process ended without the interpreter's teardown. Each gives what the plain way gives."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import textwrap
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

from lobelight import _container, brdf, model
from lobelight.bench import synthetic_model
from lobelight.brdf import _sharp
from lobelight.errors import InputError
from lobelight.model import _format

# --------------------------------------------------------------------------------------------
# the model read


@pytest.fixture(scope="module")
def model_file(tmp_path_factory):
    """A small model file with dropped records, visibility and hit tiles (a sharp material)."""
    path = tmp_path_factory.mktemp("model") / "m.npz"
    synthetic_model(200, 2, vary=True).save(path)
    return path


def _reference_expansion(path):
    """The file's Gaussians expanded to every (vertex, view) record in float64 by plain numpy
    indexing: (w, mu, lam), dropped records (0, (0, 1, 0), 1)."""
    with np.load(path, allow_pickle=False) as z:
        keep, g7 = z["keep"], z["gaussians"].astype(np.float64)
    v, j = keep.shape
    n = g7.shape[1]
    w, mu, lam = np.zeros((v, j, n, 3)), np.zeros((v, j, n, 3)), np.ones((v, j, n))
    mu[..., 1] = 1.0
    w[keep] = g7[..., :3]
    mu[keep] = g7[..., 3:6] / np.linalg.norm(g7[..., 3:6], axis=-1, keepdims=True)
    lam[keep] = g7[..., 6] ** -2.0
    return w, mu, lam


def test_the_read_expands_the_records_as_plain_indexing_does(model_file, monkeypatch):
    w, mu, lam = _reference_expansion(model_file)
    assert 0 < (w.max((-1, -2)) > 0).mean() < 1  # some records dropped, some kept
    for threads in (1, 2):
        monkeypatch.setattr(_format, "READ_THREADS", threads)
        monkeypatch.setattr(_format, "_PARALLEL_BYTES", 0)  # this small file on threads too
        g = model.load(model_file).gaussians
        # float32 against float64: the weights are copied exactly; a mean normalised and a
        # sharpness sigma^-2 computed in float32 are within a few ulps (6e-8 each)
        np.testing.assert_array_equal(g.w.numpy(), w.astype(np.float32))
        np.testing.assert_allclose(g.mu.numpy(), mu, rtol=0, atol=3e-7)
        np.testing.assert_allclose(g.lam.numpy(), lam, rtol=3e-7, atol=0)
        assert g.w.is_contiguous() and g.mu.is_contiguous() and g.lam.is_contiguous()


def test_a_read_on_threads_gives_every_array_as_numpy_reads_it(model_file, monkeypatch):
    monkeypatch.setattr(_format, "_PARALLEL_BYTES", 0)
    got = _format._open(model_file, "m")
    with np.load(model_file, allow_pickle=False) as z:
        assert sorted(got) == sorted(z.files)
        for k in z.files:
            np.testing.assert_array_equal(got[k], z[k])
    m = model.load(model_file)
    with np.load(model_file, allow_pickle=False) as z:  # the tiles, as tensors of their own
        assert torch.equal(m.visibility_held, torch.from_numpy(z["visibility"]))
        # the hit tiles stored as their texels that hit, made whole
        face = m.hits_held[0].reshape(m.hits_held[0].shape[0], -1)
        assert torch.equal(face[face >= 0], torch.from_numpy(z["hit_face"]))


def _bad_crc(src, dst, member):
    """``src`` copied to ``dst`` with one byte of ``member``'s compressed data changed."""
    data = bytearray(src.read_bytes())
    with zipfile.ZipFile(src) as z:
        info = z.getinfo(member)
    name_len = int.from_bytes(data[info.header_offset + 26 : info.header_offset + 28], "little")
    extra = int.from_bytes(data[info.header_offset + 28 : info.header_offset + 30], "little")
    at = info.header_offset + 30 + name_len + extra + info.compress_size // 2
    data[at] ^= 0xFF
    dst.write_bytes(bytes(data))


def test_a_damaged_member_read_on_threads_is_one_error_naming_the_file(
    model_file, tmp_path, monkeypatch
):
    monkeypatch.setattr(_format, "_PARALLEL_BYTES", 0)
    bad = tmp_path / "bad.npz"
    _bad_crc(model_file, bad, "hit_face.npy")
    with pytest.raises(InputError) as e:
        model.load(bad)
    assert e.value.what == str(bad) and "cannot read model file" in e.value.problem


def test_a_file_replaced_while_it_is_read_is_refused(model_file, tmp_path, monkeypatch):
    # the sizes are checked on the archive first opened; the threads open the file again, and
    # a file replaced in between (other members, other sizes) must not be read past that check
    path = tmp_path / "m.npz"
    path.write_bytes(model_file.read_bytes())
    other = tmp_path / "other.npz"
    synthetic_model(300, 1, vary=True).save(other)
    check_sizes = _format._check_sizes

    def then_replace(*args):
        check_sizes(*args)
        os.replace(other, path)

    monkeypatch.setattr(_format, "_check_sizes", then_replace)
    monkeypatch.setattr(_format, "_PARALLEL_BYTES", 0)
    with pytest.raises(InputError, match="changed while it was read"):
        model.load(path)


# --------------------------------------------------------------------------------------------
# the model file read ahead in a child process (lobelight._container)


@pytest.fixture
def ahead(monkeypatch):
    """Read ahead on for files of any size, whatever threads earlier tests left idle in this
    process (a server's, a client's: the child only inflates, and takes no lock of theirs);
    what each ``take`` gave, recorded."""
    monkeypatch.setattr(_container, "AHEAD_MIN_BYTES", 0)
    monkeypatch.setattr(_container, "_other_threads", lambda: False)
    taken = []
    take = _container.take

    def recorded(path, found):
        out = take(path, found)
        taken.append(out is not None)
        return out

    monkeypatch.setattr(_container, "take", recorded)
    yield taken
    _container.take(Path("/nonexistent"), [])  # a read ahead never taken: its child reaped


def _same_models(a, b):
    for field in ("w", "mu", "lam"):
        assert torch.equal(getattr(a.gaussians, field), getattr(b.gaussians, field))
    assert a.bounce is None and b.bounce is None  # this synthetic model has none
    for field in ("diffuse", "views", "visibility_held"):
        assert torch.equal(getattr(a, field), getattr(b, field))
    assert torch.equal(a.mesh.vertices, b.mesh.vertices) and torch.equal(a.mesh.faces, b.mesh.faces)
    assert all(torch.equal(x, y) for x, y in zip(a.hits_held, b.hits_held, strict=True))
    assert a.provenance == b.provenance


def test_a_model_read_ahead_is_the_model_read_plainly(model_file, ahead):
    plain = model.load(model_file)
    ahead.clear()
    assert _container.read_ahead(model_file)
    read = model.load(model_file)
    assert ahead == [True]  # the members came from the child
    _same_models(read, plain)
    # the arrays are the read's own: writable, as a plain read's are
    assert read.gaussians.w.numpy().flags.writeable


def test_a_file_changed_after_the_read_ahead_is_read_again(model_file, tmp_path, ahead):
    path = tmp_path / "m.npz"
    path.write_bytes(model_file.read_bytes())
    assert _container.read_ahead(path)
    other = tmp_path / "other.npz"
    synthetic_model(300, 1, vary=True).save(other)
    expected = model.load(other)
    os.replace(other, path)
    ahead.clear()
    read = model.load(path)
    assert ahead == [False]
    _same_models(read, expected)


def test_a_damaged_member_read_ahead_gives_the_plain_reads_error(model_file, tmp_path, ahead):
    bad = tmp_path / "bad.npz"
    _bad_crc(model_file, bad, "gaussians.npy")
    with pytest.raises(InputError) as plain:
        model.load(bad)
    ahead.clear()
    assert _container.read_ahead(bad)
    with pytest.raises(InputError) as read:
        model.load(bad)
    assert ahead == [False]  # the child found the checksum wrong: the file was read again
    assert (read.value.what, read.value.problem) == (plain.value.what, plain.value.problem)


def test_no_read_ahead_where_it_cannot_help_or_would_be_unsafe(model_file, tmp_path, monkeypatch):
    # each refusal for its own reason: no other thread counted until the last case
    other_threads = _container._other_threads
    monkeypatch.setattr(_container, "_other_threads", lambda: False)
    # the default threshold: this small file inflates faster than a child starts
    assert model_file.stat().st_size < _container.AHEAD_MIN_BYTES
    assert not _container.read_ahead(model_file)
    monkeypatch.setattr(_container, "AHEAD_MIN_BYTES", 0)
    assert not _container.read_ahead(tmp_path / "missing.npz")
    (tmp_path / "not.npz").write_bytes(b"not a zip file")
    assert not _container.read_ahead(tmp_path / "not.npz")
    # members declared larger than the size rule allows: nothing is allocated for them
    monkeypatch.setattr(_container, "MAX_READ_BYTES", 1000)
    assert not _container.read_ahead(model_file)
    monkeypatch.undo()
    monkeypatch.setattr(_container, "AHEAD_MIN_BYTES", 0)
    # the same file with no other thread is read ahead (the child reaped by a take)
    with monkeypatch.context() as m:
        m.setattr(_container, "_other_threads", lambda: False)
        assert _container.read_ahead(model_file)
        assert _container.take(Path("/nonexistent"), []) is None
    assert _container._other_threads is other_threads
    # a thread running: a fork would copy only this one
    import threading

    stop = threading.Event()
    t = threading.Thread(target=stop.wait)
    t.start()
    try:
        assert not _container.read_ahead(model_file)
    finally:
        stop.set()
        t.join()


def test_the_command_line_reads_its_model_ahead(model_file, tmp_path):
    # the command line's own process: the model named on it is read ahead before torch loads
    code = textwrap.dedent(
        """
        import sys
        from lobelight import _container
        _container.AHEAD_MIN_BYTES = 0
        take = _container.take
        def recorded(path, found):
            out = take(path, found)
            print("taken", out is not None, file=sys.stderr)
            return out
        _container.take = recorded
        start = _container.read_ahead
        def started(path):
            print("torch loaded", "torch" in sys.modules, file=sys.stderr)
            return start(path)
        _container.read_ahead = started
        sys.argv = ["lobelight", "info", sys.argv[1]]
        from lobelight.cli import main
        main()
        """
    )
    r = subprocess.run(
        [sys.executable, "-c", code, str(model_file)], capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 0, r.stderr
    assert "torch loaded False" in r.stderr and "taken True" in r.stderr


def _records(sigma, weight, mean=(0.0, 0.0, 1.0)):
    """One stored record (1, 1, 7) float32."""
    return np.array([[[weight, 0.0, 0.0, *mean, sigma]]], np.float32)


def _carried(sigma, weight) -> float:
    """The light a record carries, in float64: its weight times 2 pi sigma^2 (1 - e^-2/sigma^2),
    written out independently of lobelight.lobes.sg."""
    s = float(np.float32(sigma))
    return float(np.float32(weight)) * 2 * math.pi * s * s * -math.expm1(-2 / (s * s))


def _verdict(g7, integral=False):
    try:
        _format._check_records(g7, integral, "m")
        return True
    except InputError:
        return False


@pytest.mark.parametrize("rel", [-1e-3, -2e-6, 2e-6, 1e-3])
def test_a_record_at_the_light_bound_is_judged_in_float64(rel):
    # a weight that makes the record carry MAX_LIGHT (1 + rel): the float32 screen cannot
    # tell these apart from the bound (they are within its 1e-4 margin or just outside), so
    # the verdict must be the float64 one, with the float64 value in the message
    sigma = 0.5
    weight = _format.MAX_LIGHT * (1 + rel) / _carried(sigma, 1.0)
    g7 = _records(sigma, weight)
    assert _verdict(g7) == (_carried(sigma, weight) <= _format.MAX_LIGHT)


@pytest.mark.parametrize("scale", [1e-6 * (1 - 1e-6), 1e-6 * (1 + 1e-6), 1e-6 * (1 + 1e-3)])
def test_a_mean_at_the_zero_bound_is_judged_in_float64(scale):
    mean = np.float32(scale) * np.array([0.6, 0.0, 0.8], np.float32)
    g7 = _records(0.3, 0.1, mean)
    assert _verdict(g7) == (float(np.linalg.norm(mean.astype(np.float64))) > 1e-6)


def test_the_float32_screen_passes_only_what_float64_passes():
    # many records around each bound (widths at both ends, weights near the light bound,
    # zero-ish means, a negative weight): the screen's and float64's verdicts agree
    rng = np.random.default_rng(5)
    cases = []
    for sigma in (_format.SIGMA_MIN, 1e-3, 0.3, 2.0, _format.SIGMA_MAX):
        for rel in (-1e-2, -1e-5, 1e-5):  # the last two within the float32 screen's margin
            cases.append(_records(sigma, _format.MAX_LIGHT * (1 + rel) / _carried(sigma, 1.0)))
    cases.append(_records(_format.SIGMA_MAX * (1 + 2e-5), 0.1))  # just too wide
    cases.append(_records(_format.SIGMA_MIN * (1 - 1e-6), 0.1))  # just too sharp
    cases.append(_records(0.3, -1e-30))  # a negative weight
    cases.append(_records(0.3, -0.0))  # -0 is not negative
    for g7 in cases:
        bulk = np.repeat(_records(0.2, 0.5), 50, axis=0)
        bulk[..., :3] *= rng.uniform(0, 1, (50, 1, 3)).astype(np.float32)
        g = np.concatenate([bulk, g7])
        w = g[..., :3].astype(np.float64)
        sig = g[..., 6].astype(np.float64)
        carried = w.max(-1) * 2 * np.pi * sig**2 * -np.expm1(-2 / sig**2)
        want = (
            bool(sig.min() >= _format.SIGMA_MIN)
            and bool(sig.max() <= _format.SIGMA_MAX * (1 + _format._SIGMA_ROUNDING))
            and bool((w >= 0).all())
            and float(carried.max()) <= _format.MAX_LIGHT
        )
        assert _verdict(g) == want
        with np.errstate(over="ignore"):  # beyond float16's range: inf, refused
            half = g.astype(np.float16)
        assert _verdict(half, integral=True) == _verdict_f64(half, True)


def _verdict_f64(g7, integral):
    try:
        _format._check_records_f64(g7, integral, "m")
        return True
    except InputError:
        return False


def test_hit_distances_are_judged_by_their_bits_as_by_their_values():
    # every float16 bit pattern on its own: finite and not negative (-0 is not), as numpy's
    # comparison of the values says
    patterns = np.arange(1 << 16, dtype=np.uint32).astype(np.uint16).view(np.float16)
    for x in patterns:
        want = bool(np.isfinite(x)) and not bool(x < 0)
        assert _format._distances_fine(np.full((1, 2, 2), x)) == want
    fine = np.abs(patterns[np.isfinite(patterns)]).reshape(-1, 2, 2)
    assert _format._distances_fine(fine)
    assert not _format._distances_fine(np.concatenate([fine, np.full((1, 2, 2), -1e-7)]))


# --------------------------------------------------------------------------------------------
# the sharp lobe on disk


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """A private cache folder, and the sharp lobe's memory cache emptied around the test."""
    monkeypatch.setenv("LOBELIGHT_CACHE", str(tmp_path))
    _sharp._CACHE.clear()
    yield tmp_path
    _sharp._CACHE.clear()


def _ggx(alpha=0.03):
    return brdf.from_dict({"type": "ggx", "alpha": alpha, "specular": [0.9, 0.8, 0.6]})


def _same(a, b):
    return (
        a.warp == b.warp
        and torch.equal(a.weights, b.weights)
        and torch.equal(a.lam, b.lam)
        and torch.equal(a.albedo, b.albedo)
    )


def _entries(folder):
    return sorted((folder / "brdf").glob("sharp-lobe-*.npz"))


def test_a_stored_sharp_lobe_is_the_measured_one(cache):
    spec = _ggx()
    fresh = _sharp._measure(spec)
    first = brdf.sharp_lobe(spec)  # measured and written
    (entry,) = _entries(cache)
    _sharp._CACHE.clear()
    again = brdf.sharp_lobe(spec)  # read back, as in a new process
    assert _same(first, fresh) and _same(again, fresh)
    # what was read is the entry: a changed value (its hash updated) is what comes back
    with np.load(entry) as z:
        head = json.loads(str(z["header"][()]))
        arrays = {k: z[k].copy() for k in ("weights", "lam", "albedo")}
    arrays["albedo"][3, 1] = 0.5
    head["values"] = _sharp._values_digest(arrays, head["warp"])
    np.savez(entry, header=np.array(json.dumps(head)), **arrays)
    _sharp._CACHE.clear()
    assert float(brdf.sharp_lobe(spec).albedo[3, 1]) == 0.5


def test_each_material_has_its_own_entry_and_a_wide_lobe_is_stored_as_none(cache):
    assert brdf.sharp_lobe(_ggx(0.3)) is None  # wider than SHARP_LAM: fitted Gaussians
    assert brdf.sharp_lobe(_ggx(0.03)) is not None
    assert len(_entries(cache)) == 2
    _sharp._CACHE.clear()
    assert brdf.sharp_lobe(_ggx(0.3)) is None


def _truncate(path):
    path.write_bytes(path.read_bytes()[:100])


def _garbage(path):
    path.write_bytes(b"PK\x03\x04" + bytes(300))


def _value_changed(path):
    # a value changed without its hash (bit rot, a careless edit)
    with np.load(path) as z:
        arrays = {k: z[k].copy() for k in z.files}
    arrays["lam"][0] *= 2
    np.savez(path, **arrays)


def _foreign_key(path):
    with np.load(path) as z:
        arrays = {k: z[k].copy() for k in z.files}
    head = json.loads(str(arrays["header"][()]))
    head["key"] = "0" * 64
    arrays["header"] = np.array(json.dumps(head))
    np.savez(path, **arrays)


def _fifo(path):
    path.unlink()
    os.mkfifo(path)


_NO_FIFO = pytest.mark.skipif(
    not hasattr(os, "mkfifo"), reason="this system has no FIFOs (os.mkfifo) to put in the cache"
)


@pytest.mark.parametrize(
    "damage",
    [_truncate, _garbage, _value_changed, _foreign_key, pytest.param(_fifo, marks=_NO_FIFO)],
)
def test_a_damaged_sharp_lobe_entry_is_measured_again_and_rewritten(cache, damage):
    spec = _ggx()
    fresh = _sharp._measure(spec)
    brdf.sharp_lobe(spec)
    (entry,) = _entries(cache)
    damage(entry)
    _sharp._CACHE.clear()
    assert _same(brdf.sharp_lobe(spec), fresh)
    _sharp._CACHE.clear()
    key = _sharp._entry_key(json.dumps(spec.to_dict(), sort_keys=True))
    found, lobe = _sharp._read_entry(entry, key)
    assert found and _same(lobe, fresh)  # rewritten whole


# --------------------------------------------------------------------------------------------
# the command line's process ends at once, after what a normal exit does that can be seen


def _run(code: str, *args: str, tmp_path) -> subprocess.CompletedProcess:
    env = {**os.environ, "LOBELIGHT_CACHE": str(tmp_path / "cache")}
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code), *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )


# the program's own door (main() without argv), with an exit handler, a C library's buffered
# output, a logging handler writing a file, and a temporary folder removed at exit
_PROGRAM = """
    import atexit, ctypes, logging, sys, tempfile, weakref
    from lobelight.cli import main
    # a C library printing at exit, into a pipe: held in C's stdio buffer until flushed
    atexit.register(lambda: ctypes.CDLL(None).printf(b"from C\\n"))
    atexit.register(lambda: print("exit handler ran", flush=True))  # runs first
    log = logging.getLogger("t")
    log.addHandler(logging.FileHandler(sys.argv[1]))
    log.warning("logged")
    tmp = tempfile.TemporaryDirectory()
    open(sys.argv[2], "w").write(tmp.name)
    sys.argv = ["lobelight", *sys.argv[3:]]
    sys.exit(main())
"""


@pytest.mark.skipif(sys.platform == "win32", reason="printf through ctypes.CDLL(None)")
def test_the_program_ends_after_its_output_and_exit_handlers(model_file, tmp_path):
    log, tmp_name = tmp_path / "t.log", tmp_path / "tmp-name"
    p = _run(_PROGRAM, str(log), str(tmp_name), "info", str(model_file), "--json",
             tmp_path=tmp_path)  # fmt: skip
    assert p.returncode == 0, p.stderr
    # the summary, then the exit handler's line, then what C buffered (flushed last)
    summary, rest = p.stdout.rsplit("}", 1)
    assert json.loads(summary + "}")["command"] == "info"
    assert rest == "\nexit handler ran\nfrom C\n"
    assert log.read_text() == "logged\n"
    assert not os.path.exists(tmp_name.read_text())  # removed by weakref.finalize at exit


def test_the_programs_error_ends_with_its_code_and_one_line(tmp_path):
    p = _run(_PROGRAM, str(tmp_path / "t.log"), str(tmp_path / "n"), "info",
             str(tmp_path / "missing.npz"), tmp_path=tmp_path)  # fmt: skip
    assert p.returncode == 2
    assert p.stderr.strip().splitlines()[-1].startswith("lobelight: error: ")
    assert "exit handler ran" in p.stdout


def test_the_program_waits_for_a_thread_that_still_runs(tmp_path):
    # a non-daemon thread still at work: the process is not ended under it
    code = """
        import sys, threading, time
        from lobelight.cli import main
        marker = sys.argv[1]
        def late():
            time.sleep(1.0)
            open(marker, "w").write("done")
        threading.Thread(target=late).start()
        sys.argv = ["lobelight", "info", sys.argv[2]]
        sys.exit(main())
    """
    marker = tmp_path / "marker"
    p = _run(code, str(marker), str(tmp_path / "missing.npz"), tmp_path=tmp_path)
    assert p.returncode == 2 and marker.read_text() == "done"


def test_main_with_arguments_returns_its_code(tmp_path):
    from lobelight.cli import main

    assert main(["info", str(tmp_path / "missing.npz")]) == 2


def test_the_start_benchmarks_child_writes_its_record_as_the_process_ends(model_file, tmp_path):
    # the child runs the command line, which ends its process itself: the record comes from
    # the child's exit handler, with the model's read timed and the end after the start
    from lobelight.bench.start import CHILD

    times = tmp_path / "times.json"
    t0 = time.time()
    p = subprocess.run(
        [sys.executable, str(CHILD), str(times), repr(t0), "--", "info", str(model_file)],
        capture_output=True,
        text=True,
        env={**os.environ, "LOBELIGHT_CACHE": str(tmp_path / "cache")},
        timeout=300,
    )
    assert p.returncode == 0, p.stderr
    assert "command: info" in p.stdout
    record = json.loads(times.read_text())
    assert t0 <= record["start"] <= record["end"] <= time.time()
    assert record["timers"]["model_read"]["calls"] == 1


# --------------------------------------------------------------------------------------------
# the imports of the program's start, without the garbage collector


def test_the_programs_imports_run_uncollected_and_are_frozen_after(tmp_path):
    # the program's own door: while torch and the commands load the collector is off (no
    # collection at all), afterwards it is on again with what they made frozen
    code = """
        import gc, sys
        import lobelight.cli as cli
        collections = []
        gc.callbacks.append(lambda phase, info: phase == "start" and collections.append(1))
        import importlib
        real = importlib.import_module
        def watched(name, *a):
            if name == "lobelight.cli._commands":
                before = len(collections)
                module = real(name, *a)
                print("during", gc.isenabled(), len(collections) - before, flush=True)
                return module
            return real(name, *a)
        cli.importlib.import_module = watched
        sys.argv = ["lobelight", "info", sys.argv[1]]
        import atexit
        atexit.register(lambda: print("after", gc.isenabled(), gc.get_freeze_count() > 10**5,
                                      flush=True))
        sys.exit(cli.main())
    """
    p = _run(code, str(tmp_path / "missing.npz"), tmp_path=tmp_path)
    assert p.returncode == 2, p.stderr
    assert p.stdout.splitlines() == ["during False 0", "after True True"]


def test_main_with_arguments_leaves_the_callers_collector_as_it_was(tmp_path):
    # a program that embeds the command line: no freeze, the collector's state its own
    code = """
        import gc, sys
        from lobelight.cli import main
        gc.disable()
        frozen = gc.get_freeze_count()
        code = main(["info", sys.argv[1]])
        print(code, gc.isenabled(), gc.get_freeze_count() == frozen)
    """
    p = _run(code, str(tmp_path / "missing.npz"), tmp_path=tmp_path)
    assert p.stdout.split() == ["2", "False", "True"], p.stderr


def test_imports_uncollected_restores_a_disabled_collector(tmp_path):
    code = """
        import gc
        from lobelight.cli._process import imports_uncollected
        gc.disable()
        with imports_uncollected():
            pass
        print(gc.isenabled(), gc.get_freeze_count() > 0)
    """
    p = _run(code, tmp_path=tmp_path)
    assert p.stdout.split() == ["False", "True"], p.stderr
