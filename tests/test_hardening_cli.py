"""The command line's doors hold: outputs never replace inputs, ``-o`` is used as given, sizes
have maxima from memory, signals are never bad input, non-regular files are said to be what
they are, one door for unexpected errors, and no leftovers of killed runs.

Each refusal is checked the same way (:func:`refused`): exit 2, one line on stderr naming the
input and the problem, every input file unchanged (hashed before and after), and no work
started (the heavy steps are stood in for by a function that fails the test).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import OpenEXR
import pygltflib
import pytest
import torch
import trimesh

from lobelight import _cache, _io, _memory, cli, model, scene
from lobelight.cli import _commands, _limits
from lobelight.errors import InputError, Terminated
from lobelight.fit import Gaussians, MeshFit
from lobelight.geometry import sphere

#: The heavy steps of the commands: reaching one means the work started.
_WORK = ["fit_model", "Renderer", "turntable", "compare", "compare_brdf", "demo", "lobes_demo"]


class WorkStarted(BaseException):
    """A heavy step was reached (not an Exception: no handler takes it)."""


@pytest.fixture
def no_work(monkeypatch):
    """The heavy steps raise :class:`WorkStarted`."""

    def work(*args, **kwargs):
        raise WorkStarted

    for name in _WORK:
        monkeypatch.setattr(_commands, name, work)


def _hash(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def run(capsys, argv) -> tuple[int, str, str]:
    capsys.readouterr()
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def refused(capsys, argv, *, names: str, problem: str, inputs=(), code: int = 2) -> str:
    """Run ``argv``: it exits ``code`` with one stderr line naming ``names`` and ``problem``, no
    work started, every file of ``inputs`` unchanged. Returns the line."""
    before = {p: _hash(p) for p in inputs}
    try:
        got, out, err = run(capsys, argv)
    except WorkStarted:
        pytest.fail(f"{argv}: the work started")
    lines = err.strip().splitlines()
    assert got == code, (argv, got, err)
    assert len(lines) == 1, err
    assert names in lines[0] and problem in lines[0], lines[0]
    assert {p: _hash(p) for p in inputs} == before, "an input changed"
    if "--json" in argv:
        assert set(json.loads(out)) == {"error"}
    return lines[0]


# --------------------------------------------------------------------------------------------
# files


def _tiny_model(path: Path, provenance: dict | None = None) -> Path:
    sc = scene.builtin("sphere", subdivisions=0, model="ggx", roughness=0.2)
    v, j, n = sc.mesh.n_vertices, 92, 1
    g = torch.Generator().manual_seed(1)
    w = torch.rand(v, j, n, 3, generator=g)
    mu = torch.nn.functional.normalize(torch.randn(v, j, n, 3, generator=g), dim=-1)
    lam = torch.rand(v, j, n, generator=g) * 100 + 1
    fit = MeshFit(
        Gaussians(w, mu, lam), torch.rand(v, 9, 3, generator=g), sphere.geodesic_views(), None
    )
    model.save(path, sc.mesh, sc.materials, fit, provenance=provenance or {"scene": "s"})
    return path


@pytest.fixture
def files(tmp_path, monkeypatch):
    """A mesh, a scene file naming it and a map, the map, and a model, in a folder that is the
    working directory."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    trimesh.creation.icosphere(1).export(tmp_path / "in.obj")
    cv2.imwrite(str(tmp_path / "env.hdr"), np.full((8, 16, 3), 0.5, np.float32))
    (tmp_path / "sc.toml").write_text('mesh = "in.obj"\nenvironment = "env.hdr"\n')
    _tiny_model(tmp_path / "m.npz")
    return tmp_path


# --------------------------------------------------------------------------------------------
# outputs onto inputs


def test_bake_output_onto_its_mesh_is_refused(files, capsys, no_work):
    refused(capsys, ["bake", "in.obj", "-o", "in.obj"], names="in.obj", problem="is the input",
            inputs=[files / "in.obj"])  # fmt: skip


def test_bake_output_onto_its_scene_file_is_refused(files, capsys, no_work):
    refused(capsys, ["bake", "sc.toml", "-o", "sc.toml", "--json"], names="sc.toml",
            problem="is the input", inputs=[files / "sc.toml"])  # fmt: skip


def test_bake_output_onto_the_mesh_its_scene_file_names_is_refused(files, capsys, no_work):
    refused(capsys, ["bake", "sc.toml", "-o", "in.obj"], names="in.obj", problem="is the input",
            inputs=[files / "in.obj", files / "sc.toml"])  # fmt: skip


def test_bake_output_onto_its_scene_s_map_is_refused(files, capsys, no_work):
    # the map is only named by the model (render reads it): an input all the same
    refused(capsys, ["bake", "sc.toml", "-o", "env.hdr"], names="env.hdr", problem="is the input",
            inputs=[files / "env.hdr"])  # fmt: skip


def test_bake_output_through_a_symlink_to_its_mesh_is_refused(files, capsys, no_work):
    (files / "link.npz").symlink_to(files / "in.obj")
    line = refused(capsys, ["bake", "in.obj", "-o", "link.npz"], names="link.npz",
                   problem="is the input", inputs=[files / "in.obj"])  # fmt: skip
    assert "in.obj" in line  # and says which input it is


def test_bake_output_onto_a_hard_link_of_its_map_is_refused(files, capsys, no_work):
    os.link(files / "env.hdr", files / "same.npz")
    refused(capsys, ["bake", "in.obj", "--env", "env.hdr", "-o", "same.npz"], names="same.npz",
            problem="is the input", inputs=[files / "env.hdr"])  # fmt: skip


def test_bake_checkpoint_onto_an_input_is_refused(files, capsys, no_work):
    # the bake also writes MODEL.ckpt: an input there is refused like the model itself
    (files / "m2.npz.ckpt").symlink_to(files / "in.obj")
    refused(capsys, ["bake", "in.obj", "-o", "m2.npz"], names="m2.npz.ckpt",
            problem="is the input", inputs=[files / "in.obj"])  # fmt: skip


def test_render_output_onto_its_map_is_refused(files, capsys, no_work):
    refused(capsys, ["render", "m.npz", "--env", "env.hdr", "-o", "env.hdr"], names="env.hdr",
            problem="is the input", inputs=[files / "env.hdr", files / "m.npz"])  # fmt: skip


def test_render_output_symlinked_to_its_map_is_refused(files, capsys, no_work):
    (files / "pic.exr").symlink_to(files / "env.hdr")
    refused(capsys, ["render", "m.npz", "--env", "env.hdr", "-o", "pic.exr"], names="pic.exr",
            problem="is the input", inputs=[files / "env.hdr"])  # fmt: skip


def test_render_turntable_frame_onto_an_input_is_refused(files, capsys, no_work):
    (files / "spin").mkdir()
    os.link(files / "m.npz", files / "spin" / "frame_001.png")
    refused(capsys, ["render", "m.npz", "--turntable", "3", "-o", "spin"], names="frame_001.png",
            problem="is the input", inputs=[files / "m.npz"])  # fmt: skip


def test_compare_brdf_output_folder_onto_its_map_is_refused(files, capsys, no_work):
    refused(capsys, ["compare-brdf", "--env", "env.hdr", "-o", "env.hdr"], names="env.hdr",
            problem="is the input", inputs=[files / "env.hdr"])  # fmt: skip


def test_a_folder_output_onto_a_file_is_refused(files, capsys, no_work):
    refused(capsys, ["lobes-demo", "-o", "in.obj"], names="in.obj", problem="not a folder",
            inputs=[files / "in.obj"])  # fmt: skip


def test_an_output_beside_its_inputs_reaches_the_work(files, capsys, no_work):
    with pytest.raises(WorkStarted):
        cli.main(["bake", "sc.toml", "-o", "model.npz", "-q"])
    with pytest.raises(WorkStarted):
        cli.main(["render", "m.npz", "--env", "env.hdr", "-o", "pic.png", "-q"])


def test_a_write_never_replaces_an_input_while_inputs_are_protected(tmp_path):
    # the last guard, below the command line's early check
    src = tmp_path / "in.bin"
    src.write_bytes(b"input")
    with _io.protect_inputs():
        _io.check_input(src, limit=100)
        with pytest.raises(InputError, match="is the input"):
            with _io.atomic_writer(tmp_path / "in.bin") as f:
                f.write(b"output")
    assert src.read_bytes() == b"input" and not list(tmp_path.glob(".*partial*"))
    with _io.atomic_writer(src) as f:  # outside the guard a library may rewrite what it read
        f.write(b"output")
    assert src.read_bytes() == b"output"


# --------------------------------------------------------------------------------------------
# -o as given


def test_explicit_output_with_a_colon_is_used_as_given(files):
    assert _commands._model_path("knot:2", "a:b.npz") == Path("a:b.npz")
    (files / "dir:x").mkdir()
    assert _commands._model_path("knot", "dir:x/m.npz") == Path("dir:x/m.npz")
    # only the default name, made from a built-in scene's name, turns ':' into '-'
    assert _commands._model_path("knot:2", None) == Path("knot-2.lobelight.npz")


def test_output_in_a_folder_with_a_colon_is_not_renamed(files, capsys, no_work):
    # the folder the user gave does not exist: the error names it as given
    refused(capsys, ["bake", "in.obj", "-o", "nodir:x/m.npz"], names="nodir:x/m.npz",
            problem="does not exist")  # fmt: skip


# --------------------------------------------------------------------------------------------
# numeric flags: a maximum derived from memory or from the type, one line before any work

_TOO_LARGE = [
    (["render", "m.npz", "--base-res", "65536"], "--base-res"),
    (["render", "m.npz", "--base-res", "48"], "--base-res"),  # not a power of two
    (["render", "m.npz", "--size", "16384"], "--size"),
    (["render", "m.npz", "--size", "99999999999x1"], "--size"),
    (["render", "m.npz", "--width", "1000000"], "--width"),
    (["render", "m.npz", "--exposure", "1e308"], "--exposure"),
    (["render", "m.npz", "--exposure", "-inf"], "--exposure"),
    (["render", "m.npz", "--samples", "1e9"], "--samples"),
    (["render", "m.npz", "--rotate", "1e308"], "--rotate"),
    (["render", "m.npz", "--camera", "0,0,1e308:0,0,0"], "--camera"),
    (["render", "m.npz", "--camera", "0,0,4:0,0,0:0"], "--camera"),
    (["render", "m.npz", "--turntable", "100000", "-o", "spin"], "--turntable"),
    (["render", "m.npz", "--turntable", "3000", "--size", "4096", "-o", "spin"], "--turntable"),
    (["bake", "in.obj", "--bounces", str(2**62)], "--bounces"),
    (["bake", "in.obj", "--indirect-paths", str(2**31)], "--indirect-paths"),
    (["bake", "in.obj", "--seed", str(2**64)], "--seed"),
    (["bake", "in.obj", "--seed", "-1"], "--seed"),
    (["bake", "in.obj", "--memory-gb", "1e308"], "--memory-gb"),
    (["bake", "in.obj", "--memory-gb", "nan"], "--memory-gb"),
    (["bake", "in.obj", "--checkpoint-every", "-inf"], "--checkpoint-every"),
    (["compare", "in.obj", "--spp", str(2**40)], "--spp"),
    (["compare", "in.obj", "--size", "20000x20000"], "--size"),
    (["lobes-demo", "--frames", str(2**40)], "--frames"),
    (["lobes-demo", "--size", "16384"], "--size"),
    (["bench", "prefilter", "--base-res", str(2**40)], "--base-res"),
    (["bench", "lobes", "--repeats", str(2**40)], "--repeats"),
    (["bench", "all", "--budget", "nan"], "--budget"),
    (["gallery", "references", "--size", "65536"], "--size"),
    (["gallery", "references", "--spp", str(2**40)], "--spp"),
    (["gallery", "run", "--base-res", "65536"], "--base-res"),
]


#: A 16384 x 16384 image is too large only where memory cannot hold it.
_FITS_16384 = pytest.mark.skipif(
    _limits.MAX_RENDER_PIXELS >= 16384**2,
    reason="this machine's memory holds a 16384 x 16384 image",
)


@pytest.mark.parametrize(
    ("argv", "flag"),
    [pytest.param(a, f, marks=[_FITS_16384] if "16384" in a else []) for a, f in _TOO_LARGE],
    ids=[" ".join(a) for a, _ in _TOO_LARGE],
)
def test_numeric_flags_out_of_range_are_refused_before_any_work(files, capsys, no_work, argv,
                                                                flag):  # fmt: skip
    refused(capsys, argv, names=flag, problem="", inputs=[files / "m.npz", files / "in.obj"])


def test_size_flags_state_their_maximum_in_their_help(capsys):
    for argv, words in [
        (["render", "--help"], [f"at most {_limits.MAX_BASE_RES}", "megapixels", "(-64..64)"]),
        (["bake", "--help"], ["at most 64", "0..2^63-1", "at most this machine's"]),
        (["gallery", "--help"], ["1..1048576", "at most"]),
    ]:
        with pytest.raises(SystemExit):
            cli.main(argv)
        text = " ".join(capsys.readouterr().out.split())
        for w in words:
            assert w in text, (argv, w)


def test_memory_derived_limits_follow_the_machine():
    # the pixel cap is the memory share over the bytes a pixel takes, the base resolution the
    # largest power of two whose six faces fit it (closed forms of the module's constants)
    budget = _memory.MEMORY_SHARE * _memory.memory_bytes()
    assert _limits.MAX_RENDER_PIXELS == int(
        min(_limits.MAX_SIDE**2, budget // _limits.RENDER_BYTES_PER_PIXEL)
    )
    r = _limits.MAX_BASE_RES
    assert r & (r - 1) == 0
    assert 6 * r * r * _memory.PREFILTER_BYTES_PER_TEXEL <= budget
    assert 6 * (2 * r) ** 2 * _memory.PREFILTER_BYTES_PER_TEXEL > budget


# --------------------------------------------------------------------------------------------
# SIGTERM is never bad input, at every reader


def _terminate(*args, **kwargs):
    """Stands in for a library call inside a reader's ``try``: SIGTERM arrives meanwhile."""
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(5)  # the handler raises Terminated before this ends
    raise AssertionError("SIGTERM was not delivered")


def _gltf_file(d: Path) -> Path:
    mesh = trimesh.creation.icosphere(0)
    mesh.export(d / "a.glb")
    return d / "a.glb"


_READERS = {
    # reader: (patched object, attribute, the command line)
    "mesh": (trimesh, "load_scene", ["bake", "in.obj"]),
    "scene file": (json, "loads", ["bake", "sc.json"]),
    "glTF": (pygltflib.GLTF2, "gltf_from_json", ["bake", "a.glb"]),
    "EXR map": (OpenEXR, "File", ["bake", "in.obj", "--env", "env.exr"]),
    "HDR map": (cv2, "imdecode", ["bake", "in.obj", "--env", "env.hdr"]),
    "model": (np, "load", ["info", "m.npz"]),
}


@pytest.mark.parametrize("reader", list(_READERS))
def test_sigterm_while_a_reader_reads_is_not_bad_input(files, capsys, monkeypatch, no_work,
                                                       reader):  # fmt: skip
    (files / "sc.json").write_text(json.dumps({"mesh": "in.obj"}))
    _gltf_file(files)
    img = np.full((8, 16, 3), 0.5, np.float32)
    OpenEXR.File({"type": OpenEXR.scanlineimage}, {"RGB": img}).write(str(files / "env.exr"))
    obj, attr, argv = _READERS[reader]
    monkeypatch.setattr(obj, attr, _terminate)
    code, _, err = run(capsys, argv)
    assert code == 143, err
    assert err.strip().splitlines()[-1].startswith("lobelight: terminated"), err
    assert "error" not in err and "cannot read" not in err


def test_terminated_is_no_exception():
    # what makes the readers' `except Exception` let it pass
    assert issubclass(Terminated, BaseException) and not issubclass(Terminated, Exception)


def test_render_interrupted_does_not_speak_of_a_bake(files, capsys, monkeypatch):
    def interrupt(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(_commands, "Renderer", interrupt)
    code, _, err = run(capsys, ["render", "m.npz", "-o", "x.png"])
    assert code == 130 and err.strip() == "lobelight: interrupted"


# --------------------------------------------------------------------------------------------
# FIFOs and other non-regular files


def _fifo(path: Path) -> Path:
    os.mkfifo(path)
    return path


class _Hang(BaseException):
    pass


def _within(seconds: float):
    def on_alarm(signum, frame):
        raise _Hang

    signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)


def _no_alarm():
    signal.setitimer(signal.ITIMER_REAL, 0)
    signal.signal(signal.SIGALRM, signal.SIG_DFL)


@pytest.fixture
def deadline():
    """Calls ``deadline(seconds)``: a hang past it raises instead of blocking the run."""
    yield _within
    _no_alarm()


def test_gltf_buffer_uri_naming_a_fifo_is_refused(files, capsys, no_work, deadline):
    mesh = trimesh.creation.icosphere(0)
    doc = json.loads(trimesh.exchange.gltf.export_gltf(mesh)["model.gltf"])
    for b in doc["buffers"]:
        b["uri"] = "pipe.bin"
    (files / "f.gltf").write_text(json.dumps(doc))
    _fifo(files / "pipe.bin")
    deadline(30)
    refused(capsys, ["bake", "f.gltf"], names="pipe.bin", problem="not a regular file",
            inputs=[files / "f.gltf"])  # fmt: skip


def test_an_env_map_that_is_a_fifo_is_said_to_be_one(files, capsys, no_work, deadline):
    _fifo(files / "pipe.hdr")
    deadline(30)
    line = refused(capsys, ["render", "m.npz", "--env", "pipe.hdr"], names="pipe.hdr",
                   problem="not a regular file")  # fmt: skip
    assert "no such file" not in line


def test_a_mesh_that_is_a_fifo_is_said_to_be_one(files, capsys, no_work, deadline):
    _fifo(files / "pipe.obj")
    deadline(30)
    refused(capsys, ["bake", "pipe.obj"], names="pipe.obj", problem="not a regular file")


def test_a_cache_entry_that_is_a_fifo_is_no_regular_entry(tmp_path, deadline):
    deadline(10)
    assert not _cache.regular_entry(_fifo(tmp_path / "entry.npz"))
    assert not _cache.regular_entry(tmp_path / "missing.npz")
    (tmp_path / "ok.npz").write_bytes(b"x")
    assert _cache.regular_entry(tmp_path / "ok.npz")


# --------------------------------------------------------------------------------------------
# the cache's size cap at the door


@pytest.mark.parametrize("value", ["nan", "-inf", "-1", "lots", "1e400x"])
def test_cache_max_mb_that_is_no_size_is_refused_at_the_door(files, capsys, monkeypatch,
                                                             no_work, value):  # fmt: skip
    monkeypatch.setenv("LOBELIGHT_CACHE_MAX_MB", value)
    refused(capsys, ["render", "m.npz", "-o", "x.png"], names="LOBELIGHT_CACHE_MAX_MB",
            problem="inf for no cap")  # fmt: skip


def test_cache_max_mb_inf_renders_without_a_cap(files, capsys, monkeypatch):
    # it used to crash after the work, when the prefilter cache trimmed its folder
    monkeypatch.setenv("LOBELIGHT_CACHE", str(files / "cache"))
    monkeypatch.setenv("LOBELIGHT_CACHE_MAX_MB", "inf")
    argv = ["render", "m.npz", "-o", "x.png", "--size", "16", "-q", "--backend", "torch"]
    code, _, err = run(capsys, [*argv, "--base-res", "32", "--samples", "1"])
    assert code == 0, err
    assert list((files / "cache").rglob("*.npz")), "the chain was cached"


def test_cache_max_mb_inf_means_no_cap(monkeypatch):
    monkeypatch.setenv("LOBELIGHT_CACHE_MAX_MB", "inf")
    assert _cache.cache_max_bytes(2048) == sys.maxsize
    monkeypatch.setenv("LOBELIGHT_CACHE_MAX_MB", "1.5")
    assert _cache.cache_max_bytes(2048) == int(1.5 * 2**20)
    monkeypatch.setenv("LOBELIGHT_CACHE_MAX_MB", "")
    assert _cache.cache_max_bytes(2048) == 2048 * 2**20


# --------------------------------------------------------------------------------------------
# one door for unexpected errors


@pytest.fixture
def a_bug(monkeypatch, tmp_path):
    monkeypatch.setenv("LOBELIGHT_CACHE", str(tmp_path / "cache"))

    def bug(args):
        raise ZeroDivisionError("a bug")

    monkeypatch.setattr(_commands, "run_info", bug)


def test_an_unexpected_error_is_one_line_naming_its_log(files, capsys, a_bug):
    code, out, err = run(capsys, ["info", "m.npz"])
    lines = err.strip().splitlines()
    assert code == 1 and len(lines) == 1, err
    assert "ZeroDivisionError: a bug" in lines[0] and "Traceback" not in err
    log = lines[0].split("the traceback is in ")[1].split(";")[0]
    text = Path(log).read_text()
    assert "Traceback" in text and "ZeroDivisionError" in text and "info m.npz" not in out


def test_an_unexpected_error_under_json_is_a_json_error(files, capsys, a_bug):
    code, out, err = run(capsys, ["info", "m.npz", "--json"])
    doc = json.loads(out)
    assert code == 1 and set(doc) == {"error"} and doc["error"]["code"] == 1
    assert "ZeroDivisionError" in doc["error"]["problem"] and Path(doc["error"]["log"]).is_file()
    assert len(err.strip().splitlines()) == 1


def test_an_unexpected_error_under_debug_prints_its_traceback(files, capsys, a_bug):
    code, _, err = run(capsys, ["info", "m.npz", "--debug"])
    assert code == 1 and "Traceback" in err and err.strip().splitlines()[-1].startswith(
        "lobelight: error: unexpected ZeroDivisionError"
    )  # fmt: skip


# --------------------------------------------------------------------------------------------
# leftovers, escapes, long values


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def _age(path: Path, seconds: float) -> Path:
    t = time.time() - seconds
    os.utime(path, (t, t))
    return path


def test_leftovers_of_a_killed_writer_are_removed_on_the_next_write(tmp_path):
    dead, live = _dead_pid(), os.getppid()
    ages = {
        f".m.npz.p{dead}.abcd1234.partial.npz": 120,  # a dead writer's, idle: removed
        f".m.npz.p{dead}.efgh5678.partial.npz": 0,  # a dead writer's, just written: kept a while
        f".m.npz.p{live}.ijkl9012.partial.npz": 3600,  # a live writer's: kept
        ".pic.png.mnop3456.partial.png": 2 * 86400,  # no pid, abandoned: removed
        ".pic.png.qrst7890.partial.png": 3600,  # no pid, recent: kept
        "notes.partial.txt": 2 * 86400,  # not one of ours: kept
    }
    for name, age in ages.items():
        (tmp_path / name).write_bytes(b"x")
        _age(tmp_path / name, age)
    with _io.atomic_writer(tmp_path / "out.bin") as f:
        f.write(b"whole")
    left = {p.name for p in tmp_path.iterdir()}
    removed = {n for n in ages if n not in left}
    assert removed == {f".m.npz.p{dead}.abcd1234.partial.npz", ".pic.png.mnop3456.partial.png"}
    assert "out.bin" in left


def test_a_killed_render_s_leftover_is_removed_by_the_next_render(files, capsys, monkeypatch):
    monkeypatch.setenv("LOBELIGHT_CACHE", str(files / "cache"))
    left = files / f".x.png.p{_dead_pid()}.abcd1234.partial.png"
    left.write_bytes(b"half an image")
    _age(left, 600)
    argv = ["render", "m.npz", "-o", "x.png", "--size", "16", "-q", "--backend", "torch"]
    code, _, err = run(capsys, [*argv, "--base-res", "32", "--samples", "1"])
    assert code == 0, err
    assert not left.exists() and (files / "x.png").is_file()


def test_info_escapes_terminal_codes_from_the_file(files, capsys):
    _tiny_model(files / "esc.npz", provenance={"scene": "evil\x1b[2J\x1b]0;title\x07name"})
    code, out, err = run(capsys, ["info", "esc.npz"])
    assert code == 0, err
    assert "\x1b" not in out and "\x07" not in out and "\\x1b[2J" in out


def test_a_huge_value_is_shortened_in_its_error_line(files, capsys, no_work):
    camera = ",".join(["1"] * 1_000_000)
    line = refused(capsys, ["render", "m.npz", "--camera", camera], names="--camera",
                   problem="characters left out")  # fmt: skip
    assert len(line) < 5000 and math.isfinite(len(line))


def test_a_symlink_loop_in_a_scene_files_mesh_is_bad_input(tmp_path, capsys, no_work):
    """A scene file whose ``mesh`` is a symbolic link loop: exit 2, one line naming the entry."""
    (tmp_path / "loop1").symlink_to(tmp_path / "loop2")
    (tmp_path / "loop2").symlink_to(tmp_path / "loop1")
    sc = tmp_path / "a.toml"
    sc.write_text('mesh = "loop1"\n')
    refused(capsys, ["bake", sc, "-o", tmp_path / "a.npz"], names="a.toml: mesh",
            problem="cannot resolve", inputs=[sc])  # fmt: skip


def test_a_scene_files_map_that_is_a_fifo_is_named_as_such(tmp_path, capsys, no_work):
    """A scene file's ``environment`` that is a named pipe is reported as not a regular file
    (not as a missing one), before any work and without blocking on the pipe."""
    mesh = tmp_path / "tri.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    os.mkfifo(tmp_path / "sky.hdr")
    sc = tmp_path / "b.toml"
    sc.write_text('mesh = "tri.obj"\nenvironment = "sky.hdr"\n')
    refused(capsys, ["bake", sc, "-o", tmp_path / "b.npz"], names="b.toml: environment",
            problem="not a regular file", inputs=[sc, mesh])  # fmt: skip


# --------------------------------------------------------------------------------------------
# paths the system refuses, folders in the way, values left empty


LONG = "a" * 300  # past every Linux file system's 255-byte name


@pytest.mark.parametrize(
    "argv",
    [
        ["render", "m.npz", "-o", f"{LONG}.png"],
        ["render", "m.npz", "--turntable", "2", "-o", LONG],
        ["export", "m.npz", "--gltf", f"{LONG}.glb"],
        ["export", "m.npz", "--web", LONG],
        ["bake", "in.obj", "-o", f"{LONG}.npz"],
        ["compare", "--model", "m.npz", "-o", LONG],
    ],
)
def test_a_name_too_long_is_bad_input_before_any_work(files, capsys, no_work, argv):
    refused(capsys, argv, names=LONG[:50], problem="file name too long",
            inputs=[files / "m.npz"])  # fmt: skip


@pytest.mark.parametrize(
    "argv",
    [
        ["render", "m.npz", "--turntable", "2", "-o", "{}"],
        ["export", "m.npz", "--web", "{}"],
        ["compare", "--model", "m.npz", "-o", "{}"],
    ],
)
def test_an_output_folder_that_cannot_be_made_is_refused_before_any_work(
    files, capsys, no_work, argv
):
    # a link to nothing, a loop of links, a folder under a file
    (files / "dangling").symlink_to(files / "nothere")
    (files / "loop_a").symlink_to(files / "loop_b")
    (files / "loop_b").symlink_to(files / "loop_a")
    for bad, problem in (("dangling", "symbolic link to nothing"),
                         ("loop_a", "symbolic link to nothing"),
                         ("m.npz/sub", "is a file, not a folder")):  # fmt: skip
        args = [a.replace("{}", bad) for a in argv]
        refused(capsys, args, names=bad, problem=problem, inputs=[files / "m.npz"])


def test_an_output_folder_s_parent_must_be_writable(files, capsys, no_work, monkeypatch):
    # root writes anywhere: a folder not writable is stood in for by os.access
    real = os.access
    ro = str(files / "ro")
    (files / "ro").mkdir()
    monkeypatch.setattr(
        os, "access", lambda p, mode: False if os.path.abspath(p) == ro else real(p, mode)
    )
    for name in ("export_gltf", "export_web"):  # the exports' work, as _WORK's
        monkeypatch.setattr(_commands, name, lambda *a, **k: (_ for _ in ()).throw(WorkStarted))
    for argv in (["export", "m.npz", "--gltf", "ro/x.glb"], ["export", "m.npz", "--web", "ro/w"],
                 ["render", "m.npz", "--turntable", "2", "-o", "ro/t"]):  # fmt: skip
        refused(capsys, argv, names="ro/", problem="is not writable", inputs=[files / "m.npz"])


def test_empty_values_are_refused_not_taken_for_defaults(files, capsys, no_work):
    refused(capsys, ["render", "m.npz", "--env", ""], names="--env", problem="is empty")
    refused(capsys, ["render", "m.npz", "--camera", ""], names="--camera", problem="is empty")
    refused(capsys, ["render", "m.npz", "--env", "."], names=".", problem="is a directory")


def test_render_s_default_output_and_spin_follow_the_turntable(files, capsys, no_work, monkeypatch):
    refused(capsys, ["render", "m.npz", "--spin", "light"], names="--spin",
            problem="give --turntable")  # fmt: skip
    # no -o: render.png, and with --turntable the folder turntable
    chosen = []
    real = _commands._render_outputs

    def outputs(args, width, height):
        chosen.append((args.output, args.spin))
        return real(args, width, height)

    monkeypatch.setattr(_commands, "_render_outputs", outputs)
    for argv in (["render", "m.npz"], ["render", "m.npz", "--turntable", "2"]):
        with pytest.raises(WorkStarted):
            cli.main(argv)
    assert chosen == [("render.png", "camera"), ("turntable", "camera")]


def test_a_bake_s_model_is_an_npz_and_its_checkpoint_a_file(files, capsys, no_work):
    refused(capsys, ["bake", "in.obj", "-o", "x.png"], names="x.png", problem=".npz archive")
    refused(capsys, ["bake", "in.obj", "-o", "out/"], names="out/", problem="is a directory")
    (files / "z.npz.ckpt").mkdir()
    refused(capsys, ["bake", "in.obj", "-o", "z.npz"], names="z.npz.ckpt",
            problem="is not a file")  # fmt: skip


def test_a_usage_error_s_json_names_the_flag(files, capsys):
    code, out, _ = run(capsys, ["render", "m.npz", "--width", "0", "--json"])
    assert code == 2 and json.loads(out)["error"]["input"] == "--width"


def test_a_model_whose_map_moved_is_lit_by_the_bundled_map_of_its_name_or_says_so(files, capsys):
    from lobelight.data import envmap_names

    name = envmap_names()[0]
    moved = str(files / "gone" / f"{name}.hdr")
    assert _commands._env_source(None, {"environment": moved}) == name
    mine = str(files / "gone" / "mine.hdr")
    assert _commands._env_source(None, {"environment": mine}) == "builtin"
    assert _commands._env_source(None, {"environment": mine}) == "builtin"
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2  # each missing map said once
    assert name in err[0] and "bundled map" in err[0]
    assert "mine.hdr" in err[1] and "built-in sky" in err[1]


def test_a_stored_camera_that_is_no_camera_is_said(files, capsys):
    mesh = scene.builtin("sphere", subdivisions=0).mesh
    cam = _commands._camera_from(None, {"camera": {"origin": [0, 0, 0], "target": [0, 0, 0]}},
                                 mesh)  # fmt: skip
    assert cam is not None
    err = capsys.readouterr().err
    assert "the model's camera is not one" in err and "default framing" in err


def test_stale_frames_of_another_turntable_are_refused(tmp_path):
    from lobelight.render._turntable import _output_paths

    out = tmp_path / "tt"
    out.mkdir()
    for k in range(4):
        (out / f"frame_{k:03d}.png").write_bytes(b"")
    paths, _ = _output_paths(out, 4, "frames.gif")  # the same count replaces them all
    assert len(paths) == 4
    with pytest.raises(InputError, match="2 frame\\(s\\) of another turntable"):
        _output_paths(out, 2, "frames.gif")


def test_a_model_too_small_or_too_large_to_render_is_refused_on_read(tmp_path):
    for scale in (1e-15, 1e30):
        path = _tiny_model(tmp_path / "m.npz")
        with np.load(path) as z:
            arrays = dict(z)
        arrays["vertices"] = arrays["vertices"] * np.float32(scale)
        np.savez(tmp_path / "s.npz", **arrays)
        with pytest.raises(InputError, match=r"outside 1e-06\.\.1e\+09"):
            model.load(tmp_path / "s.npz")


def test_view_web_checks_a_size_it_is_given(files, capsys, no_work):
    # the page takes the browser's size, but a size given must still be one
    refused(capsys, ["view", "--web", "m.npz", "--size", "0"], names="--size", problem="1..")
    refused(capsys, ["view", "--web", "m.npz", "--size", "junk"], names="--size",
            problem="expected N or WxH")  # fmt: skip


def test_view_opens_with_the_camera_render_takes_and_says_a_damaged_one(files, capsys, monkeypatch):
    seen = []
    monkeypatch.setattr(_commands, "require_display", lambda: None)
    monkeypatch.setattr(_commands, "view", lambda m, **kw: seen.append(kw["camera"]) or {})
    good = {"origin": [0.0, 1.0, 4.0], "target": [0.0, 0.0, 0.0], "fov": 35.0}
    bad = {"origin": [0.0, 0.0, 0.0], "target": [0.0, 0.0, 0.0], "fov": 35.0}
    for name, cam in (("good.npz", good), ("bad.npz", bad)):
        _tiny_model(files / name, provenance={"scene": "s", "camera": cam})
        assert cli.main(["view", name]) == 0
    assert seen[0].origin == (0.0, 1.0, 4.0) and seen[0].fov == 35.0
    mesh = model.load(files / "bad.npz").mesh
    assert seen[1] == scene.default_camera(mesh)
    assert "the model's camera is not one" in capsys.readouterr().err
