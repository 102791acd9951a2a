"""The command line end to end on a small built-in scene: bake -> info -> render -> compare."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import torch
from PIL import Image

from lobelight import cli
from lobelight.cli import main


def run(capsys, *argv) -> tuple[int, dict]:
    code = main([*map(str, argv), "--json"])
    out = capsys.readouterr().out
    return code, (json.loads(out) if code == 0 else {})


def test_bake_info_render_compare(tmp_path, capsys):
    import cv2

    model = tmp_path / "s.npz"
    env = tmp_path / "sky.hdr"  # the model's default lighting, given to the bake
    sky = np.random.default_rng(0).uniform(0.1, 2.0, (16, 32, 3)).astype(np.float32)
    assert cv2.imwrite(str(env), sky)
    code, bake = run(capsys, "bake", "sphere:1", "--env", env, "-o", model)
    assert code == 0 and model.is_file()
    assert not list(tmp_path.glob("*.ckpt*"))  # the checkpoint is gone once the model is whole
    assert {"model", "vertices", "bytes", "relative_l2_error_mean", "seconds"} <= set(bake)
    assert bake["vertices"] == 42 and bake["bytes"] == model.stat().st_size
    assert bake["refinement"] == "none needed (42 vertices as given)"
    assert bake["environment"] == str(env.resolve())

    code, info = run(capsys, "info", model)
    assert code == 0 and info["vertices"] == 42 and info["views"] == 92
    # a convex sphere's edges see the same sky at both ends: the bake kept its mesh
    assert info["refinement"] == "none needed (42 vertices as given)"
    # the built-in sphere is a GGX alpha 0.1 metal-like lobe: --gaussians auto (the default)
    # gives it two, and info says why
    assert info["n_gaussians"] == 2 and info["provenance"]["scene"] == "sphere1"
    assert info["n_gaussians_choice"]["asked"] == "auto"
    assert "alpha 0.103" in info["n_gaussians_choice"]["reason"]
    # GGX alpha 0.1 is wider than a lobe shaded per pixel: the fitted Gaussians shade it
    assert info["reflection"] == "fitted Gaussians"
    assert info["provenance"]["environment"] == str(env.resolve())
    # what was baked of interreflection: the defaults
    assert (
        info["interreflection"] == {"bounces": 4, "indirect_paths": 16} == bake["interreflection"]
    )

    png = tmp_path / "r.png"
    code, r = run(
        capsys, "render", model, "-o", png, "--width", 40, "--height", 30, "--base-res", 32
    )
    assert code == 0 and r["output"] == str(png)
    assert r["environment"] == str(env.resolve())  # the bake's, without --env
    img = np.asarray(Image.open(png))
    assert img.shape == (30, 40, 3) and img.std() > 5  # a picture, not a flat fill
    exr = tmp_path / "r.exr"
    code, _ = run(
        capsys,
        "render",
        model,
        "-o",
        exr,
        "--width",
        40,
        "--height",
        30,
        "--base-res",
        32,
        "--backend",
        "torch",
        "--rotate",
        45,
    )
    assert code == 0 and exr.stat().st_size > 0

    out = tmp_path / "cmp"
    code, c = run(
        capsys,
        "compare",
        "sphere:1",
        "--model",
        model,
        "--width",
        32,
        "--height",
        24,
        "--spp",
        4,
        "--baselines",
        "linear",
        "--base-res",
        32,
        "--out",
        out,
        "--env",  # the model's map (its default) is a random sky without a sun; this has one
        "builtin",
    )
    assert code == 0 and c["environment"] == "builtin" and c["material"] == "ggx"
    assert {"table", "reference_noise", "images", "seconds", "object_pixels", "sun"} <= set(c)
    assert all({"psnr", "psnr_display", "rel_l2"} <= set(row) for row in c["table"])
    methods = {(row["method"], row["component"]) for row in c["table"]}
    assert methods == {
        ("ours", "full"),
        ("ours", "glossy"),
        ("ours_sh_diffuse", "full"),  # the sun in the SH diffuse: the paper's diffuse term
        ("linear", "full"),
        ("linear", "glossy"),
    }
    for row in c["table"]:
        assert np.isfinite(row["psnr"]) and row["rel_l2"] >= 0
    saved = json.loads((out / "compare.json").read_text())
    assert saved["table"] == c["table"]
    for p in c["images"].values():
        assert Image.open(p).size == (32, 24)


@pytest.mark.parametrize(
    "argv, what",
    [
        (["bake", "no/such/mesh.ply"], "no/such/mesh.ply"),
        (["bake", "sphere:1", "--env", "no/such/sky.hdr"], "no/such/sky.hdr"),
        (["info", "missing.npz"], "missing.npz"),
        (["render", "missing.npz"], "missing.npz"),
        (["view", "missing.npz"], "view"),
    ],
)
def test_bad_input_exits_2_with_one_line(capsys, tmp_path, monkeypatch, argv, what):
    monkeypatch.chdir(tmp_path)  # relative paths (and any default output) land in tmp_path
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and what in err[0] and err[0].startswith("lobelight: error:")


def test_render_rejects_a_bad_camera(tmp_path, capsys, monkeypatch):
    from lobelight import fit, scene

    monkeypatch.chdir(tmp_path)  # render's default output would go to the working folder
    m = fit.fit_model(scene.builtin("sphere", subdivisions=0), 1)
    m.save(tmp_path / "m.npz")
    assert main(["render", str(tmp_path / "m.npz"), "--camera", "1,2:3"]) == 2
    assert "--camera" in capsys.readouterr().err


def test_a_reader_that_stops_early_is_not_an_error(tmp_path):
    # `lobelight info m.npz | head -1`: the pipe closes before the summary is written; the CLI
    # exits 0 without a traceback (it used to die with BrokenPipeError, exit 1)

    from lobelight.bench import synthetic_model

    path = tmp_path / "m.lobelight.npz"
    synthetic_model(200, 1).save(path)
    code = "import sys; from lobelight.cli import main; sys.exit(main(sys.argv[1:]))"
    p = subprocess.Popen(
        [sys.executable, "-c", code, "info", str(path), "--json"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        cwd=tmp_path,
    )
    p.stdout.close()  # the reader is gone before anything is written
    err = p.stderr.read().decode()
    assert p.wait(timeout=120) == 0, err
    assert "Traceback" not in err


def test_reference_reports_progress_per_batch():
    """The path tracer's ``progress`` (the CLI's bars for compare and demo) follows its batches
    of samples, and changes no sample."""
    from lobelight import scene
    from lobelight.reference import paths as reference

    sc = scene.builtin("sphere", subdivisions=0)
    calls = []
    kw = dict(width=12, height=9, spp=5, batch_spp=2, seed=3)
    img = reference.render(sc, progress=lambda *a: calls.append(a), **kw)
    assert calls == [("reference", 2, 5), ("reference", 4, 5), ("reference", 5, 5)]
    assert torch.equal(img, reference.render(sc, **kw))


def test_the_bake_flags_default_to_the_bake_s_interreflection():
    # the parser restates the defaults so that building it imports no torch
    from lobelight import fit, transport

    args = cli._parser().parse_args(["bake", "sphere:1"])
    assert args.bounces == transport.BOUNCES and args.indirect_paths == transport.INDIRECT_PATHS
    assert args.refine == fit.REFINE_ROUNDS


def test_base_res_auto_is_the_default_where_a_model_is_rendered():
    # the help states auto's range, restated so that building the parser imports no torch
    from lobelight import render
    from lobelight.cli._arguments import AUTO_BASE_RES_RANGE

    assert AUTO_BASE_RES_RANGE == (render.AUTO_BASE_RES_MIN, render.AUTO_BASE_RES_MAX)
    p = cli._parser()
    for argv in (["render", "m.npz"], ["compare", "s.toml"], ["gallery", "run"]):
        assert p.parse_args(argv).base_res == "auto"
    assert p.parse_args(["render", "m.npz", "--base-res", "512"]).base_res == 512


def test_sigterm_ends_a_bake_like_ctrl_c(tmp_path):
    """Batch schedulers stop jobs with SIGTERM: one line and exit 143, unwound like Ctrl-C (not a
    silent death of the process), and nothing half-written is left."""
    import signal

    out = tmp_path / "knot.npz"
    code = "import sys; from lobelight.cli import main; sys.exit(main(sys.argv[1:]))"
    # the mesh as it is (--refine 0): the fit's first chunk comes 6-7 s sooner, and the signal
    # still arrives mid-fit, after that chunk
    cmd = [sys.executable, "-c", code, "bake", "knot", "-o", str(out), "--refine", "0"]
    p = subprocess.Popen(cmd, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, cwd=tmp_path)
    lines = []
    for raw in p.stderr:  # plain progress lines: wait until the fit has done some chunks
        lines.append(raw.decode().rstrip())
        if "fit:" in lines[-1] and "chunks" in lines[-1]:
            break
    p.send_signal(signal.SIGTERM)
    rest = p.stderr.read().decode().splitlines()
    assert p.wait(timeout=120) == 143, "\n".join(lines + rest)
    assert rest[-1] == "lobelight: terminated (a bake resumes when run again)"
    assert not any("Traceback" in x for x in rest)
    assert not out.exists() and not list(tmp_path.glob("*.partial*"))


def test_a_truncated_exr_leaves_stdout_to_the_json(tmp_path, capfd, monkeypatch):
    # OpenEXR prints a warning on stdout and another on stderr when a file is cut short: under
    # --json stdout must hold the JSON alone, and the library's words go into our one line
    import OpenEXR

    monkeypatch.chdir(tmp_path)
    img = np.random.default_rng(0).random((64, 128, 3), dtype=np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, {"RGB": img}).write(str(tmp_path / "full.exr"))
    data = (tmp_path / "full.exr").read_bytes()
    (tmp_path / "cut.exr").write_bytes(data[: len(data) * 6 // 10])
    assert main(["bake", "sphere:1", "--env", "cut.exr", "--json", "-q"]) == 2
    out, err = capfd.readouterr()
    doc = json.loads(out)  # the whole of stdout is one JSON document
    assert "cut.exr" in json.dumps(doc) and "OpenEXR" in json.dumps(doc)
    lines = err.strip().splitlines()  # one line, ours, with the library's words inside it
    assert len(lines) == 1 and lines[0].startswith("lobelight: error: cut.exr")


def test_help_and_parsing_load_no_torch():
    """The parser is built and a line parsed without torch: ``--help`` and a usage error answer
    at once; the commands load after parsing."""
    code = (
        "import sys; from lobelight import cli; cli._parser().parse_args(['bake', 'x']); "
        "print('torch' in sys.modules, 'lobelight.cli._commands' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"]


def test_a_usage_error_quoting_control_characters_stays_one_line(capsys):
    """argparse quotes unrecognised arguments: a group separator or carriage return in one
    split the error over lines (the long fuzz run found it); they are escaped."""
    assert main(["figure5", "x", "--parts", "6\x1d\r2"]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "\\x1d" in err


def test_view_reads_every_map_at_the_door(tmp_path, capsys, monkeypatch):
    # no window here: the display check and the window stand in; what view is given is the
    # maps, each read before the window would open, in the order given
    from lobelight import fit, scene
    from lobelight.cli import _commands

    m = fit.fit_model(scene.builtin("sphere", subdivisions=0), 1)
    m.save(tmp_path / "m.npz")
    seen = {}
    monkeypatch.setattr(_commands, "require_display", lambda: None)

    def window(model, env, **kw):
        seen["env"] = env
        return {"command": "view", "frames": 0}

    monkeypatch.setattr(_commands, "view", window)
    hdr = tmp_path / "sky.hdr"
    from lobelight import envmap

    envmap.save(envmap.builtin(height=16), hdr)
    assert main(["view", str(tmp_path / "m.npz"), "--env", "builtin", "--env", str(hdr)]) == 0
    assert [e.name for e in seen["env"]] == ["builtin-sky", str(hdr)]
    seen.clear()
    assert main(["view", str(tmp_path / "m.npz")]) == 0  # the model's map alone
    assert len(seen["env"]) == 1
    seen.clear()
    bad = ["view", str(tmp_path / "m.npz"), "--env", "builtin", "--env", "no/such/sky.hdr"]
    assert main(bad) == 2
    assert "no/such/sky.hdr" in capsys.readouterr().err and not seen
