"""Haar wavelets on cube maps against their defining properties.

References: the transform's matrix built column by column (orthonormality), the closed-form Haar
basis functions (layout), Parseval's identity (truncation error = dropped energy), and direct
top-k selection with numpy. float64 checks sit at rounding level; float32 round trips at the
1e-6 relative the transform is held to (log2 R levels of sums of four numbers: ~1e-7 measured).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lobelight.errors import InputError
from lobelight.lobes import haar


def random_cube(res: int, ch: int = 3, *, seed: int = 0, dtype=np.float64) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=(6, res, res, ch)).astype(dtype)


@pytest.mark.parametrize("res", [1, 2, 8, 32])
def test_round_trip(res):
    x = random_cube(res)
    np.testing.assert_allclose(haar.inverse(haar.forward(x)), x, rtol=0, atol=1e-13)
    x32 = x.astype(np.float32)
    y32 = haar.inverse(haar.forward(x32))
    assert y32.dtype == np.float32
    # float32: each level adds ~1 ulp of the running magnitude; measured 3e-7 of max |x|
    assert np.abs(y32 - x32).max() <= 1e-6 * np.abs(x32).max()


def test_transform_matrix_is_orthonormal_and_per_face():
    res = 4
    n = 6 * res * res
    # channel k of this cube is the k-th unit texel, so channel k of forward() is column k of W
    eye = np.eye(n).reshape(n, 6, res, res).transpose(1, 2, 3, 0)  # (6, R, R, n)
    w = haar.forward(eye).transpose(3, 0, 1, 2).reshape(n, n).T  # (coeff, texel)
    np.testing.assert_allclose(w @ w.T, np.eye(n), rtol=0, atol=1e-14)
    face = np.repeat(np.arange(6), res * res)
    assert np.all(w[face[:, None] != face[None, :]] == 0)  # faces do not mix


def test_parseval():
    x = random_cube(16, seed=1)
    c = haar.forward(x)
    np.testing.assert_allclose((c**2).sum(), (x**2).sum(), rtol=1e-13)


def test_layout_matches_closed_form_basis_functions():
    res, f = 8, 2
    h = res // 2

    def basis_fn(i, j):
        c = np.zeros((6, res, res, 1))
        c[f, i, j] = 1
        return haar.inverse(c)[f, :, :, 0]

    left = np.arange(res) < h
    top = np.arange(res)[:, None] < h
    # scaling coefficient: the constant 1/R (unit norm over R^2 texels)
    np.testing.assert_allclose(basis_fn(0, 0), np.full((res, res), 1 / res), atol=1e-15)
    # coarsest details: +- 1/R over halves of the face
    np.testing.assert_allclose(basis_fn(0, 1), np.where(left, 1, -1) / res * np.ones((res, 1)))
    np.testing.assert_allclose(basis_fn(1, 0), np.where(top, 1, -1) / res * np.ones((1, res)))
    np.testing.assert_allclose(basis_fn(1, 1), np.where(top == left, 1, -1) / res)
    # a finest diagonal detail: [[+, -], [-, +]] / 2 on the 2x2 block (i, j) = (1, 2)
    ref = np.zeros((res, res))
    ref[2:4, 4:6] = [[0.5, -0.5], [-0.5, 0.5]]
    np.testing.assert_allclose(basis_fn(h + 1, h + 2), ref, atol=1e-15)
    # a constant-per-face cube has only its scaling coefficients, face value x R
    vals = np.arange(1.0, 7.0)[:, None, None, None] * np.ones((6, res, res, 2))
    c = haar.forward(vals)
    np.testing.assert_allclose(c[:, 0, 0, 0], np.arange(1.0, 7.0) * res, rtol=1e-15)
    c[:, 0, 0] = 0
    np.testing.assert_allclose(c, 0, atol=1e-14)


@pytest.mark.parametrize("by", ["norm", "luminance", "per_channel"])
def test_truncate_keeps_k_and_error_is_dropped_energy(by):
    x = random_cube(16, seed=2)
    c = haar.forward(x)
    k = 97
    t = haar.truncate(c, k, by=by)
    kept = t != 0  # random normal data: no kept coefficient is 0
    if by == "per_channel":
        np.testing.assert_array_equal(kept.reshape(-1, 3).sum(0), [k, k, k])
    else:
        # same positions in every channel
        assert kept.all(-1).sum() == k and kept.any(-1).sum() == k
    # Parseval: the texel-space squared error is the energy of what was dropped
    err = ((haar.inverse(t) - x) ** 2).sum()
    np.testing.assert_allclose(err, ((c - t) ** 2).sum(), rtol=1e-12)
    # every kept coefficient ranks at least as high as every dropped one
    if by == "norm":
        score = np.linalg.norm(c, axis=-1)
    elif by == "luminance":
        score = np.abs(c @ np.array([0.2126, 0.7152, 0.0722]))
    else:
        score = np.abs(c)
    mask = kept.any(-1) if by != "per_channel" else kept
    if by == "per_channel":
        for ch in range(3):
            assert score[..., ch][mask[..., ch]].min() >= score[..., ch][~mask[..., ch]].max()
    else:
        assert score[mask].min() >= score[~mask].max()


def test_norm_ranking_is_best_shared_choice():
    # ranking by the channel norm drops the least energy of any shared-position choice
    x = random_cube(8, seed=3)
    errs = {by: ((haar.approximate(x, 40, by=by) - x) ** 2).sum() for by in ("norm", "luminance")}
    assert errs["norm"] <= errs["luminance"]


def test_truncate_extremes_and_approximate():
    x = random_cube(8, seed=4)
    c = haar.forward(x)
    n = 6 * 8 * 8
    np.testing.assert_array_equal(haar.truncate(c, n), c)
    np.testing.assert_allclose(haar.approximate(x, n), x, rtol=0, atol=1e-13)
    np.testing.assert_array_equal(haar.truncate(c, 0), 0)
    np.testing.assert_array_equal(haar.approximate(x, 50), haar.inverse(haar.truncate(c, 50)))
    errs = [((haar.approximate(x, k) - x) ** 2).sum() for k in (1, 10, 100, 300)]
    assert np.all(np.diff(errs) <= 0)  # more coefficients never cost accuracy


def test_numpy_in_numpy_out():
    x = random_cube(4, dtype=np.float32)
    for out in (haar.forward(x), haar.inverse(x), haar.truncate(x, 5), haar.approximate(x, 5)):
        assert isinstance(out, np.ndarray) and out.dtype == np.float32 and out.shape == x.shape


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_torch_keeps_dtype_and_device(device, dtype):
    x = torch.randn(6, 8, 8, 3, device=device, dtype=dtype)
    outs = (haar.forward(x), haar.inverse(x), haar.truncate(x, 5), haar.approximate(x, 5))
    for out in outs:
        assert isinstance(out, torch.Tensor) and out.dtype == dtype and out.device == x.device
    # same numbers as on the CPU (float rounding only)
    torch.testing.assert_close(haar.forward(x).cpu(), haar.forward(x.cpu()))


def test_bad_inputs_name_the_input():
    with pytest.raises(InputError, match="power of two"):
        haar.forward(np.zeros((6, 6, 6, 3)))
    with pytest.raises(InputError, match="cube"):
        haar.forward(np.zeros((6, 4, 8, 3)))
    with pytest.raises(InputError, match="k"):
        haar.truncate(np.zeros((6, 4, 4, 3)), 97)
    with pytest.raises(InputError, match="by"):
        haar.truncate(np.zeros((6, 4, 4, 3)), 3, by="energy")
    with pytest.raises(InputError, match="luminance"):
        haar.truncate(np.zeros((6, 4, 4, 2)), 3, by="luminance")
