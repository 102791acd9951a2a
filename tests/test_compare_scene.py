"""``lobelight compare`` scores the scene a model was baked from: the model's material, map and
camera by default, a mismatched scene refused (or scored as given with ``--allow-mismatch``),
the paper's costly baselines only when asked, every stage under a name, and the plan with its
expected seconds said before the reference starts."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from lobelight import cli, fit, scene
from lobelight.cli import _commands, main
from lobelight.studies import compare as compare_mod

#: The copper of the scenario: a bare mesh baked with a material other than its default.
COPPER = "ggx:alpha=0.05,specular=0.9,0.5,0.3"


@pytest.fixture(scope="module")
def copper(tmp_path_factory):
    """A model of the built-in sphere (42 vertices) baked in copper, direct light only (fast)."""
    sc = scene.load("sphere:1", material=COPPER)
    path = tmp_path_factory.mktemp("copper") / "copper.npz"
    fit.fit_model(sc, 1, indirect_paths=0, bounces=0, progress=None).save(path)
    return path


@pytest.fixture
def scored(monkeypatch):
    """Stands in for the comparison: records the scene and arguments it was given."""
    calls = []

    def fake(sc, **kw):
        calls.append((sc, kw))
        return {"table": []}

    monkeypatch.setattr(_commands, "compare", fake)
    return calls


def _same(a, b) -> bool:
    return _commands._same_materials(a, b)


def _obj(path, scale: float = 1.0):
    """The built-in sphere's mesh as an OBJ file (its vertices scaled by ``scale``)."""
    sc = scene.load("sphere:1")
    v = (sc.mesh.vertices.cpu() * scale).tolist()
    f = (sc.mesh.faces.cpu() + 1).tolist()
    path.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in v)
                    + "".join(f"f {a} {b} {c}\n" for a, b, c in f))  # fmt: skip
    return path


def test_a_scene_of_another_material_is_refused(copper, scored, capsys):
    # the built-in sphere's own material is GGX alpha 0.1, grey: not the copper it was baked in
    assert main(["compare", "sphere:1", "--model", str(copper)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "sphere:1" in err[0] and "material" in err[0]
    assert "--allow-mismatch" in err[0]
    assert not scored  # refused before any rendering


def test_the_model_s_own_scene_is_scored_by_default(copper, scored):
    ref = scene.load("sphere:1", material=COPPER)
    assert main(["compare", "--model", str(copper), "--spp", "4"]) == 0
    ((sc, kw),) = scored
    assert _same(sc.materials, ref.materials) and sc.materials.model == "ggx"
    assert torch.equal(sc.mesh.vertices.cpu(), ref.mesh.vertices.cpu())
    assert sc.camera.to_dict() == ref.camera.to_dict()  # the camera the bake recorded
    assert kw["baselines"] == ("linear",)  # the costly baselines only when asked


def test_a_bare_mesh_takes_the_model_s_material(copper, scored, tmp_path):
    """The issue's scenario: ``compare mesh.obj --model copper.npz`` path-traced the bare
    mesh's default grey; a bare mesh brings only its mesh, so the copper is scored."""
    sc = scene.load("sphere:1")
    mesh = _obj(tmp_path / "sphere.obj")
    assert main(["compare", str(mesh), "--model", str(copper), "--spp", "4"]) == 0
    ((got, _),) = scored
    assert _same(got.materials, scene.load("sphere:1", material=COPPER).materials)
    assert not _same(got.materials, sc.materials)


def test_allow_mismatch_scores_the_scene_as_given(copper, scored, capsys):
    assert main(["compare", "sphere:1", "--model", str(copper), "--allow-mismatch"]) == 0
    ((got, _),) = scored
    assert _same(got.materials, scene.load("sphere:1").materials)
    assert "--allow-mismatch" in capsys.readouterr().err


def test_a_scene_file_of_another_map_is_refused(copper, scored, tmp_path, capsys):
    _obj(tmp_path / "sphere.obj")
    toml = tmp_path / "s.toml"
    toml.write_text(  # the copper the model holds, under another map
        'mesh = "sphere.obj"\nenvironment = "rooitou_park_512"\n[material]\nmodel = "ggx"\n'
        "alpha = 0.05\nspecular = [0.9, 0.5, 0.3]\n"
    )
    err_free = scene.load(str(toml))
    assert _same(err_free.materials, scene.load("sphere:1", material=COPPER).materials)
    assert main(["compare", str(toml), "--model", str(copper)]) == 2
    assert "map" in capsys.readouterr().err and not scored


def test_another_mesh_of_the_same_size_is_refused(copper, scored, tmp_path, capsys):
    mesh = _obj(tmp_path / "big.obj", scale=1.5)  # same count, other positions
    assert main(["compare", str(mesh), "--model", str(copper)]) == 2
    assert "vertex positions" in capsys.readouterr().err and not scored


def test_materials_compare_within_half_float_rounding():
    a = scene.load("sphere:1", material=COPPER).materials
    # half floats keep 11 bits: a round trip through float16 is the same material ...
    half = dataclasses.replace(a, diffuse=a.diffuse.half().float())
    assert _same(a, half)
    # ... and a specular of 0.9 against 0.85 is not
    assert not _same(a, scene.load("sphere:1", material=COPPER.replace("0.9", "0.85")).materials)


class _Recorder:
    """A progress callable with a ``note``, as the command line's reporter."""

    def __init__(self):
        self.events = []

    def __call__(self, stage, done, total):
        self.events.append(("stage", stage))

    def note(self, text):
        self.events.append(("note", text))


def test_every_stage_is_named_and_the_plan_said_before_the_reference(copper):
    from lobelight import model

    m = model.load(copper)
    sc = scene.load("sphere:1", material=COPPER)
    rec = _Recorder()
    compare_mod.compare(sc, model=m, width=16, height=12, spp=2, base_res=32, backend="torch",
                        baselines=("linear", "sh10"), progress=rec)  # fmt: skip
    notes = [i for i, e in enumerate(rec.events) if e[0] == "note"]
    first_ref = next(i for i, e in enumerate(rec.events) if e == ("stage", "reference"))
    assert notes and notes[0] < first_ref  # the plan, before the path tracer starts
    text = rec.events[notes[0]][1]
    assert "the reference" in text and "sh10 baseline: gathers the transport" in text
    stages = {e[1] for e in rec.events if e[0] == "stage"}
    assert stages == {"reference", "reference, glossy", "sh10 baseline: transport"}


def test_the_forecast_times_the_reference_on_its_first_batches(monkeypatch):
    """Set-up 3 s, then 0.5 s per sample per pixel: two images of 100 spp are 2 x (3 + 50) s,
    plus the 10 s of the other stages; said once, at the second batch (past a sixteenth of
    the samples)."""
    clock = iter([0.0, 3.0 + 10 * 0.5, 3.0 + 20 * 0.5, 3.0 + 30 * 0.5])
    monkeypatch.setattr(compare_mod.time, "perf_counter", lambda: next(clock))
    rec = _Recorder()
    f = compare_mod._Forecast(rec, rec.note, 100, 10.0)
    for done in (10, 20, 30):
        f("reference", done, 100)
    notes = [e[1] for e in rec.events if e[0] == "note"]
    assert len(notes) == 1 and "expected about 116 s in all" in notes[0]
    assert "the reference about 106 s" in notes[0]


def test_the_parser_s_baselines_default_to_the_cheap_one():
    args = cli._parser().parse_args(["compare", "--model", "m.npz"])
    assert args.baselines == ["linear"] and args.scene is None
    assert compare_mod.compare.__kwdefaults__["baselines"] == ("linear",)
