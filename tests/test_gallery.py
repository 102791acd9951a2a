"""The gallery (lobelight.studies.gallery): its scores against hand-computed values, the references'
manifest, the scene list, the Mitsuba export of its plastic, and one tiny run end to end.

Every file is made here: a small icosphere written as OBJ and a small synthetic sky in a
temporary data folder; references are synthetic (no Mitsuba render).
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import math
from collections import Counter
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from lobelight import envmap
from lobelight import model as model_io
from lobelight.cli._gallery import add_arguments, gallery_main
from lobelight.errors import InputError
from lobelight.render import Lighting, Renderer, auto_exposure
from lobelight.studies.gallery import (
    MAPS,
    MATERIALS,
    SCENES,
    SHARP_REFERENCE_SAMPLES,
    GalleryScene,
    Reference,
    ReferenceSettings,
    _references,
    _scenes,
    _sweep,
    coverage_mask,
    data_folder,
    display_exposure,
    energy_ratio,
    equal_quality,
    find_map,
    find_mesh,
    geometry_sha256,
    load_reference,
    mitsuba_sweep,
    prepare_mesh,
    reference_status,
    render_references,
    run,
    scene_hash,
    scene_settings,
    score,
    select,
    spp_levels,
    summarise,
    to_scene,
    write_reference,
)
from lobelight.studies.gallery._scenes import GLTF_ENV, GLTF_MATERIAL
from lobelight.studies.score import noise_psnr_display, psnr_display


def _srgb(x: float) -> float:
    x = min(max(x, 0.0), 1.0)
    return 12.92 * x if x <= 0.0031308 else 1.055 * x ** (1 / 2.4) - 0.055


def _grey(values) -> torch.Tensor:
    """``(1, W, 3)`` grey pixels (luminance = value: the Rec. 709 weights sum to 1)."""
    v = torch.tensor(values, dtype=torch.float32)
    return v[None, :, None].expand(1, len(values), 3).clone()


# --------------------------------------------------------------------------------------------
# scores


def test_display_exposure_is_the_reference_99th_percentile_over_the_mask():
    # object pixels 0.01 .. 1.00; numpy's 99th percentile of 100 values interpolates between
    # ranks 98 and 99: 0.99 + 0.01 (1.00 - 0.99) = 0.9901. The background (50) is not counted.
    ref = _grey([0.01 * k for k in range(1, 101)] + [50.0] * 20)
    mask = torch.zeros(1, 120, dtype=torch.bool)
    mask[0, :100] = True
    assert display_exposure(ref, mask) == pytest.approx(-math.log2(0.9901), rel=1e-6)
    # a colour counts by its luminance: pure green at 1 has luminance 0.7152
    green = torch.zeros(1, 1, 3)
    green[..., 1] = 1.0
    assert display_exposure(green, torch.ones(1, 1, dtype=torch.bool)) == pytest.approx(
        -math.log2(0.7152), rel=1e-6
    )


def test_scores_match_hand_computed_values():
    # three object pixels and one background pixel
    ref = _grey([0.2, 0.4, 0.5, 8.0])
    img = _grey([0.1, 0.4, 1.0, 0.0])
    mask = torch.tensor([[True, True, True, False]])
    p99 = 0.4 + 0.98 * (0.5 - 0.4)  # rank 1.98 of [0.2, 0.4, 0.5]
    k = 1 / p99  # 2^exposure
    err = [(_srgb(k * a) - _srgb(k * b)) ** 2 for a, b in [(0.1, 0.2), (0.4, 0.4), (1.0, 0.5)]]
    psnr = 10 * math.log10(1 / (sum(err) / 3))
    full = 10 * math.log10(1 / ((sum(err) + (_srgb(0.0) - _srgb(8.0 * k)) ** 2) / 4))
    rel = math.sqrt(3 * (0.1**2 + 0 + 0.5**2)) / math.sqrt(3 * (0.2**2 + 0.4**2 + 0.5**2))
    s = score(img, ref, mask)
    assert s["exposure"] == pytest.approx(math.log2(k), rel=1e-9)
    assert s["psnr_display"] == pytest.approx(psnr, rel=1e-6)
    assert s["psnr_display_full"] == pytest.approx(full, rel=1e-6)
    assert s["rel_l2"] == pytest.approx(rel, rel=1e-6)
    assert s["energy_ratio"] == pytest.approx(1.5 / 1.1, rel=1e-6)
    # a wrong mask (the background in) or a wrong exposure (compare's log-average key) differs
    wrong_mask = score(img, ref, torch.ones_like(mask))
    assert abs(wrong_mask["psnr_display"] - psnr) > 0.5
    assert abs(wrong_mask["energy_ratio"] - 1.5 / 1.1) > 0.1
    wrong_exposure = psnr_display(img, ref, mask, auto_exposure(ref, mask))
    assert abs(wrong_exposure - psnr) > 0.5


def test_energy_ratio_weighs_colour_by_luminance_and_ignores_the_background():
    ref = torch.full((2, 2, 3), 0.5)
    img = ref.clone()
    img[..., 0] += 0.1  # red: luminance + 0.02126 per object pixel
    img[1, 1] = 100.0  # a background pixel
    mask = torch.tensor([[True, True], [True, False]])
    assert energy_ratio(img, ref, mask) == pytest.approx((0.5 + 0.02126) / 0.5, rel=1e-6)


def test_noise_psnr_is_the_reference_noise_through_the_display_slope():
    ref = torch.full((2, 3, 3), 0.25)
    stderr = torch.full((2, 3, 3), 0.01)
    mask = torch.ones(2, 3, dtype=torch.bool)
    # exposure 1: displayed 0.5, where sRGB's slope is 1.055 / 2.4 0.5^(1 / 2.4 - 1)
    slope = 1.055 / 2.4 * 0.5 ** (1 / 2.4 - 1)
    expected = -20 * math.log10(slope * 2 * 0.01)
    assert noise_psnr_display(ref, stderr, mask, 1.0) == pytest.approx(expected, rel=1e-6)


def test_summary_takes_the_median_and_the_worst_scene():
    scores = {
        "a": {"psnr_display": 30.0, "psnr_display_full": 20, "rel_l2": 0.1, "energy_ratio": 0.9},
        "b": {"psnr_display": 40.0, "psnr_display_full": 25, "rel_l2": 0.05, "energy_ratio": 1.2},
        "c": {"psnr_display": 35.0, "psnr_display_full": 22, "rel_l2": 0.2, "energy_ratio": 1.0},
    }
    s = summarise(scores)
    assert s["median"]["psnr_display"] == 35.0 and s["median"]["rel_l2"] == 0.1
    assert s["worst"]["psnr_display"] == {"scene": "a", "value": 30.0}
    assert s["worst"]["rel_l2"]["scene"] == "c"
    assert s["worst"]["energy_ratio"]["scene"] == "b"  # |ln 1.2| > |ln 0.9|


# --------------------------------------------------------------------------------------------
# the scene list


def test_scene_list_covers_the_meshes_maps_and_materials():
    plain = [s for s in SCENES if not s.is_gltf]  # the glTF scenes: test_gltf_scenes_...
    assert len(plain) >= 30
    assert len({s.name for s in SCENES}) == len(SCENES)
    meshes = {"bunny_hr.obj", "spot.obj", "teapot.obj", "suzanne.obj", "scorpion.obj"}
    assert {s.mesh for s in plain} == meshes
    assert set(MAPS) == {"park", "studio", "overcast", "grace", "dawn", "interior"}
    assert {s.envmap for s in plain} == set(MAPS.values())
    assert {s.material for s in plain} == set(MATERIALS.values())
    assert "alpha=0.03" in MATERIALS["sharp_metal"] and "alpha=0.25" in MATERIALS["rough_metal"]
    # every bake under three maps or more, every material under three maps or more
    per_bake = Counter(s.bake for s in plain)
    assert min(per_bake.values()) >= 3
    maps_per_material = {
        m: {s.envmap for s in plain if s.material == m} for m in MATERIALS.values()
    }
    assert min(len(v) for v in maps_per_material.values()) >= 3
    # the first four meshes' bakes see every (material, map) pair once: each map four times
    first = [s for s in plain if s.mesh != "scorpion.obj"]
    pairs = Counter((s.material, s.envmap) for s in first)
    assert set(pairs) == {(m, e) for m in MATERIALS.values() for e in MAPS.values()}
    assert set(pairs.values()) == {1}
    # the new maps are each used several times
    per_map = Counter(s.envmap for s in plain)
    assert per_map[MAPS["dawn"]] >= 4 and per_map[MAPS["interior"]] >= 4
    # the scorpion: a rough metal and another material, decimated by the gallery itself
    scorpion = [s for s in SCENES if s.mesh == "scorpion.obj"]
    assert MATERIALS["rough_metal"] in {s.material for s in scorpion}
    assert len({s.material for s in scorpion}) >= 2
    assert all(10000 <= s.max_vertices <= 15000 for s in scorpion)
    # every bake takes fit_model's default Gaussians per view
    assert all(s.gaussians is None for s in SCENES)
    # a bake's scenes agree on what the bake depends on
    assert select() == list(SCENES)
    assert all(s.max_vertices for s in SCENES if s.mesh == "bunny_hr.obj")
    assert all(s.subdivisions >= 1 for s in SCENES if s.mesh == "suzanne.obj")


def test_gltf_scenes_are_four_assets_each_under_a_sharp_sun_and_a_soft_map():
    gltf = [s for s in SCENES if s.is_gltf]
    assets = Counter(s.mesh for s in gltf)
    assert len(assets) >= 4 and set(assets.values()) == {2}
    assert {s.material for s in gltf} == {GLTF_MATERIAL}
    for mesh in assets:
        name = Path(mesh).stem
        assert mesh == f"{name}/{name}.glb"
        maps = {s.envmap for s in gltf if s.mesh == mesh}
        assert MAPS["park"] in maps  # a small unclipped sun: sharp shadows and highlights
        assert maps & {MAPS["interior"], MAPS["overcast"]}
        bakes = {s.bake for s in gltf if s.mesh == mesh}
        assert len(bakes) == 1 and all(s.name.startswith(f"{s.bake}-") for s in gltf)
    # neither subdivided nor decimated (their UVs would not follow), each with a camera
    assert all(s.subdivisions == 0 and s.max_vertices is None for s in gltf)
    assert all(s.camera is not None for s in gltf)
    assert [s.name for s in select(["helmet"])] == ["helmet-park", "helmet-interior"]


# --------------------------------------------------------------------------------------------
# glTF scenes


#: The repository's glTF assets, found from this file (an installed package has none).
REPO_GLTF = Path(__file__).resolve().parents[1] / "assets" / "gltf"


def _gltf_rows() -> dict[str, list[str]]:
    """``{file: cells}`` of the table in assets/gltf/LICENSES.md."""
    rows = {}
    for line in (REPO_GLTF / "LICENSES.md").read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.startswith("| `") and len(cells) == 6:
            rows[cells[0].strip("`")] = cells
    return rows


def test_every_gltf_asset_has_its_source_and_licence():
    """Each glTF asset a scene names has a row (source repository @ commit, author, licence,
    size, md5); the files themselves are checked where they are present (they are fetched
    data, kept beside the repository's files, not in git: LICENSES.md)."""
    rows = _gltf_rows()
    assert {s.mesh for s in SCENES if s.is_gltf} <= set(rows)
    for name, (_, source, author, licence, size, md5) in rows.items():
        assert "@" in source and author and licence, name
        path = REPO_GLTF / name
        if path.is_file():
            data = path.read_bytes()
            assert int(size.replace(",", "")) == len(data), name
            assert hashlib.md5(data).hexdigest() == md5, name


def test_the_package_finds_the_gltf_assets_of_the_source_tree_it_runs_from():
    here = Path(_scenes.__file__).resolve().parents[4] / "assets" / "gltf"
    assert _scenes.GLTF_ASSETS == (here if here.is_dir() else None)


def _tiny_glb(path: Path, scale: float = 3.0) -> None:
    """A textured two-material glTF (tests/test_gltf.py's quads), scaled up by ``scale``."""
    from test_gltf import Gltf, two_material_quads

    g = Gltf()
    two_material_quads(g)
    g.doc["nodes"][0]["scale"] = [scale] * 3
    path.parent.mkdir(parents=True, exist_ok=True)
    g.write(path)


TINY = GalleryScene(
    "tiny-sky", "tiny", "Tiny/Tiny.glb", "sky.hdr", GLTF_MATERIAL, camera=_scenes.default_camera()
)


def test_a_gltf_scene_is_the_asset_with_its_materials_centred_and_scaled(
    data_dir, tmp_path, monkeypatch
):
    monkeypatch.setenv(GLTF_ENV, str(tmp_path / "assets"))
    _tiny_glb(tmp_path / "assets" / "Tiny" / "Tiny.glb")
    assert find_mesh(TINY, data_dir) == tmp_path / "assets" / "Tiny" / "Tiny.glb"
    mesh = prepare_mesh(TINY, data_dir)
    lo, hi = mesh.bounds
    assert float((hi - lo).norm()) == pytest.approx(2.0, rel=1e-5)
    assert float((lo + hi).abs().max()) < 1e-5
    sc = to_scene(TINY, data_dir)
    assert sc.mesh is sc.gltf.mesh and torch.equal(sc.mesh.vertices, mesh.vertices)
    assert [m.name for m in sc.gltf.materials[:2]] == ["painted", "plain"]
    assert sc.gltf.materials[0].base_color_texture is not None
    assert sc.environment == str(data_dir / "envmaps" / "sky.hdr") and sc.name == "tiny-sky"
    # the file's own normals (+z), not recomputed; the hash follows the file's bytes
    assert torch.allclose(sc.mesh.normals, torch.tensor([0.0, 0.0, 1.0]).expand_as(sc.mesh.normals))
    before = scene_hash(TINY, data_dir)
    _tiny_glb(tmp_path / "assets" / "Tiny" / "Tiny.glb", scale=2.0)
    assert scene_hash(TINY, data_dir) != before
    # not decimated, not subdivided
    with pytest.raises(InputError, match="neither subdivided nor decimated"):
        prepare_mesh(dataclasses.replace(TINY, max_vertices=10), data_dir)


def test_a_gltf_asset_is_looked_for_in_the_folders_in_order(data_dir, tmp_path, monkeypatch):
    monkeypatch.delenv(GLTF_ENV, raising=False)
    monkeypatch.setattr(_scenes, "GLTF_ASSETS", tmp_path / "repo")
    _tiny_glb(tmp_path / "repo" / "Tiny" / "Tiny.glb")
    assert find_mesh(TINY, data_dir) == tmp_path / "repo" / "Tiny" / "Tiny.glb"
    _tiny_glb(data_dir / "gltf" / "Tiny" / "Tiny.glb")
    assert find_mesh(TINY, data_dir) == data_dir / "gltf" / "Tiny" / "Tiny.glb"
    monkeypatch.setenv(GLTF_ENV, str(tmp_path / "mine"))
    with pytest.raises(InputError, match=r"\$LOBELIGHT_GLTF: no such folder"):
        find_mesh(TINY, data_dir)
    _tiny_glb(tmp_path / "mine" / "Tiny" / "Tiny.glb")
    assert find_mesh(TINY, data_dir) == tmp_path / "mine" / "Tiny" / "Tiny.glb"
    # nowhere: one error naming the asset, every place looked and the variable
    gone = dataclasses.replace(TINY, mesh="Gone/Gone.glb")
    with pytest.raises(InputError, match=r"tiny-sky: mesh: 'Gone/Gone\.glb'") as err:
        find_mesh(gone, data_dir)
    for place in (tmp_path / "mine", data_dir / "gltf", tmp_path / "repo"):
        assert str(place) in str(err.value)


def test_a_gltf_scene_reference_renders_with_its_textures(data_dir, tmp_path, monkeypatch):
    """The references step renders a glTF scene through the textured Mitsuba export (tiny
    settings, the scalar variant) into a fresh manifest entry with the asset's vertices."""
    pytest.importorskip("mitsuba", reason="Mitsuba 3 renders the references")
    monkeypatch.setenv(GLTF_ENV, str(tmp_path / "assets"))
    _tiny_glb(tmp_path / "assets" / "Tiny" / "Tiny.glb")
    settings = ReferenceSettings(spp=4, pass_spp=2, width=16, height=16, max_depth=2)
    refs = tmp_path / "refs"
    out = render_references([TINY], data=data_dir, refs=refs, settings=settings,
                            variant="scalar_rgb", progress=False)  # fmt: skip
    assert out["rendered"] == ["tiny-sky"]
    assert reference_status(refs, TINY, data_dir, settings) == ("ok", "")
    ref = load_reference(refs, TINY, data_dir)
    assert int(ref.mask.sum()) > 10 and bool(torch.isfinite(ref.image).all())
    assert float(ref.image[ref.mask].mean()) > 0
    assert ref.entry["vertices"] == prepare_mesh(TINY, data_dir).n_vertices


@pytest.mark.skipif(
    not any(REPO_GLTF.glob("*/*.glb")), reason="the glTF assets are not beside the repository"
)
def test_the_repository_gltf_assets_load_as_bare_meshes():
    """Every gallery glTF asset present loads with lobelight.scene.load: its materials and
    textures read, what is not supported only warned about."""
    from lobelight.scene import load

    for mesh in sorted({s.mesh for s in SCENES if s.is_gltf}):
        path = REPO_GLTF / mesh
        if not path.is_file():
            continue
        sc = load(path)
        assert sc.gltf is not None and sc.mesh.n_vertices > 300
        assert any(m.base_color_texture is not None for m in sc.gltf.materials)


def test_select_names_scenes_and_bakes_and_refuses_unknown_names():
    assert [s.name for s in select(["teapot-diffuse"])] == [
        "teapot-diffuse-park",
        "teapot-diffuse-studio",
        "teapot-diffuse-dawn",
    ]
    with pytest.raises(InputError, match="no gallery scene or bake 'nope'"):
        select(["nope"])


# --------------------------------------------------------------------------------------------
# the repository's gallery data


#: The repository's gallery data, found from this file: the tests may run against an installed
#: copy of the package, which does not hold it (its ``GALLERY_DATA`` is then None).
REPO_DATA = Path(__file__).resolve().parents[1] / "gallery-data"


@pytest.fixture
def repo_data(monkeypatch) -> Path:
    """The repository's gallery data, as the gallery's own folder."""
    monkeypatch.setattr(_scenes, "GALLERY_DATA", REPO_DATA)
    return REPO_DATA


def _licence_rows() -> dict[str, list[str]]:
    """``{file: cells}`` of the table in gallery-data/LICENSES.md."""
    rows = {}
    for line in (REPO_DATA / "LICENSES.md").read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.startswith("| `") and len(cells) == 6:
            rows[cells[0].strip("`")] = cells
    return rows


def test_every_file_of_the_gallery_data_has_its_source_and_licence(repo_data):
    rows = _licence_rows()
    files = {
        p.relative_to(repo_data).as_posix()
        for p in repo_data.rglob("*")
        if p.is_file() and p.name != "LICENSES.md"
    }
    assert files and files == set(rows)
    for name, (_, source, author, licence, size, md5) in rows.items():
        data = (repo_data / name).read_bytes()
        assert int(size.replace(",", "")) == len(data), name
        assert hashlib.md5(data).hexdigest() == md5, name  # a byte-exact copy of its source
        assert "@" in source and author and licence, name  # repository @ commit, who, terms
    # the files the new scenes name are there, found without a data folder
    for sc in SCENES:
        if sc.mesh == "scorpion.obj":
            assert find_mesh(sc, None) == repo_data / "meshes" / sc.mesh
        if sc.envmap in (MAPS["dawn"], MAPS["interior"]):
            assert find_map(sc, None) == repo_data / "envmaps" / sc.envmap


def test_the_package_finds_the_gallery_data_of_the_source_tree_it_runs_from():
    # an editable install (the developer's) finds it; an installed copy has none
    here = Path(_scenes.__file__).resolve().parents[4] / "gallery-data"
    assert _scenes.GALLERY_DATA == (here if here.is_dir() else None)


def test_a_file_is_read_from_the_data_folder_first_then_the_repository(
    tmp_path, monkeypatch, repo_data
):
    monkeypatch.delenv("LOBELIGHT_DATA", raising=False)
    dawn = next(s for s in SCENES if s.envmap == MAPS["dawn"])
    assert find_map(dawn, data_folder(None)) == repo_data / "envmaps" / dawn.envmap
    (tmp_path / "envmaps").mkdir()
    own = tmp_path / "envmaps" / dawn.envmap
    own.write_bytes(b"not a map")
    monkeypatch.setenv("LOBELIGHT_DATA", str(tmp_path))
    assert find_map(dawn, data_folder(None)) == own
    # neither place: one error naming the file and both places
    gone = dataclasses.replace(dawn, envmap="nowhere.hdr")
    with pytest.raises(InputError, match=r"nowhere\.hdr") as err:
        find_map(gone, data_folder(None))
    assert str(tmp_path / "envmaps") in str(err.value)
    assert str(repo_data / "envmaps") in str(err.value)
    # no repository folder (an installed copy): the error says so
    monkeypatch.setattr(_scenes, "GALLERY_DATA", None)
    with pytest.raises(InputError, match="gallery-data/envmaps"):
        find_map(gone, data_folder(None))


# --------------------------------------------------------------------------------------------
# a tiny data folder


@pytest.fixture
def data_dir(tmp_path) -> Path:
    import trimesh

    d = tmp_path / "data"
    (d / "meshes").mkdir(parents=True)
    (d / "envmaps").mkdir()
    ball = trimesh.creation.icosphere(subdivisions=2, radius=3.0)  # scaled down when prepared
    ball.export(d / "meshes" / "ball.obj")
    # a small sky, bright at the zenith, with a small bright light (64 x 32: quick to prefilter)
    sky = torch.linspace(1.0, 0.2, 32)[:, None, None].expand(32, 64, 3).clone()
    sky[..., 0] *= 1.2
    sky[4:6, 10:12] = 40.0
    envmap.save(envmap.EnvMap(sky, layout="latlong"), d / "envmaps" / "sky.hdr")
    return d


BALL = GalleryScene("ball-diffuse-sky", "ball-diffuse", "ball.obj", "sky.hdr", "diffuse:color=0.7")
BALL_2 = GalleryScene("ball-diffuse-sky-2", "ball-diffuse", "ball.obj", "sky.hdr", BALL.material)


def _synthetic(refs, sc, data, settings, value=1.0):
    """A constant reference with the scene's real mask and manifest entry."""
    mesh = prepare_mesh(sc, data)
    mask = coverage_mask(mesh, sc.view(), settings.width, settings.height)
    img = np.full((settings.height, settings.width, 3), value, np.float32)
    entry = {
        "scene_hash": scene_hash(sc, data),
        "geometry_sha256": geometry_sha256(mesh),
        "settings": settings.to_dict(),
        "variant": "synthetic",
    }
    return write_reference(refs, sc, img, np.zeros_like(img), mask.numpy(), entry=entry)


def test_prepared_mesh_is_centred_with_diagonal_two(data_dir):
    m = prepare_mesh(BALL, data_dir)
    lo, hi = m.bounds
    assert float((hi - lo).norm()) == pytest.approx(2.0, rel=1e-5)
    assert float((lo + hi).abs().max()) < 1e-5
    mask = coverage_mask(m, BALL.view(), 24, 24)
    assert 0 < int(mask.sum()) < 24 * 24 and not bool(mask[0, 0])


def test_a_reference_does_not_depend_on_the_bakes_gaussians_per_view(data_dir):
    # the bake's lobe count changes the model, not what Mitsuba renders: its references stay
    more = dataclasses.replace(BALL, gaussians=2)
    assert scene_hash(more, data_dir) == scene_hash(BALL, data_dir)
    assert more.bake_definition() != BALL.bake_definition()  # but the bake is another
    assert scene_hash(dataclasses.replace(BALL, material="diffuse:color=0.5"), data_dir) != (
        scene_hash(BALL, data_dir)
    )


def test_bad_inputs_name_the_input(data_dir, monkeypatch):
    monkeypatch.delenv("LOBELIGHT_DATA", raising=False)
    # no data folder, and the repository does not hold the file: the error says how to give one
    with pytest.raises(InputError, match=r"ball-diffuse-sky: mesh: 'ball\.obj' .*--data DIR"):
        run([BALL], refs=data_dir, out=data_dir / "out")
    with pytest.raises(InputError, match="--data: no such folder"):
        run([BALL], data=data_dir / "nope", refs=data_dir, out=data_dir / "out")
    monkeypatch.setenv("LOBELIGHT_DATA", str(data_dir / "nope"))
    with pytest.raises(InputError, match=r"\$LOBELIGHT_DATA: no such folder"):
        run([BALL], refs=data_dir, out=data_dir / "out")
    with pytest.raises(InputError, match="--sweep-max-spp"):
        run([BALL], data=data_dir, refs=data_dir, out=data_dir / "out", sweep_max_spp=0)
    missing = GalleryScene("x-sky", "x", "missing.obj", "sky.hdr", "diffuse:color=0.5")
    with pytest.raises(InputError, match="x-sky: mesh"):
        prepare_mesh(missing, data_dir)
    with pytest.raises(InputError, match="ball-diffuse-sky: reference: missing"):
        run([BALL], data=data_dir, refs=data_dir / "refs", out=data_dir / "out")


def _stub_references(monkeypatch) -> list[tuple[str, int]]:
    """Mitsuba replaced for render_references: each render is the constant 0.5 with no noise;
    returns the list its calls fill with (scene name, samples per pixel)."""
    calls = []

    class FakeMitsuba:
        __version__ = "0-test"

    def fake_render(mi, variant, scene, s, progress):
        calls.append((scene.name, s.spp))
        img = np.full((s.height, s.width, 3), 0.5, np.float32)
        return img, np.zeros_like(img)

    monkeypatch.setattr(_references, "_mitsuba", lambda v: (FakeMitsuba, "stub", ""))
    monkeypatch.setattr(_references, "_render_mitsuba", fake_render)
    return calls


def test_manifest_checksum_finds_a_corrupt_reference_and_it_is_rendered_again(
    data_dir, tmp_path, monkeypatch
):
    refs = tmp_path / "refs"
    settings = ReferenceSettings(spp=4, pass_spp=2, width=16, height=12)
    for sc in (BALL, BALL_2):
        _synthetic(refs, sc, data_dir, settings)
        assert reference_status(refs, sc, data_dir, settings) == ("ok", "")
    ref = load_reference(refs, BALL, data_dir)
    assert ref.image.shape == (12, 16, 3) and ref.mask.dtype == torch.bool
    # one flipped byte in the middle of the file
    path = refs / "ball-diffuse-sky.npz"
    raw = bytearray(path.read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    path.write_bytes(bytes(raw))
    assert reference_status(refs, BALL, data_dir)[0] == "corrupt"
    with pytest.raises(InputError, match="ball-diffuse-sky: reference: corrupt"):
        load_reference(refs, BALL, data_dir)
    # other settings, or another material, make an entry stale
    assert reference_status(refs, BALL_2, data_dir, ReferenceSettings())[0] == "stale"
    other = GalleryScene(BALL_2.name, BALL_2.bake, "ball.obj", "sky.hdr", "diffuse:color=0.2")
    assert reference_status(refs, other, data_dir)[0] == "stale"

    calls = _stub_references(monkeypatch)
    out = render_references([BALL, BALL_2], data=data_dir, refs=refs, settings=settings)
    assert [c[0] for c in calls] == ["ball-diffuse-sky"] and out["kept"] == ["ball-diffuse-sky-2"]
    assert out["status"]["ball-diffuse-sky"].startswith("corrupt")
    assert reference_status(refs, BALL, data_dir, settings) == ("ok", "")
    manifest = json.loads((refs / "manifest.json").read_text())
    entry = manifest["entries"]["ball-diffuse-sky"]
    assert entry["settings"] == settings.to_dict() and entry["variant"] == "stub"
    assert float(load_reference(refs, BALL, data_dir).image.mean()) == pytest.approx(0.5)


def test_a_scene_with_more_reference_samples_is_rendered_and_checked_with_them(
    data_dir, tmp_path, monkeypatch
):
    # the sharp metals' references take SHARP_REFERENCE_SAMPLES times the settings' samples:
    # rendered so, recorded so, and a reference of the settings' samples alone is stale
    refs = tmp_path / "refs"
    settings = ReferenceSettings(spp=4, pass_spp=2, width=16, height=12)
    more = dataclasses.replace(BALL, reference_samples=SHARP_REFERENCE_SAMPLES)
    assert SHARP_REFERENCE_SAMPLES > 1
    assert scene_hash(more, data_dir) == scene_hash(BALL, data_dir)  # the same picture
    assert scene_settings(settings, BALL) == settings
    want = scene_settings(settings, more)
    assert want.spp == 4 * SHARP_REFERENCE_SAMPLES and want.pass_spp == 2
    _synthetic(refs, more, data_dir, settings)  # at the settings' samples: too few
    assert reference_status(refs, more, data_dir, settings)[0] == "stale"
    assert reference_status(refs, BALL, data_dir, settings) == ("ok", "")
    calls = _stub_references(monkeypatch)
    out = render_references([more], data=data_dir, refs=refs, settings=settings)
    assert out["rendered"] == [more.name] and calls == [(more.name, want.spp)]
    assert reference_status(refs, more, data_dir, settings) == ("ok", "")
    entry = json.loads((refs / "manifest.json").read_text())["entries"][more.name]
    assert entry["settings"] == want.to_dict()
    # the gallery's sharp metals, and only they, take more
    for sc in SCENES:
        sharp = sc.material == MATERIALS["sharp_metal"]
        assert sc.reference_samples == (SHARP_REFERENCE_SAMPLES if sharp else 1), sc.name


class FakeMitsuba:
    """Mitsuba's stand-in for the sweep: a render is the constant 1 (the tiny gallery's
    synthetic reference) plus Gaussian noise of standard deviation 0.5 / sqrt(spp), seeded by
    ``seed``; the seeds used are kept."""

    __version__ = "0-test"

    def __init__(self):
        self.seeds = []
        self.size = (32, 40)

    def load_dict(self, d):
        return d

    def render(self, scene, *, spp, seed):
        self.seeds.append(seed)
        rng = np.random.default_rng(seed)
        return 1.0 + 0.5 / math.sqrt(spp) * rng.standard_normal((*self.size, 3))


def test_a_tiny_gallery_runs_end_to_end_and_resumes(data_dir, tmp_path, monkeypatch):
    refs, out = tmp_path / "refs", tmp_path / "out"
    settings = ReferenceSettings(spp=4, pass_spp=2, width=40, height=32)
    _synthetic(refs, BALL, data_dir, settings, value=1.0)
    kw = dict(data=data_dir, refs=refs, out=out, samples=4, backend="torch", base_res=16)
    monkeypatch.setattr(_references, "_mitsuba", lambda v: (FakeMitsuba(), "stub", ""))
    monkeypatch.setattr(_sweep, "scene_dict", lambda *a, **k: {})
    first = run([BALL], progress=False, sweep_max_spp=64, **kw)
    s = first["scenes"]["ball-diffuse-sky"]
    # the sweep ran until it reached our score (or its last level), and the table shows it
    rows = s["mitsuba_sweep"]["sweep"]
    assert [r["spp"] for r in rows] == spp_levels(64)[: len(rows)]
    eq = s["equal_quality"]
    assert eq["bound"] in ("=", "<=", "~", ">=") and s["frame_seconds"] > 0
    assert eq["speedup"] == pytest.approx(eq["seconds"] / s["frame_seconds"])
    (row,) = first["table"]
    assert row["scene"] == "ball-diffuse-sky" and row["speedup"] == eq["speedup"]
    assert row["highpass_ratio"] == s["highpass_ratio"] > 0
    # a reference with no noise (stderr 0): all its high-pass energy is detail
    assert s["reference_noise_highpass"] == [0.0, 0.0]
    assert s["highpass_ratio_detail"] == [s["highpass_ratio"]] * 2
    bake = first["bakes"]["ball-diffuse"]
    assert bake["resumed"] is False
    # no per-bake override: fit_model's default, recorded, and what it chose
    assert bake["settings"]["n_gaussians"] is None and bake["settings"]["fit_model_default"]
    assert bake["gaussians"] in (1, 2, 3) and s["gaussians"] == bake["gaussians"]
    assert s["vertices"] == 162 and s["object_pixels"] > 100 and s["mask_partial_in_ours"] == 0
    assert math.isfinite(s["psnr_display"]) and s["energy_ratio"] > 0
    assert first["summary"]["worst"]["psnr_display"]["scene"] == "ball-diffuse-sky"
    on_disk = json.loads((out / "gallery.json").read_text())
    assert on_disk["scenes"]["ball-diffuse-sky"]["rel_l2"] == pytest.approx(s["rel_l2"])
    from PIL import Image

    assert Image.open(out / "ball-diffuse-sky.png").size == (3 * 40, 32)

    # our own image as the reference: a second run loads the model and scores it perfect
    m = model_io.load(out / "models" / "ball-diffuse.npz")
    lighting = Lighting(envmap.load(data_dir / "envmaps" / "sky.hdr"), base_res=16, sun=True)
    with Renderer(m, lighting, 40, 32, backend="torch", samples=4) as ren:
        ours = ren.render(BALL.view()).numpy()
    mesh = prepare_mesh(BALL, data_dir)
    entry = {
        "scene_hash": scene_hash(BALL, data_dir),
        "geometry_sha256": geometry_sha256(mesh),
        "settings": settings.to_dict(),
    }
    mask = coverage_mask(mesh, BALL.view(), 40, 32).numpy()
    write_reference(refs, BALL, ours, np.zeros_like(ours), mask, entry=entry)
    second = run([BALL], progress=False, sweep=False, **kw)
    s2 = second["scenes"]["ball-diffuse-sky"]
    assert second["bakes"]["ball-diffuse"]["resumed"] is True
    assert s2["rel_l2"] == 0.0 and s2["energy_ratio"] == 1.0
    assert s2["psnr_display"] is None  # infinite: identical images (null in strict JSON)


# --------------------------------------------------------------------------------------------
# the command line and the Mitsuba export of the plastic


def test_arguments_fit_a_parser_that_has_the_common_flags(data_dir):
    p = argparse.ArgumentParser()
    p.add_argument("--json", action="store_true")
    p.add_argument("--device", default="cpu")
    add_arguments(p)
    args = p.parse_args(["list", "--scenes", "teapot-diffuse", "--json"])
    assert args.json and args.device == "cpu"
    assert [s["name"] for s in gallery_main(args)["scenes"]] == [
        "teapot-diffuse-park",
        "teapot-diffuse-studio",
        "teapot-diffuse-dawn",
    ]
    run_args = p.parse_args(["run"])
    assert run_args.sweep is True and run_args.sweep_max_spp == 256
    assert run_args.gaussians is None  # each bake's own, else fit_model's default
    assert p.parse_args(["run", "--gaussians", "auto"]).gaussians == "auto"
    assert p.parse_args(["run", "--gaussians", "2"]).gaussians == 2
    run_args = p.parse_args(["run", "--no-sweep", "--sweep-max-spp", "64"])
    assert run_args.sweep is False and run_args.sweep_max_spp == 64
    args = p.parse_args(["references", "--data", str(data_dir / "nope")])
    with pytest.raises(InputError, match="--data"):
        gallery_main(args)


def test_lambert_plus_ggx_exports_as_their_exact_sum():
    """The plastic's Mitsuba blendbsdf evaluates to Lambert + GGX at 40 direction pairs."""
    mi = pytest.importorskip("mitsuba", reason="mitsuba is not installed")
    from lobelight.reference.mitsuba import _blend
    from lobelight.scene import parse_material

    if mi.variant() != "scalar_rgb":
        mi.set_variant("scalar_rgb")
    mats = parse_material(MATERIALS["plastic"].replace("diffuse=0.5", "diffuse=0.6,0.3,0.1"))
    bsdf = mi.load_dict(_blend(mats.diffuse[0], mats.specular))
    g = torch.Generator().manual_seed(5)
    d = torch.randn(2, 40, 3, generator=g, dtype=torch.float64)
    d[..., 2] = d[..., 2].abs() + 0.05
    wi, wo = torch.nn.functional.normalize(d, dim=-1).float()
    n = torch.tensor([0.0, 0.0, 1.0]).expand(40, 3)
    t = torch.tensor([1.0, 0.0, 0.0]).expand(40, 3)
    ours = (mats.brdf().eval(wi, wo, n, t) * wi[:, 2:]).double().numpy()
    ctx, ref = mi.BSDFContext(), []
    for a in range(40):
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(*wo[a].tolist())  # Mitsuba's wi points to the viewer: our wo
        si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
        ref.append(list(bsdf.eval(ctx, si, mi.Vector3f(*wi[a].tolist()))))
    np.testing.assert_allclose(ours, np.array(ref), rtol=1e-4, atol=1e-7)
    too_bright = parse_material("ggx:alpha=0.1,specular=0.5,diffuse=0.6")
    with pytest.raises(InputError, match="exceed 1"):
        _blend(too_bright.diffuse[0], too_bright.specular)


# --------------------------------------------------------------------------------------------
# equal quality: the Mitsuba sweep and its crossing


def test_spp_levels_double_up_to_the_largest():
    assert spp_levels(8) == [1, 2, 4, 8]
    assert spp_levels(6) == [1, 2, 4, 6]
    assert spp_levels(1) == [1]
    with pytest.raises(InputError, match="--sweep-max-spp"):
        spp_levels(0)


def _law(spp, a, b, per_spp=0.05):
    """A sweep row under the Monte Carlo law MSE = a / spp + b, seconds in proportion to spp."""
    return {"spp": spp, "seconds": per_spp * spp, "psnr_display": -10 * math.log10(a / spp + b)}


def test_equal_quality_interpolates_in_log_spp():
    # with no reference noise (b = 0) PSNR is a line in log2 spp and seconds a line in
    # log-log: the interpolation is exact
    sweep = [_law(n, 0.03, 0.0) for n in spp_levels(256)]
    target = -10 * math.log10(0.03 / 100)  # the score of 100 spp
    eq = equal_quality(target, sweep, 0.2)
    assert eq["bound"] == "="
    assert eq["spp"] == pytest.approx(100, rel=1e-9)
    assert eq["seconds"] == pytest.approx(5.0, rel=1e-9)
    assert eq["speedup"] == pytest.approx(25.0, rel=1e-9)
    # already reached at 1 spp: upper bounds
    assert equal_quality(0.0, sweep, 0.2)["bound"] == "<="
    # an identical image (infinite score) or no sweep: nothing to say
    assert equal_quality(math.inf, sweep, 0.2)["spp"] is None
    assert equal_quality(30.0, [], 0.2)["bound"] is None


def test_equal_quality_extrapolates_with_the_reference_noise():
    a, b = 0.03, 3e-5
    sweep = [_law(n, a, b) for n in spp_levels(64)]
    target = -10 * math.log10(a / 500 + b)  # the score of 500 spp, past the sweep
    eq = equal_quality(target, sweep, 0.5, noise_mse=b)
    assert eq["bound"] == "~"
    assert eq["spp"] == pytest.approx(500, rel=1e-9)  # the law holds exactly here
    assert eq["seconds"] == pytest.approx(25.0, rel=1e-9)
    # without the reference's noise, or under its floor: the last render's figures, lower bounds
    assert equal_quality(target, sweep, 0.5) == {
        "spp": 64,
        "seconds": pytest.approx(3.2),
        "speedup": pytest.approx(6.4),
        "bound": ">=",
    }
    floor = -10 * math.log10(b)
    assert equal_quality(floor + 1, sweep, 0.5, noise_mse=b)["bound"] == ">="
    # past the reference's own samples per pixel: a lower bound at them, by the same law
    capped = equal_quality(target, sweep, 0.5, noise_mse=b, cap_spp=256)
    assert capped["bound"] == ">=" and capped["spp"] == 256
    assert capped["seconds"] == pytest.approx(12.8, rel=1e-9)
    assert equal_quality(target, sweep, 0.5, noise_mse=b, cap_spp=1024)["bound"] == "~"


def test_mitsuba_sweep_stops_at_our_score_with_seeds_apart_from_the_reference(monkeypatch):
    fake = FakeMitsuba()
    fake.size = (16, 16)
    monkeypatch.setattr(_references, "_mitsuba", lambda v: (fake, "stub", ""))
    monkeypatch.setattr(_sweep, "scene_dict", lambda *a, **k: {})
    image = torch.ones(16, 16, 3)
    mask = torch.ones(16, 16, dtype=torch.bool)
    settings = ReferenceSettings(spp=64, pass_spp=8, width=16, height=16, seed=3).to_dict()
    ref = Reference(image, torch.zeros_like(image), mask, {"settings": settings, "variant": "x"})
    scene = SimpleNamespace(environment="sky.hdr", camera=None)  # read by the stubbed export
    out = mitsuba_sweep(scene, ref, mask, 0.0, 24.0, max_spp=1024)
    rows = out["sweep"]
    psnr = [r["psnr_display"] for r in rows]
    # stops at the first level that reaches the target, not before
    assert psnr[-1] >= 24.0 and all(p < 24.0 for p in psnr[:-1])
    assert [r["spp"] for r in rows] == spp_levels(1024)[: len(rows)]
    assert all(r["seconds"] >= 0 for r in rows)
    # the reference's passes used seeds 3 * 8 .. 3 * 8 + 7; the sweep's (a warm-up, then one per
    # level) are all others, and all different
    assert not set(fake.seeds) & set(range(24, 32))
    assert len(set(fake.seeds)) == len(fake.seeds) == len(rows) + 1
    # with no target every level renders
    fake.seeds.clear()
    assert len(mitsuba_sweep(scene, ref, mask, 0.0, None, max_spp=8)["sweep"]) == 4
