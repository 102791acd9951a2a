"""The model file's reader and writer against hostile and broken models: every array the reader
builds bounded before it is allocated, values that would crash later refused at the door with
one line naming the file and the part, and no model written that the reader would refuse."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import torch

from lobelight import fit, model, scene
from lobelight.cli import main
from lobelight.errors import InputError
from lobelight.geometry import sphere
from lobelight.model import _format


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    """A small fitted model's file (a glossy sphere, 42 vertices, one Gaussian per view)."""
    sc = scene.builtin("sphere", subdivisions=1, model="ggx", roughness=0.2)
    mf = fit.fit_mesh(sc, n=1)
    path = tmp_path_factory.mktemp("model") / "good.npz"
    model.save(path, sc.mesh, sc.materials, mf, provenance={"scene": "s", "bounces": 0})
    return path


def _arrays(path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def _meta(arrays) -> dict:
    return json.loads(bytes(arrays["meta"]).decode())


def _rewrite(src, dst, **changes):
    arrays = _arrays(src)
    arrays.update(changes)
    np.savez(dst, **arrays)
    return dst


def _sparse(path, v: int, n: int) -> None:
    """A model file of ``v`` vertices and ``n`` Gaussians per view whose records are all
    dropped (a keep mask of zeros: the file stays small, its expansion does not)."""
    views = sphere.geodesic_views(dtype=torch.float64).numpy().astype(np.float32)
    vertices = np.zeros((v, 3), np.float32)
    vertices[:, 0] = np.arange(v) % 7  # an extent
    meta = {
        "format": _format.FORMAT,
        "version": _format.VERSION,
        "n_vertices": v,
        "n_views": 92,
        "n_gaussians": n,
        "sh_order": 1,
        "weights": "peak",
        "materials": {"diffuse": [0.5, 0.5, 0.5], "specular": None},
        "provenance": {},
    }
    np.savez_compressed(
        path,
        meta=np.frombuffer(json.dumps(meta).encode(), np.uint8),
        vertices=vertices,
        faces=np.array([[0, 1, 2]], np.int32),
        normals=np.tile(np.float32([0, 0, 1]), (v, 1)),
        views=views,
        keep=np.zeros((v, 92), bool),
        gaussians=np.zeros((0, n, 7), np.float32),
        diffuse=np.zeros((v, 1, 3), np.float32),
    )


def _one_line_exit_2(capsys, argv, *needles):
    """``lobelight ARGV`` exits 2 with one line on stderr holding every needle."""
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    for needle in needles:
        assert needle in err, err
    return err


# the child process of the memory tests: its peak resident memory, less the process's before
# the read (the interpreter and torch), under an address-space cap so that a regression fails
# fast instead of taking the machine's memory
_CHILD = textwrap.dedent(
    """
    import resource, sys
    resource.setrlimit(resource.RLIMIT_AS, (6 << 30, 6 << 30))
    import torch
    from lobelight.cli import main
    from lobelight import model
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    code = main(sys.argv[1:])
    after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    print("GROWTH", (after - before) * 1024, "CODE", code)
    """
)


def _growth(argv) -> tuple[int, int, str]:
    """Bytes of resident memory ``lobelight ARGV`` grew by in a child process, its exit code
    and its stderr."""
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    run = subprocess.run(
        [sys.executable, "-c", _CHILD, *argv], capture_output=True, text=True, env=env, timeout=300
    )
    words = run.stdout.split()
    assert "GROWTH" in words, run.stdout + run.stderr
    return int(words[words.index("GROWTH") + 1]), int(words[-1]), run.stderr


def test_a_small_file_claiming_a_huge_model_is_refused_before_it_is_expanded(tmp_path):
    # an 85 KB file claiming 500,000 vertices and 8 Gaussians per view asked for one 10 GB
    # block (its Gaussians expanded to every vertex and view): refused from its counts
    # (in a child process under an address-space cap: a regression fails there, not here)
    path = tmp_path / "claims.npz"
    _sparse(path, 500_000, 8)
    assert path.stat().st_size < 200_000
    growth, code, err = _growth(["info", str(path)])
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert str(path) in err and "over the reader's limit of 8 GiB" in err, err
    # refused before the expansion: the arrays the file holds (46 MB decompressed: keep mask,
    # vertices, normals) and their checks' temporaries, against 10 GB expanded
    assert growth < 400 << 20, growth


def test_reading_a_sparse_model_holds_its_expanded_gaussians_and_little_more(tmp_path):
    # a 23 KB file claiming 150,000 vertices and 8 Gaussians made `info` take 13.4 GB, 4.3
    # times the 3.1 GB of its expanded Gaussians; the same ratio at 20,000 vertices
    path = tmp_path / "sparse.npz"
    _sparse(path, 20_000, 8)
    expanded = 28 * 20_000 * 92 * 8  # 7 float32 per Gaussian: 412 MB
    growth, code, err = _growth(["info", str(path), "-q"])
    # the expanded Gaussians are the model's own; beyond them the decompressed arrays (6 MB),
    # the summary's (V, J) mask and the allocator's rounding: 15 % and 64 MB cover those, far
    # under the 4.3 times the expansion took with its float64 temporaries
    assert code == 0, err
    assert growth < 1.15 * expanded + (64 << 20), growth / expanded


def test_float64_vertices_beyond_float32_are_refused(tmp_path, good, capsys):
    # float64 vertices of 1e300 passed the finite check and became Inf in float32
    verts = _arrays(good)["vertices"].astype(np.float64)
    verts[0, 0] = 1e300
    bad = _rewrite(good, tmp_path / "far.npz", vertices=verts)
    _one_line_exit_2(capsys, ["info", str(bad)], str(bad), "vertices has NaN or Inf values")


def test_a_gaussian_width_of_1e30_is_refused(tmp_path, good, capsys):
    # sigma = 1e30 read as sharpness 1e-60, which float32 holds as 0: render's IndexError
    g = _arrays(good)["gaussians"].copy()
    g[0, 0, 6] = 1e30
    bad = _rewrite(good, tmp_path / "wide.npz", gaussians=g)
    _one_line_exit_2(capsys, ["info", str(bad)], str(bad), "Gaussian widths (sigma) must be in")


@pytest.mark.parametrize(
    "key", ["meta", "vertices", "faces", "normals", "views", "keep", "gaussians", "diffuse"]
)
def test_an_array_of_strings_is_refused_naming_it(tmp_path, good, key, capsys):
    arr = _arrays(good)[key]
    bad = _rewrite(good, tmp_path / f"str_{key}.npz", **{key: arr.astype(str)})
    _one_line_exit_2(capsys, ["info", str(bad)], str(bad), f"{key} must be", "got dtype '<U")


@pytest.mark.parametrize(
    ("entry", "value"),
    [
        ("bounces", "two"),
        ("indirect_paths", [1]),
        ("bounces", -1),
        ("scene", 5),
        ("environment", ["a.hdr"]),
        ("camera", "front"),
        ("materials", {"a": 1}),
        ("seconds", {"fit": "slow"}),
        ("seconds", [1.0]),
        ("relative_l2_error_mean", "0.3"),
    ],
)
def test_provenance_of_the_wrong_type_is_refused_at_read(tmp_path, good, entry, value, capsys):
    # `info` crashed with ValueError/TypeError on such provenance (int("two"), float("slow"))
    arrays = _arrays(good)
    meta = _meta(arrays)
    meta["provenance"][entry] = value
    raw = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    bad = _rewrite(good, tmp_path / "prov.npz", meta=raw)
    _one_line_exit_2(capsys, ["info", str(bad)], str(bad), f"provenance {entry.split('.')[0]}")


def test_metadata_larger_than_its_vertices_need_is_refused_before_it_is_parsed(tmp_path, good):
    arrays = _arrays(good)
    meta = _meta(arrays)
    meta["provenance"]["pad"] = [{}] * (6 << 20)  # 24 MB of JSON: 6M dicts when parsed
    bad = _rewrite(good, tmp_path / "fat.npz", meta=np.frombuffer(json.dumps(meta).encode(), "u1"))
    with pytest.raises(InputError, match=r"fat\.npz: its metadata takes .* over .* vertices"):
        model.load(bad)


def test_a_model_the_reader_would_refuse_is_not_written(tmp_path):
    # a Ward bake of alpha 1e-6 wrote NaN Gaussians with exit 0, and every reader refused the
    # file; now the writer applies the reader's checks and writes nothing
    sc = scene.builtin("sphere", subdivisions=1, model="ggx", roughness=0.2)
    mf = fit.fit_mesh(sc, n=1)
    mf.gaussians.w[0, 0, 0, 0] = float("nan")
    out = tmp_path / "nan.npz"
    with pytest.raises(InputError, match=r"nan\.npz: not written, a reader would refuse it: .*NaN"):
        model.save(out, sc.mesh, sc.materials, mf)
    assert not out.exists() and not list(tmp_path.iterdir())


def test_a_half_float_model_of_flat_lobes_is_written_readable(tmp_path):
    # the writer's widest lobe (sharpness 1e-12, sigma 1e6) overflowed half floats to Inf;
    # half-float files hold widths up to 65504, a lobe as flat over the sphere
    sc = scene.builtin("sphere", subdivisions=1, model="ggx", roughness=0.2)
    mf = fit.fit_mesh(sc, n=1)
    mf.gaussians.lam[0] = 1e-12
    out = tmp_path / "flat.npz"
    model.save(out, sc.mesh, sc.materials, mf, float16=True, drop=False)
    m = model.load(out)
    # sharpness 1/65504^2 = 2.3e-10 instead of 1e-12: both lobes are 1 to within 1e-9 over
    # the whole sphere (exp(-2 lam) at worst)
    assert float(m.gaussians.lam[0].max()) < 3e-10
