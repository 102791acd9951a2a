"""The model file: round trips, storage options, and bad files (never unpickled)."""

from __future__ import annotations

import dataclasses
import io
import json
import zipfile

import numpy as np
import pytest
import torch

from lobelight import fit, model, scene
from lobelight.cli import main
from lobelight.errors import InputError


@pytest.fixture(scope="module")
def fitted():
    sc = scene.builtin("sphere", subdivisions=1, model="ggx", roughness=0.2)
    return sc, fit.fit_mesh(sc, n=1)


def test_round_trip_float32_is_exact_where_rendering_can_see(tmp_path, fitted):
    sc, mf = fitted
    info = model.save(tmp_path / "m.npz", sc.mesh, sc.materials, mf, provenance={"scene": "s"})
    m = model.load(tmp_path / "m.npz")
    g, h = mf.gaussians, m.gaussians
    keep = torch.from_numpy(np.load(tmp_path / "m.npz")["keep"])
    assert info["records"] == int(keep.sum()) < info["records_total"]  # some views dropped
    torch.testing.assert_close(h.w[keep], g.w[keep], rtol=0, atol=0)
    torch.testing.assert_close(h.mu[keep], g.mu[keep], rtol=1e-6, atol=1e-6)
    torch.testing.assert_close(h.lam[keep], g.lam[keep], rtol=1e-5, atol=0)
    # dropped records: zero weight, and so are all their neighbouring views (never visible)
    assert bool((g.w[~keep] == 0).all()) and bool((h.w[~keep] == 0).all())
    torch.testing.assert_close(m.diffuse, mf.diffuse)
    torch.testing.assert_close(m.mesh.vertices, sc.mesh.vertices)
    assert m.materials.model == "ggx" and m.provenance["scene"] == "s"


def test_float16_halves_storage_within_half_precision(tmp_path, fitted):
    sc, mf = fitted
    a = model.save(tmp_path / "a.npz", sc.mesh, sc.materials, mf, drop=False)
    b = model.save(tmp_path / "b.npz", sc.mesh, sc.materials, mf, float16=True)
    assert b["bytes"] < 0.75 * a["bytes"]
    m = model.load(tmp_path / "b.npz")
    keep = m.gaussians.w.amax((-1, -2)) > 0
    # half floats: 11-bit mantissa, relative error <= 2^-11 = 4.9e-4 per stored number; the
    # peak weight is the stored integral over the Gaussian's integral, whose sigma is stored
    # too (lam = sigma^-2 doubles sigma's error): up to ~1.5e-3 together
    torch.testing.assert_close(m.gaussians.w[keep], mf.gaussians.w[keep], rtol=2e-3, atol=1e-6)
    sig_a = m.gaussians.lam[keep].rsqrt()
    sig_b = mf.gaussians.lam[keep].rsqrt()
    torch.testing.assert_close(sig_a, sig_b, rtol=1e-3, atol=0)


def _rewrite(src, dst, **changes):
    with np.load(src, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    arrays.update(changes)
    np.savez(dst, **arrays)


def test_bad_model_files(tmp_path, fitted):
    sc, mf = fitted
    good = tmp_path / "good.npz"
    model.save(good, sc.mesh, sc.materials, mf)
    with pytest.raises(InputError, match="no such file"):
        model.load(tmp_path / "missing.npz")
    trunc = tmp_path / "trunc.npz"
    trunc.write_bytes(good.read_bytes()[:300])
    with pytest.raises(InputError, match=r"trunc\.npz"):
        model.load(trunc)
    other = tmp_path / "other.npz"
    np.savez(other, x=np.zeros(3))
    with pytest.raises(InputError, match="not a lobelight model file"):
        model.load(other)
    meta = json.loads(bytes(np.load(good)["meta"]).decode())
    meta["version"] = 99
    _rewrite(good, tmp_path / "v.npz", meta=np.frombuffer(json.dumps(meta).encode(), np.uint8))
    with pytest.raises(InputError, match="version 99"):
        model.load(tmp_path / "v.npz")
    gs = np.load(good)["gaussians"].copy()
    gs[0, 0, 6] = np.nan
    _rewrite(good, tmp_path / "nan.npz", gaussians=gs)
    with pytest.raises(InputError, match="NaN"):
        model.load(tmp_path / "nan.npz")
    _rewrite(good, tmp_path / "shape.npz", gaussians=gs[:-1])
    with pytest.raises(InputError, match="gaussians has shape"):
        model.load(tmp_path / "shape.npz")
    # an object array would need pickle: refused by the reader, reported as a bad file
    with zipfile.ZipFile(tmp_path / "obj.npz", "w") as zf, np.load(good) as z:
        for k in z.files:
            buf = io.BytesIO()
            if k == "faces":
                np.lib.format.write_array_header_1_0(
                    buf, {"descr": "|O", "fortran_order": False, "shape": (1,)}
                )
                buf.write(b"\x00" * 16)  # never read: the object dtype is refused first
            else:
                np.save(buf, z[k])
            zf.writestr(k + ".npy", buf.getvalue())
    with pytest.raises(InputError, match=r"obj\.npz"):
        model.load(tmp_path / "obj.npz")
    # an interrupted save leaves nothing behind
    with pytest.raises(InputError, match="does not exist"):
        model.save(tmp_path / "nodir" / "m.npz", sc.mesh, sc.materials, mf)
    assert not list(tmp_path.glob("*.partial*"))


def test_metadata_nested_too_deep_is_refused_not_a_recursion_error(tmp_path, fitted):
    # meta JSON nested 10^5 deep crashed the loader with RecursionError (exit 1)
    sc, mf = fitted
    model.save(tmp_path / "m.npz", sc.mesh, sc.materials, mf)
    deep = '{"format": "lobelight-model", "x": ' + "[" * 100_000 + "]" * 100_000 + "}"
    _rewrite(tmp_path / "m.npz", tmp_path / "deep.npz",
             meta=np.frombuffer(deep.encode(), dtype=np.uint8))  # fmt: skip
    with pytest.raises(InputError, match=r"deep\.npz: corrupt metadata: nested too deep"):
        model.load(tmp_path / "deep.npz")


def test_weights_near_the_float_range_are_refused(tmp_path, fitted):
    # weights of 3e38 loaded and rendered Inf pixels with exit 0
    sc, mf = fitted
    model.save(tmp_path / "m.npz", sc.mesh, sc.materials, mf)
    with np.load(tmp_path / "m.npz", allow_pickle=False) as z:
        g = z["gaussians"].copy()
    g[..., :3] = 3e38
    _rewrite(tmp_path / "m.npz", tmp_path / "huge.npz", gaussians=g)
    with pytest.raises(InputError, match=r"huge\.npz: a Gaussian carries .* of light"):
        model.load(tmp_path / "huge.npz")


def test_what_info_reads_render_draws(tmp_path, fitted):
    """One reader for both: a model file whose views are not the 92 geodesic views is refused
    at load (every renderer blends between them), and one of another SH order loads and
    renders (the lighting is projected to the model's order)."""
    sc, mf = fitted
    good = tmp_path / "good.npz"
    model.save(good, sc.mesh, sc.materials, mf)
    _rewrite(good, tmp_path / "turned.npz", views=np.roll(np.load(good)["views"], 1, axis=0))
    for cmd in ("info", "render"):
        args = [cmd, str(tmp_path / "turned.npz")]
        args += ["-o", str(tmp_path / "x.png"), "--backend", "torch"] if cmd == "render" else []
        assert main([*args, "-q"]) == 2

    order4 = dataclasses.replace(
        mf,
        diffuse=mf.diffuse[:, :16].contiguous(),
        bounce=None if mf.bounce is None else mf.bounce[:, :16].contiguous(),
    )
    model.save(tmp_path / "sh4.npz", sc.mesh, sc.materials, order4)
    assert model.load(tmp_path / "sh4.npz").sh_order == 4
    assert main(["info", str(tmp_path / "sh4.npz"), "-q"]) == 0
    out = tmp_path / "sh4.png"
    argv = ["render", str(tmp_path / "sh4.npz"), "-o", str(out), "--backend", "torch"]
    assert main([*argv, "--size", "32", "--samples", "1", "-q"]) == 0 and out.is_file()


def test_a_zip_bomb_is_refused_before_it_is_decompressed(tmp_path, fitted):
    """A model file with a member that deflates 1000:1 (200 MB of zeros in ~200 kB) is refused
    from the sizes the zip directory declares, before anything is decompressed: a read takes
    at most lobelight._container.declared_limit of the file's size."""
    sc, mf = fitted
    good = tmp_path / "good.npz"
    model.save(good, sc.mesh, sc.materials, mf)
    bomb = tmp_path / "bomb.npz"
    bomb.write_bytes(good.read_bytes())
    size = 200 << 20
    with zipfile.ZipFile(bomb, "a", compression=zipfile.ZIP_DEFLATED) as zf:
        with zf.open("pad.npy", "w", force_zip64=True) as f:
            header = io.BytesIO()
            np.lib.format.write_array_header_1_0(
                header, {"descr": "|u1", "fortran_order": False, "shape": (size,)}
            )
            f.write(header.getvalue())
            chunk = bytes(1 << 20)
            for _ in range(size >> 20):
                f.write(chunk)
    assert bomb.stat().st_size < 2 << 20
    with pytest.raises(InputError, match="would decompress to"):
        model.load(bomb)
    assert model.load(good).mesh.n_vertices == sc.mesh.n_vertices  # a real model is well within


def test_a_device_is_not_reported_as_a_missing_model():
    with pytest.raises(InputError, match="/dev/zero: is not a regular file"):
        model.load("/dev/zero")


@pytest.mark.parametrize("float16", [False, True])
def test_records_read_from_the_stored_rows_are_the_expansions(tmp_path, float16):
    """A model read from a file holds its Gaussians as the file stores them and expands them
    on first use; a range of records decoded straight from the stored rows (the GL renderer's
    records texture) is the same range of the expansion, dropped rows included (zero weight,
    unit sharpness, mean +y), for ranges that start and end inside a row of N = 3 Gaussians."""
    from lobelight.bench.synthetic import synthetic_model

    path = tmp_path / "m.npz"
    synthetic_model(200, 3, vary=True).save(path, float16=float16)
    stored = model.load(path).to("cpu").gaussians  # the CPU keeps the stored form
    whole = model.load(path).gaussians
    v, j, n = stored.shape
    w, mu, lam = whole.w.reshape(-1, 3), whole.mu.reshape(-1, 3), whole.lam.reshape(-1)
    keep = torch.from_numpy(np.load(path)["keep"]).reshape(-1)
    assert 0 < int(keep.sum()) < v * j  # some rows dropped, and so decoded as dropped
    assert bool((w.view(v * j, n, 3)[~keep] == 0).all())
    assert bool((lam.view(v * j, n)[~keep] == 1).all())
    count = v * j * n
    for a, b in [(0, count), (1, count - 2), (4, 5), (3 * 7 + 2, 3 * 900 + 1), (count - 1, count)]:
        got = stored.records(a, b)
        # the same arithmetic on the same numbers; a vectorised kernel and its scalar tail
        # may round the integral's expm1 differently (one float32 rounding)
        for x, y in zip(got, (w[a:b], mu[a:b], lam[a:b]), strict=True):
            torch.testing.assert_close(x, y, rtol=1e-6, atol=0)
    # the ranges were decoded without the expansion; reading w makes it, once
    assert stored._expanded is None
    assert stored.w is stored.w and stored._expanded is not None
    torch.testing.assert_close(stored.lam, whole.lam, rtol=1e-6, atol=0)


def test_a_read_model_moved_to_a_device_makes_its_arrays_there(tmp_path):
    """A read model holds its Gaussians and hit tiles as the file stores them (on the CPU);
    moved to a device, what it makes whole later (the expansion, the whole tiles) is made
    there, as every tensor it holds is (the meta device stands in for a GPU here)."""
    from lobelight.bench.synthetic import synthetic_model

    synthetic_model(200, 3, vary=True).save(tmp_path / "m.npz")  # a sharp lobe: hit tiles
    m = model.load(tmp_path / "m.npz")
    assert m.device.type == "cpu" and m.to("cpu").gaussians.w.device.type == "cpu"
    m = model.load(tmp_path / "m.npz").to("meta")
    assert m.device.type == "meta" and m.gaussians.w.device.type == "meta"
    assert all(t.device.type == "meta" for t in m.hits())
