"""What a new user meets first: progress on any stream, errors as one line (and as JSON under
``--json``), flags that parse as written, inputs checked before work, help for every flag."""

from __future__ import annotations

import argparse
import io
import json

import pytest

from lobelight import cli, progress
from lobelight.cli import _commands, main


class _Clock:
    def __init__(self):
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


def test_progress_off_a_terminal_is_plain_lines_at_most_every_interval(monkeypatch):
    """On a stream that is not a terminal: a line when a stage starts, at most one per
    ``interval`` while it runs, one when it ends (with its time); no bar escape codes."""
    clock = _Clock()
    monkeypatch.setattr(progress.time, "monotonic", clock)
    out = io.StringIO()
    rep = progress.Reporter(out, interval=5.0)
    for done in range(1, 101):  # 100 chunks, 0.2 s apart: 20 s in all
        clock.t += 0.2
        rep("fit", done, 100)
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("lobelight: fit: 1/100 chunks")
    assert lines[-1].startswith("lobelight: fit: 100/100 chunks (100 %), done in")
    # 20 s at one line per 5 s: the first, three in between (at 5, 10, 15 s), the last
    assert 4 <= len(lines) <= 6, lines
    assert "\r" not in out.getvalue() and "\x1b" not in out.getvalue()
    # a stage that starts later reports from its own start
    rep("relax", 0, 3)
    assert out.getvalue().splitlines()[-1] == "lobelight: relax: 0/3 chunks (0 %)"


def test_progress_of_a_stage_with_a_bound_promises_no_share_or_time_left(monkeypatch):
    """The reordering's sweeps are counted against a bound it rarely reaches: its lines say
    "of at most" and give no share or time left, and its end says the sweeps it made."""
    clock = _Clock()
    monkeypatch.setattr(progress.time, "monotonic", clock)
    out = io.StringIO()
    rep = progress.Reporter(out, interval=5.0)
    for done in range(1, 4):
        clock.t += 6.0
        rep("reorder", done, 64)
    rep("reorder", 4, 4)
    lines = out.getvalue().splitlines()
    assert lines[0] == "lobelight: reorder: sweep 1 of at most 64"
    assert lines[1] == "lobelight: reorder: sweep 2 of at most 64, 6 s elapsed"
    assert lines[-1] == "lobelight: reorder: 4 sweeps, done in 12.0 s"
    assert "%" not in out.getvalue() and "left" not in out.getvalue()


def test_progress_counts_samples_per_pixel_as_spp(monkeypatch):
    monkeypatch.setattr(progress.time, "monotonic", _Clock())
    out = io.StringIO()
    progress.Reporter(out)("reference", 64, 64)
    assert out.getvalue().startswith("lobelight: reference: 64/64 spp (100 %), done in")


def test_progress_argument_forms():
    assert progress.resolve(None) is None and progress.resolve(False) is None
    assert isinstance(progress.resolve(True), progress.Reporter)
    fn = lambda *a: None  # noqa: E731
    assert progress.resolve(fn) is fn
    with pytest.raises(TypeError, match="progress"):
        progress.resolve("yes")


def test_the_bake_reports_progress_without_a_terminal(capsys):
    """The API's default: plain lines on stderr (pytest's capture is not a terminal)."""
    from lobelight import fit, scene

    fit.fit_model(scene.builtin("sphere", subdivisions=0), 1)
    err = capsys.readouterr().err
    assert "lobelight: fit:" in err and "done in" in err


def _json_error(capsys, argv) -> tuple[int, dict, list[str]]:
    code = main([*argv, "--json"])
    cap = capsys.readouterr()
    return code, json.loads(cap.out), cap.err.strip().splitlines()


@pytest.mark.parametrize(
    "argv, what",
    [
        (["info", "missing.npz"], "missing.npz"),
        (["render", "missing.npz", "--exposure", "abc"], "--exposure"),
        (["render", "missing.npz", "--exposure", "nan"], "--exposure"),
        (["render", "missing.npz", "--rotate", "nan"], "--rotate"),
        (["info", "missing.npz", "--device", "bogus"], "--device"),
        (["bake", "sphere:1", "--indirect-paths", "-1"], "--indirect-paths"),
        (["render", "missing.npz", "--size", "12x"], "--size"),
    ],
)
def test_errors_under_json_are_json_on_stdout_and_one_line_on_stderr(capsys, argv, what):
    code, out, err = _json_error(capsys, argv)
    assert code == 2 and out["error"]["code"] == 2
    assert what in out["error"]["input"] + out["error"]["problem"]
    assert len(err) == 1 and err[0].startswith("lobelight: error:") and what in err[0]


def test_a_command_line_argparse_rejects_is_bad_input_too(capsys):
    code, out, err = _json_error(capsys, ["render"])  # the model is missing
    assert code == 2 and "model" in out["error"]["problem"]
    assert len(err) == 1 and err[0].startswith("lobelight: error:")
    assert main(["render", "m.npz", "--no-such-flag"]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_cuda_without_cuda_is_bad_input(capsys):
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    assert main(["render", "missing.npz", "--device", "cuda"]) == 2
    assert "CUDA" in capsys.readouterr().err


def test_info_on_a_mesh_says_it_is_not_a_model(tmp_path, capsys):
    mesh = tmp_path / "mesh.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    assert main(["info", str(mesh)]) == 2
    err = capsys.readouterr().err
    assert "not a lobelight model" in err and "bake" in err and "pickle" not in err


def test_a_camera_below_the_origin_parses():
    """``--camera -1.6,0.7,-2.6:0,0,0`` (argparse would read the value as an option)."""
    argv = cli._join_signed(["render", "m.npz", "--camera", "-1.6,0.7,-2.6:0,0,0:35",
                             "--rotate", "-30"])  # fmt: skip
    args = cli._parser().parse_args(argv)
    assert args.camera == "-1.6,0.7,-2.6:0,0,0:35" and args.rotate == -30.0
    cam = _commands._camera_from(args.camera, {}, None)
    assert cam.origin == pytest.approx((-1.6, 0.7, -2.6)) and cam.fov == pytest.approx(35)


def test_bake_checks_its_output_before_any_work(tmp_path, capsys, monkeypatch):
    """A missing folder or a folder as the model path: exit 2 before the transport runs."""
    from lobelight import fit

    def no_fit(*a, **k):
        raise AssertionError("the fit ran before the output was checked")

    monkeypatch.setattr(fit, "fit_model", no_fit)
    for out in (tmp_path / "missing" / "m.npz", tmp_path):
        assert main(["bake", "sphere:1", "-o", str(out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and str(out) in err[0]
    assert not list(tmp_path.iterdir())  # nothing half-written


def _subparsers():
    p = cli._parser()
    sub = next(a for a in p._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices


def test_every_flag_has_help_text():
    for name, sp in _subparsers().items():
        for action in sp._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            assert action.help, f"lobelight {name}: {action.option_strings or action.dest}"


def test_flag_names_are_shared_across_commands():
    """The same option means the same thing everywhere, under one name."""
    cmds = _subparsers()
    for name, sp in cmds.items():
        opts = {o for a in sp._actions for o in a.option_strings}
        assert {"--json", "--quiet"} <= opts, name
        # --device where there is heavy work to place, --rays where it casts rays; nowhere else
        heavy = name not in ("info", "view", "figure5")
        assert ("--device" in opts) == heavy, name
        assert ("--rays" in opts) == (heavy and name != "compare-brdf"), name  # a closed form
        if "--output" in opts:
            assert {"-o", "--output"} <= opts, name
        assert not {"--out", "--ref-spp", "--lobes"} & opts, name
        assert "--no-sun" not in opts or "--sun" in opts, name
    args = cli._parser().parse_args(["compare-brdf", "--output", "x", "--spp", "8"])
    assert args.output == "x" and args.spp == 8
    args = cli._parser().parse_args(["bench", "render", "--sun"])
    assert args.sun is True
    with pytest.raises(cli._UsageError):  # --gaussians is 1-3 everywhere
        cli._parser().parse_args(["bench", "fit", "--gaussians", "5"])


@pytest.fixture(scope="module")
def tiny_model(tmp_path_factory):
    from lobelight import fit, scene

    path = tmp_path_factory.mktemp("model") / "m.npz"
    fit.fit_model(scene.builtin("sphere", subdivisions=0), 1, progress=None).save(path)
    return path


def test_render_checks_its_output_before_rendering(tiny_model, tmp_path, capsys, monkeypatch):
    from lobelight import render

    def no_render(*a, **k):
        raise AssertionError("rendered before the output was checked")

    monkeypatch.setattr(render.Renderer, "__init__", no_render)
    for out in (tmp_path / "x.bmp", tmp_path / "missing" / "x.png", tmp_path):
        assert main(["render", str(tiny_model), "-o", str(out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and str(out) in err[0]


def test_render_writes_jpeg_and_a_turntable(tiny_model, tmp_path, capsys):
    from PIL import Image

    small = ["--size", "40x30", "--base-res", "32", "--backend", "torch"]
    jpg = tmp_path / "r.jpg"
    assert main(["render", str(tiny_model), "-o", str(jpg), *small, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["output"] == str(jpg)
    assert Image.open(jpg).format == "JPEG" and Image.open(jpg).size == (40, 30)
    frames = tmp_path / "spin"
    argv = ["render", str(tiny_model), "-o", str(frames), "--turntable", "3", *small, "--json"]
    assert main(argv) == 0
    capsys.readouterr()
    assert len(list(frames.glob("frame_*.png"))) == 3
    gif = Image.open(frames / "frames.gif")
    assert gif.n_frames == 3


def test_quiet_is_offered_only_where_there_is_progress_to_quiet(tiny_model, capsys):
    """-q is accepted by every command (a script may pass it to each), and shown in the help of
    those that report progress only; a flag that does nothing for a command is not offered."""
    for name in ("info", "export", "view", "figure5", "compare-brdf"):
        assert "--quiet" not in _subparsers()[name].format_help(), name
    for name in ("bake", "render", "compare", "demo", "bench"):
        assert "--quiet" in _subparsers()[name].format_help(), name
    assert main(["info", str(tiny_model), "-q", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["command"] == "info"
    # the bench's options say which benchmark reads them
    bench = " ".join(_subparsers()["bench"].format_help().split())
    for flag in ("fit: Gaussians", "fit: the bake's memory", "prefilter: face resolution",
                 "render: renderer", "render: anti-aliasing", "render: shade the map's sun",
                 "--device is used by all, prefilter"):  # fmt: skip
        assert flag in bench, flag


def test_compare_refuses_gaussians_it_would_not_use(tiny_model, capsys):
    # with --model the model's own Gaussians are scored: a --gaussians would be ignored
    assert main(["compare", "--model", str(tiny_model), "--gaussians", "2"]) == 2
    err = capsys.readouterr().err
    assert "--gaussians" in err and "without --model" in err


def test_every_flag_s_help_shows_its_default():
    """Each option's help says its default: the formatter adds it where there is one (a
    boolean pair names the flag that is on, a switch says it is off), and an option without
    one says what happens."""
    from lobelight.cli._arguments import _Help

    plain = (argparse._HelpAction, argparse._VersionAction)
    for name, sp in _subparsers().items():
        fmt = _Help(sp.prog)
        for action in sp._actions:
            if not action.option_strings or isinstance(action, plain):
                continue
            text = fmt._get_help_string(action) or ""
            assert "default" in text, f"lobelight {name} {action.option_strings[0]}: {text!r}"
    render = _subparsers()["render"].format_help()
    assert "vertical axis" in render and "(default: 0.0)" in render  # --rotate: axis, default
    assert "(errors too, as JSON) (default: off)" in " ".join(render.split())  # a switch


def test_the_gitignore_keeps_the_readme_s_outputs_out_of_git():
    """What the README's commands write in a clone (the demo's and compare's folders, models)
    is ignored; asked of git itself where the tests run in a work tree."""
    import shutil
    import subprocess
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    paths = ["lobelight-demo/report.md", "lobelight-compare/compare.json", "spot.npz",
             "examples/gold.npz", "render.png", "turntable/frame_000.png"]  # fmt: skip
    if shutil.which("git") is None or not (root / ".git").exists():
        text = (root / ".gitignore").read_text()
        assert {
            "/lobelight-demo/",
            "/lobelight-compare/",
            "*.npz",
            "/render.png",
            "/turntable/",
        } <= set(text.split())
        return
    for path in paths:
        r = subprocess.run(["git", "check-ignore", "-q", path], cwd=root, check=False)
        assert r.returncode == 0, f"{path} is not ignored"
    r = subprocess.run(["git", "check-ignore", "-q", "README.md"], cwd=root, check=False)
    assert r.returncode == 1  # and the sources are not


def test_a_fall_back_to_the_torch_renderer_is_said_in_one_line(monkeypatch, capsys):
    monkeypatch.setattr(_commands, "gl_available", lambda: False)
    assert _commands._backend("auto") == "torch"
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "torch renderer" in err[0] and "EGL" in err[0]
    assert _commands._backend("torch") == "torch"  # asked for: nothing to say
    assert _commands._backend("gl") == "gl"
    assert capsys.readouterr().err == ""


def test_an_unknown_map_name_lists_the_bundled_maps(capsys):
    from lobelight.data import envmap_names

    assert main(["bake", "sphere:1", "--env", "park"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "park" in err[0] and "no such file" in err[0]
    assert envmap_names() and all(n in err[0] for n in envmap_names())


def test_a_diffuse_model_reports_no_gaussians_and_no_glossy_paths(tmp_path, capsys):
    from lobelight import fit, scene

    path = tmp_path / "d.npz"
    sc = scene.load("sphere:0", material="diffuse:color=0.7")
    fit.fit_model(sc, 1, bounces=1, progress=None).save(path)
    assert main(["info", str(path), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["n_gaussians"] == 0 and info["indirect_gaussians"] == 0
    # the diffuse bounce applies and is reported; glossy paths do not
    assert info["interreflection"] == {"bounces": 1, "indirect_paths": 0}


def test_the_bake_s_fit_error_comes_with_a_hint():
    assert "0 is exact" in _commands._ERROR_HINT and "compare" in _commands._ERROR_HINT


def test_gallery_list_fits_a_terminal(capsys):
    assert main(["gallery", "list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) > 10 and max(map(len, lines)) <= 120
    assert main(["gallery", "list", "--json"]) == 0  # every field under --json
    scenes = json.loads(capsys.readouterr().out)["scenes"]
    assert {"name", "mesh", "envmap", "material", "description"} <= set(scenes[0])
