"""The scene-file format: its documentation, the examples, one-line material specs and bundled
environment names."""

from __future__ import annotations

import dataclasses
import inspect
import json
import re
from pathlib import Path

import pytest
import torch

from lobelight import brdf, data, scene
from lobelight.errors import InputError
from lobelight.geometry.camera import Camera

try:
    import tomllib
except ImportError:  # Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]

ROOT = Path(__file__).resolve().parents[1]
DOC = (ROOT / "docs" / "scene-format.md").read_text()
EXAMPLES = sorted((ROOT / "examples").glob("*.toml"))

_TETRA_OBJ = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"


def _sections(doc: str) -> dict[str, str]:
    """Level-3 sections of the doc by title."""
    parts = re.split(r"^### (.+)$", doc, flags=re.M)
    return {title.strip(): body for title, body in zip(parts[1::2], parts[2::2], strict=True)}


def _same(a: scene.Materials, b: scene.Materials) -> bool:
    if not torch.equal(a.diffuse, b.diffuse) or a.model != b.model:
        return False
    return a.specular is None or a.specular.to_dict() == b.specular.to_dict()


@pytest.fixture
def tetra(tmp_path: Path) -> Path:
    p = tmp_path / "tetra.obj"
    p.write_text(_TETRA_OBJ)
    return p


# --------------------------------------------------------------------------------------------
# the examples


#: What docs/scene-format.md says each example is.
DOCUMENTED = {
    "spot-metal": ("ggx", {"alpha": 0.12, "specular": [1.0, 0.78, 0.34]}, [0.0] * 3),
    "spot-plastic": ("ggx", {"alpha": 0.1, "specular": 0.04}, [0.6, 0.12, 0.08]),
    "spot-diffuse": ("none", {}, [0.75, 0.72, 0.68]),
    "spot-gradient": ("phong", {}, None),
}


def test_examples_are_the_documented_ones():
    assert [p.stem for p in EXAMPLES] == sorted(DOCUMENTED)
    for p in EXAMPLES:
        assert f"`{p.name}`" in DOC


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.stem)
def test_example_loads_with_its_documented_material(path: Path):
    sc = scene.load(path)
    model, params, diffuse = DOCUMENTED[path.stem]
    assert sc.name == path.stem
    assert sc.mesh.n_vertices == 2930  # Spot, examples/LICENSES.md
    assert sc.materials.model == model
    if diffuse is not None:
        assert torch.allclose(sc.materials.diffuse, torch.tensor(diffuse).expand(2930, 3))
    for key, value in params.items():
        assert torch.allclose(sc.materials.specular.params[key], torch.tensor(value))
    # every example is lit by a bundled map, resolved by its name
    names = tomllib.loads(path.read_text())["environment"]
    assert sc.environment == str(data.envmap_path(names))
    # its camera is the file's, not the default one
    assert sc.camera != scene.load(ROOT / "examples" / "spot.obj").camera


def test_gradient_example_runs_from_matte_to_glossy():
    sc = scene.load(ROOT / "examples" / "spot-gradient.toml")
    y = sc.mesh.vertices[:, 1]
    spec = sc.materials.specular.params["specular"]
    assert float(spec[int(y.argmin())].abs().max()) == 0
    assert torch.allclose(spec[int(y.argmax())], torch.tensor([0.3, 0.7, 0.3]))


# --------------------------------------------------------------------------------------------
# the documentation covers what the loader accepts


def test_model_params_are_the_brdf_constructor_arguments():
    # MODEL_PARAMS is the loader's table of keys: it must follow the BRDF classes
    classes = {
        c.type_name: c
        for c in vars(brdf).values()
        if isinstance(c, type) and issubclass(c, brdf.BRDF) and c.type_name in scene.SPECULAR_MODELS
    }
    assert sorted(classes) == sorted(scene.MODEL_PARAMS) == sorted(scene.SPECULAR_MODELS)
    for name, cls in classes.items():
        args = [p for p in inspect.signature(cls.__init__).parameters if p != "self"]
        assert sorted(args) == sorted(scene.MODEL_PARAMS[name]), name
    lobe = brdf.Lafortune([{"cx": -1, "cy": -1, "cz": 1, "exponent": 5, "rho": 0.5}])
    assert sorted(k.split(".")[1] for k in lobe.params) == sorted(scene.LOBE_PARAMS)


def test_doc_mentions_every_key_the_loader_accepts():
    sections = _sections(DOC)
    for key in (*scene.SCENE_KEYS, *scene.GRADIENT_KEYS, "diffuse", "model", *scene.LOBE_PARAMS):
        assert f"`{key}`" in DOC, key
    for field in dataclasses.fields(Camera):
        assert f"| `{field.name}` |" in DOC, field.name
    for model, params in scene.MODEL_PARAMS.items():
        # each model has its own section (ggx and beckmann share one) listing every parameter
        title = next(t for t in sections if model in re.split(r"[ ,]+", t))
        for key in params:
            assert re.search(rf"\| `{key}`", sections[title]), (model, key)
    for suffix in scene.MESH_SUFFIXES:
        assert suffix.lstrip(".").upper() in DOC.upper()
    for name in data.envmap_names():
        assert f'"{name}"' in DOC
    for key, value in scene.BARE_MESH_MATERIAL.items():
        assert f"`{key} = {json.dumps(value)}`" in DOC, key


# --------------------------------------------------------------------------------------------
# one-line material specs


SPECS = [
    ("phong:exponent=100,specular=0.5,diffuse=0.2,0.3,0.6",
     'diffuse = [0.2, 0.3, 0.6]\nmodel = "phong"\nspecular = 0.5\nexponent = 100'),
    ("blinn_phong:exponent=400,specular=0.3,0.3,0.2",
     'model = "blinn_phong"\nspecular = [0.3, 0.3, 0.2]\nexponent = 400'),
    ("ward:alpha_x=0.1,alpha_y=0.3,specular=0.3,diffuse=0.4",
     'diffuse = 0.4\nmodel = "ward"\nspecular = 0.3\nalpha_x = 0.1\nalpha_y = 0.3'),
    ("lafortune:diffuse=0.3,lobe=-1,-1,1,30,0.6,lobe=0,0,1,5,0.1,0.2,0.3",
     'diffuse = 0.3\nmodel = "lafortune"\nlobes = [{ cx = -1, cy = -1, cz = 1, exponent = 30, '
     "rho = 0.6 }, { cx = 0, cy = 0, cz = 1, exponent = 5, rho = [0.1, 0.2, 0.3] }]"),
    ("ggx:alpha=0.05,specular=0.9,0.8,0.6",
     'model = "ggx"\nalpha = 0.05\nspecular = [0.9, 0.8, 0.6]'),
    ("ggx_schlick:alpha=0.09,f0=0.9,0.6,0.2,diffuse=0.1",
     'diffuse = 0.1\nmodel = "ggx_schlick"\nalpha = 0.09\nf0 = [0.9, 0.6, 0.2]'),
    ("ggx:alpha=0.1,specular=0.04,diffuse=0.5,0.5,0.5",
     'diffuse = [0.5, 0.5, 0.5]\nmodel = "ggx"\nspecular = 0.04\nalpha = 0.1'),
    ("beckmann:alpha_u=0.1,alpha_v=0.2,eta=0.2,0.9,1.1,k=3.9,2.4,2.2",
     'model = "beckmann"\nalpha_u = 0.1\nalpha_v = 0.2\neta = [0.2, 0.9, 1.1]\n'
     "k = [3.9, 2.4, 2.2]"),
    ("model=ggx,alpha=0.2", 'model = "ggx"\nalpha = 0.2'),
    ("GGX", 'model = "ggx"'),
    ("diffuse:color=0.7", "diffuse = [0.7, 0.7, 0.7]"),
    ("diffuse=0.7,0.7,0.7", "diffuse = 0.7"),
]  # fmt: skip


@pytest.mark.parametrize(("spec", "toml"), SPECS, ids=[s for s, _ in SPECS])
def test_spec_is_the_material_table(spec: str, toml: str):
    table = tomllib.loads(toml)
    assert _same(scene.parse_material(spec, 5), scene.uniform(table, 5))
    # the spec's table is the TOML table itself (up to a grey colour's spelling)
    again = scene.material_table(spec)
    assert _same(scene.uniform(again, 1), scene.uniform(table, 1))


def test_every_model_has_a_spec_test():
    models = {scene.material_table(spec).get("model", "none") for spec, _ in SPECS}
    assert models == {*scene.SPECULAR_MODELS, "none"}


@pytest.mark.parametrize(
    ("spec", "match"),
    [
        ("glass:alpha=0.1", "unknown model 'glass'"),
        ("model=glass", "unknown model 'glass'"),
        ("ggx:alpah=0.1", "unknown key 'alpah' for ggx"),
        ("diffuse:alpha=0.1", "unknown key 'alpha' for a diffuse material"),
        ("ggx:alpha=0.1,0.2", "alpha: takes one number, got 2 values"),
        ("ggx:specular=0.5,0.5", "specular: takes one number or an RGB triple, got 2 values"),
        ("diffuse=0.5,0.5", "diffuse"),
        ("ggx:alpha=-1", r"alpha: must be >= 0, got -1"),
        ("ggx:specular=1.5", r"specular: must be <= 1"),
        ("diffuse=2", r"diffuse: colour values must be in \[0, 1\]"),
        ("ward:alpha_x=0,specular=0.5", r"alpha_x: must be > 0"),
        ("ggx:alpha=nan", "alpha: must be finite"),
        ("phong:exponent=10", "specular: is missing"),
        ("ggx:alpha=0.1,alpha_u=0.1,alpha_v=0.2", "either alpha or alpha_u and alpha_v"),
        ("ggx:alpha=x", "alpha: 'x' is not a number"),
        ("ggx:alpha=0.1,alpha=0.2", "gives 'alpha' twice"),
        ("ggx:alpha=0.1,", "empty item"),
        ("0.5", "unknown model '0.5'"),
        ("ggx:model=phong", "names the model twice"),
        ("lafortune:lobe=-1,-1,1", "lobe 1 takes 5 numbers"),
        ("   ", "is empty"),
    ],
)
def test_bad_spec_names_the_flag_and_the_problem(spec: str, match: str):
    with pytest.raises(InputError, match=match) as info:
        scene.parse_material(spec)
    assert info.value.what == "--material"
    assert str(info.value).startswith("--material: ")


def test_load_with_a_material_overrides_the_scene_s(tetra: Path, tmp_path: Path):
    spec = "ggx:alpha=0.05,specular=0.9,0.8,0.6"
    bare = scene.load(tetra)
    assert _same(bare.materials, scene.uniform(scene.BARE_MESH_MATERIAL, 4))
    assert _same(scene.load(tetra, material=spec).materials, scene.parse_material(spec, 4))
    # a mapping is a [material] table
    table = {"diffuse": 0.2, "model": "phong", "specular": 0.5, "exponent": 50}
    assert _same(scene.load(tetra, material=table).materials, scene.uniform(table, 4))
    # over a scene file's gradient, and over a built-in's materials
    (tmp_path / "s.toml").write_text(
        'mesh = "tetra.obj"\n[gradient]\nfrom = { diffuse = 0.1 }\nto = { diffuse = 0.9 }\n'
    )
    assert _same(
        scene.load(tmp_path / "s.toml", material=spec).materials, scene.parse_material(spec, 4)
    )
    ball = scene.load("sphere:1", material="diffuse=0.3")
    assert _same(ball.materials, scene.uniform({"diffuse": 0.3}, ball.mesh.n_vertices))


def test_a_bad_material_is_reported_before_the_scene_is_read():
    with pytest.raises(InputError, match="--material: unknown model"):
        scene.load("no_such_mesh.obj", material="glass")


@pytest.mark.parametrize(
    ("material", "match"),
    [
        ('model = "phong"\nspecular = 0.5\nexponent = [1, 2, 3]', r"material\.exponent: takes one"),
        ('model = "ggx"\nspecular = [[0.5, 0.5, 0.5]]', r"material\.specular: takes one number"),
        ('model = "ggx"\nroughness = 0.1', r"material\.roughness: is not a parameter of ggx"),
    ],
)
def test_scene_file_material_values_are_counted(tetra: Path, material: str, match: str):
    p = tetra.parent / "s.toml"
    p.write_text(f'mesh = "tetra.obj"\n[material]\n{material}\n')
    with pytest.raises(InputError, match=match):
        scene.load(p)


def test_gradient_rejects_unknown_keys(tetra: Path):
    p = tetra.parent / "s.toml"
    p.write_text('mesh = "tetra.obj"\n[gradient]\naxes = [1, 0, 0]\nfrom = {}\nto = {}\n')
    with pytest.raises(InputError, match=r"gradient\.axes: unknown key"):
        scene.load(p)


# --------------------------------------------------------------------------------------------
# environments


def test_bundled_environment_name_resolves(tetra: Path):
    p = tetra.parent / "s.toml"
    p.write_text(f'mesh = "tetra.obj"\nenvironment = "{data.DEFAULT_ENVMAP}"\n')
    assert scene.load(p).environment == str(data.envmap_path(data.DEFAULT_ENVMAP))
    # a file of that name without a map's suffix is not a map: the bundled one is taken
    (tetra.parent / data.DEFAULT_ENVMAP).write_bytes(b"#?RADIANCE\n")
    assert scene.load(p).environment == str(data.envmap_path(data.DEFAULT_ENVMAP))
    # a map file next to the scene file comes first
    (tetra.parent / "sky.hdr").write_bytes(b"#?RADIANCE\n")
    p.write_text('mesh = "tetra.obj"\nenvironment = "sky.hdr"\n')
    assert scene.load(p).environment == str(tetra.parent / "sky.hdr")
    p.write_text('mesh = "tetra.obj"\nenvironment = "builtin"\n')
    assert scene.load(p).environment == "builtin"
    p.write_text('mesh = "tetra.obj"\nenvironment = "no_such_park"\n')
    with pytest.raises(InputError, match="not a bundled map") as info:
        scene.load(p)
    assert all(name in info.value.problem for name in data.envmap_names())
