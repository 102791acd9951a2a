"""Spherical harmonics against independent references.

References: scipy's complex ``sph_harm_y`` (converted to the real, phase-free basis here), product
Gauss–Legendre x uniform-azimuth quadrature (nodes from scipy, not from the module), scipy's
rotations, the Bessel closed form of the spherical-Gaussian zonal coefficients, adaptive
quadrature, and Ramamoorthi–Hanrahan's clamped-cosine coefficients. float64 results sit at
rounding level (~1e-14); the tolerances below leave a margin of about 100x over what was measured
and say why where they are looser.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import integrate
from scipy.spatial.transform import Rotation
from scipy.special import ive, roots_legendre, sph_harm_y

from lobelight.errors import InputError
from lobelight.geometry import cubemap
from lobelight.lobes import sh

# ------------------------------------------------------------------------------------------------
# references


def sphere_rule(n_z: int, n_phi: int) -> tuple[np.ndarray, np.ndarray]:
    """Product rule: Gauss–Legendre in z (exact to degree 2 n_z - 1) x n_phi uniform azimuths
    (exact for e^{i k phi}, |k| < n_phi). Returns dirs (M, 3) and weights (M,) summing to 4 pi."""
    z, wz = roots_legendre(n_z)
    phi = 2 * np.pi * (np.arange(n_phi) + 0.5) / n_phi  # offset: no node shared with sh's rule
    s = np.sqrt(1 - z * z)
    dirs = np.stack(
        [
            np.outer(s, np.cos(phi)),
            np.outer(s, np.sin(phi)),
            np.repeat(z[:, None], n_phi, 1),
        ],
        -1,
    ).reshape(-1, 3)
    return dirs, np.repeat(wz * 2 * np.pi / n_phi, n_phi)


def scipy_real_sh(dirs: np.ndarray, order: int) -> np.ndarray:
    """Real, phase-free orthonormal SH from scipy's complex ones: (N, 3) -> (N, order**2)."""
    theta = np.arccos(np.clip(dirs[:, 2], -1, 1))
    phi = np.mod(np.arctan2(dirs[:, 1], dirs[:, 0]), 2 * np.pi)
    out = np.empty((len(dirs), order * order))
    for l in range(order):
        for m in range(-l, l + 1):
            y = sph_harm_y(l, abs(m), theta, phi)
            # (-1)^m removes scipy's Condon–Shortley phase
            if m > 0:
                out[:, l * l + l + m] = math.sqrt(2) * (-1) ** m * y.real
            elif m < 0:
                out[:, l * l + l + m] = math.sqrt(2) * (-1) ** m * y.imag
            else:
                out[:, l * l + l] = y.real
    return out


def random_dirs(n: int, rng: np.random.Generator) -> np.ndarray:
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


# ------------------------------------------------------------------------------------------------
# basis


def test_first_bands_closed_form():
    """Pins the documented convention: polar axis +Z, no Condon–Shortley phase."""
    rng = np.random.default_rng(1)
    d = random_dirs(50, rng)
    x, y, z = d.T
    c0, c1, c2 = (
        0.5 / math.sqrt(math.pi),
        math.sqrt(3 / (4 * math.pi)),
        math.sqrt(15 / (4 * math.pi)),
    )
    ref = np.stack(
        [
            np.full_like(x, c0),
            c1 * y,
            c1 * z,
            c1 * x,
            c2 * x * y,
            c2 * y * z,
            c2 * (3 * z * z - 1) / (2 * math.sqrt(3)),
            c2 * x * z,
            c2 * (x * x - y * y) / 2,
        ],
        -1,
    )
    # products of O(1) numbers in float64: 1e-13 is ~1000 ulps
    np.testing.assert_allclose(sh.basis(d, 3), ref, rtol=0, atol=1e-13)


@pytest.mark.parametrize("order", [10, 30])
def test_basis_matches_scipy(order):
    rng = np.random.default_rng(2)
    # random directions plus the six axes (poles included, where theta/phi are degenerate)
    d = np.concatenate([random_dirs(300, rng), np.eye(3), -np.eye(3)])
    got = sh.basis(d, order)
    assert got.shape == (len(d), order * order)
    # measured <= 3e-14 at order 30 (recurrence + scipy's own rounding); held to 1e-10
    np.testing.assert_allclose(got, scipy_real_sh(d, order), rtol=0, atol=1e-10)


def test_basis_lower_order_is_prefix_and_dirs_are_normalised():
    rng = np.random.default_rng(3)
    d = random_dirs(20, rng)
    b10 = sh.basis(d, 10)
    np.testing.assert_array_equal(sh.basis(d, 4), b10[:, :16])
    np.testing.assert_allclose(sh.basis(3.5 * d, 10), b10, rtol=0, atol=1e-13)


@pytest.mark.parametrize("order", [10, 30])
def test_orthonormality(order):
    # the rule integrates products of two order-`order` harmonics exactly (degree 2 order - 2)
    dirs, w = sphere_rule(order + 2, 2 * order + 3)
    b = sh.basis(dirs, order)
    gram = b.T @ (w[:, None] * b)
    # float64 sums of ~1e4 terms of size <= 1: measured 1e-13 at order 30
    np.testing.assert_allclose(gram, np.eye(order * order), rtol=0, atol=1e-11)


# ------------------------------------------------------------------------------------------------
# projection and reconstruction


@pytest.mark.parametrize("order", [1, 5, 10])
def test_project_band_limited_function_is_exact(order):
    rng = np.random.default_rng(4)
    coeffs = rng.normal(size=(order * order, 3))
    # exact for f * Y_k with f of order <= 10: degree <= 18 in z, azimuthal frequency <= 18
    dirs, w = sphere_rule(12, 21)
    values = scipy_real_sh(dirs, order) @ coeffs  # sampled through the independent reference
    got = sh.project(values, dirs, w, order)
    assert got.shape == (order * order, 3)
    # float64: rounding only (measured ~1e-14)
    np.testing.assert_allclose(got, coeffs, rtol=0, atol=1e-11)
    # float32 input, held to 1e-5: values carry 6e-8 relative rounding, |f| <= ~15 here, and
    # the error is bounded by that times sum |w Y| <= sqrt(4 pi) -> ~3e-6
    got32 = sh.project(values.astype(np.float32), dirs, w.astype(np.float32), order)
    assert got32.dtype == np.float32
    np.testing.assert_allclose(got32, coeffs, rtol=0, atol=1e-5)


def test_project_scalar_values_and_batched_dirs():
    rng = np.random.default_rng(5)
    coeffs = rng.normal(size=25)
    dirs, w = sphere_rule(8, 15)
    values = scipy_real_sh(dirs, 5) @ coeffs
    # leading shape (8, 15) instead of flat: same result, no channel axis in or out
    got = sh.project(values.reshape(8, 15), dirs.reshape(8, 15, 3), w.reshape(8, 15), 5)
    assert got.shape == (25,)
    np.testing.assert_allclose(got, coeffs, rtol=0, atol=1e-12)


def test_reconstruct_matches_reference_sum():
    rng = np.random.default_rng(6)
    coeffs = rng.normal(size=(100, 2))
    d = random_dirs(40, rng).reshape(4, 10, 3)
    got = sh.reconstruct(coeffs, d)
    assert got.shape == (4, 10, 2)
    ref = scipy_real_sh(d.reshape(-1, 3), 10) @ coeffs
    np.testing.assert_allclose(got.reshape(-1, 2), ref, rtol=0, atol=1e-11)
    assert sh.reconstruct(coeffs[:, 0], d).shape == (4, 10)


def test_project_cubemap_constant():
    c = np.array([1.0, 2.0, 3.0])
    cube = np.broadcast_to(c, (6, 16, 16, 3)).astype(np.float64)
    got = sh.project_cubemap(cube, 6)
    # exact solid angles sum to 4 pi to rounding, so coefficient 0 is sqrt(4 pi) c to rounding
    np.testing.assert_allclose(got[0], math.sqrt(4 * math.pi) * c, rtol=1e-13)
    # bands 1-3 vanish exactly by the cube's octahedral symmetry (no invariant harmonic there)
    np.testing.assert_allclose(got[1:16], 0, atol=1e-13)
    # band 4 holds the cubic harmonic, which the texel-centre (midpoint) rule only sees to
    # O(1/R^2): measured 1.7 c/R^2 at R = 8..64; bound 2 c/R^2
    assert np.all(np.abs(got[16:25]) < 2 * c / 16**2)
    # float32 cube: coefficient 0 to float32 rounding of the input and output
    got32 = sh.project_cubemap(cube.astype(np.float32), 2)
    assert got32.dtype == np.float32
    np.testing.assert_allclose(got32[0], math.sqrt(4 * math.pi) * c, rtol=1e-6)


def test_project_cubemap_linear_functions_axis_convention():
    # channels x, y, z of the texel directions: band 1 is (y, z, x) * sqrt(4 pi/3) exactly,
    # because sum x_c^2 Omega = sum y_c^2 Omega = sum z_c^2 Omega by symmetry and they add to
    # 4 pi; so this checks cubemap's face layout against sh's axes to rounding
    cube = cubemap.texel_directions(8, dtype=torch.float64)
    got = sh.project_cubemap(cube, 2)
    ref = math.sqrt(4 * math.pi / 3) * torch.eye(3, dtype=torch.float64)[[1, 2, 0]]
    torch.testing.assert_close(got[1:4], ref, rtol=0, atol=1e-13)
    torch.testing.assert_close(got[0], torch.zeros(3, dtype=torch.float64), rtol=0, atol=1e-13)


def test_project_envmap_duck_typed():
    rng = np.random.default_rng(7)
    cube = rng.random((6, 8, 8, 3)).astype(np.float32)

    class FakeEnv:
        def to_cubemap(self, res):
            assert res == 8
            return torch.from_numpy(cube)

    got = sh.project_envmap(FakeEnv(), 5, res=8)
    assert isinstance(got, torch.Tensor)
    np.testing.assert_array_equal(got.numpy(), sh.project_cubemap(cube, 5))
    with pytest.raises(InputError, match="env"):
        sh.project_envmap(object(), 5)


# ------------------------------------------------------------------------------------------------
# rotation


def random_rotations(n: int, seed: int) -> np.ndarray:
    return Rotation.random(n, random_state=seed).as_matrix()


def test_rotation_matches_projection_of_rotated_function():
    order = 10
    rng = np.random.default_rng(8)
    coeffs = rng.normal(size=(order * order, 2))
    dirs, w = sphere_rule(12, 21)  # exact for the order-10 products, as above
    for R in random_rotations(3, seed=9):
        # f(R^T w): row vectors w^T R are R^T w
        values = scipy_real_sh(dirs @ R, order) @ coeffs
        ref = sh.project(values, dirs, w, order)
        got = sh.rotation_matrix(R, order) @ coeffs
        # float64 rounding (measured ~1e-14); the float32 bound is 1e-5
        np.testing.assert_allclose(got, ref, rtol=0, atol=1e-10)
        np.testing.assert_allclose(sh.rotate(coeffs, R), ref, rtol=0, atol=1e-10)


@pytest.mark.parametrize("order", [10, 30])
def test_rotation_orthogonal_block_diagonal_and_composes(order):
    r1, r2 = random_rotations(2, seed=10)
    d1, d2 = sh.rotation_matrix(r1, order), sh.rotation_matrix(r2, order)
    n2 = order * order
    # float64 rounding, measured 9e-14 at order 30
    np.testing.assert_allclose(d1 @ d1.T, np.eye(n2), rtol=0, atol=1e-11)
    np.testing.assert_allclose(sh.rotation_matrix(r1 @ r2, order), d1 @ d2, rtol=0, atol=1e-11)
    band = np.repeat(np.arange(order), 2 * np.arange(order) + 1)
    assert np.all(d1[band[:, None] != band[None, :]] == 0)


def test_rotation_band1_moves_a_linear_lobe():
    # f(w) = a . w has band-1 coefficients sqrt(4 pi/3) (a_y, a_z, a_x); f(R^T w) = (R a) . w
    a = np.array([0.3, -0.5, 0.8])
    c = np.zeros(4)
    c[1:] = math.sqrt(4 * math.pi / 3) * a[[1, 2, 0]]
    for R in random_rotations(3, seed=11):
        ra = R @ a
        np.testing.assert_allclose(
            sh.rotate(c, R)[1:], math.sqrt(4 * math.pi / 3) * ra[[1, 2, 0]], rtol=0, atol=1e-14
        )


def test_rotation_about_polar_axis_closed_form():
    # rotating by alpha about +Z shifts phi: cos m(phi - alpha), sin m(phi - alpha)
    order, alpha = 6, 0.7
    D = sh.rotation_matrix(Rotation.from_rotvec([0, 0, alpha]).as_matrix(), order)
    ref = np.zeros_like(D)
    for l in range(order):
        ref[l * l + l, l * l + l] = 1
        for m in range(1, l + 1):
            p, n = l * l + l + m, l * l + l - m
            ref[p, p] = ref[n, n] = math.cos(m * alpha)
            ref[n, p] = math.sin(m * alpha)
            ref[p, n] = -math.sin(m * alpha)
    np.testing.assert_allclose(D, ref, rtol=0, atol=1e-13)


def test_rotation_batched_and_float32():
    Rs = random_rotations(4, seed=12).reshape(2, 2, 3, 3)
    D = sh.rotation_matrix(Rs, 5)
    assert D.shape == (2, 2, 25, 25)
    # batched and single matmuls may round differently (1 ulp seen on another BLAS)
    np.testing.assert_allclose(D[1, 0], sh.rotation_matrix(Rs[1, 0], 5), rtol=0, atol=1e-14)
    D32 = sh.rotation_matrix(torch.tensor(Rs, dtype=torch.float32), 5)
    assert D32.dtype == torch.float32
    # float32 input matrices are orthogonal to ~1e-7; the result is rounded to float32
    torch.testing.assert_close(D32, torch.tensor(D, dtype=torch.float32), rtol=0, atol=1e-5)
    c = np.random.default_rng(13).normal(size=(25, 3))
    assert sh.rotate(c, Rs).shape == (2, 2, 25, 3)


unit_quaternions = st.lists(st.floats(-1, 1, allow_nan=False), min_size=4, max_size=4).filter(
    lambda q: np.linalg.norm(q) > 0.1
)


@settings(max_examples=25, deadline=None)
@given(q=unit_quaternions)
def test_rotate_is_pointwise_composition(q):
    # property: reconstruct(rotate(c, R), w) == f(R^T w), checked pointwise without projection
    R = Rotation.from_quat(np.asarray(q) / np.linalg.norm(q)).as_matrix()
    rng = np.random.default_rng(14)
    c = rng.normal(size=64)
    d = random_dirs(30, rng)
    np.testing.assert_allclose(
        sh.reconstruct(sh.rotate(c, R), d), sh.reconstruct(c, d @ R), rtol=0, atol=1e-11
    )


def test_rotation_rejects_non_orthogonal():
    with pytest.raises(InputError, match="R"):
        sh.rotation_matrix(np.diag([1.0, 2.0, 1.0]), 3)
    with pytest.raises(InputError, match="R"):
        sh.rotation_matrix(np.eye(4), 3)


# ------------------------------------------------------------------------------------------------
# zonal functions


def sg_zonal_bessel(lam: np.ndarray, order: int) -> np.ndarray:
    """sqrt(4 pi (2l+1)) e^{-lam} i_l(lam), with scipy's exponentially scaled I_{l+1/2}."""
    lam = np.asarray(lam, dtype=np.float64)[:, None]
    l = np.arange(order)
    return np.sqrt(4 * np.pi * (2 * l + 1)) * np.sqrt(np.pi / (2 * lam)) * ive(l + 0.5, lam)


def test_sg_zonal_matches_bessel_closed_form():
    lam = np.logspace(-3, 4, 29)
    got = sh.sg_zonal(lam, 30)
    assert got.shape == (29, 30) and got.dtype == np.float64
    ref = sg_zonal_bessel(lam, 30)
    # accuracy is absolute relative to z_0 (high bands of a wide lobe are ~1e-40): measured
    # 1e-12 z_0, set by the quadrature's end weights
    assert np.all(np.abs(got - ref).max(1) < 1e-10 * ref[:, 0])


@pytest.mark.parametrize("lam", [0.5, 5.0, 50.0])
def test_sg_zonal_matches_adaptive_quadrature(lam):
    got = sh.sg_zonal(np.array([lam]), 8)[0]
    l = np.arange(8)
    legendre = [np.polynomial.legendre.Legendre.basis(k) for k in l]

    def integrand(t, k):
        return math.exp(lam * (t - 1)) * legendre[k](t)

    # absolute 1e-13 / relative 1e-11 is what quad reaches here without roundoff warnings
    integrals = [
        integrate.quad(integrand, -1, 1, args=(k,), epsabs=1e-13, epsrel=1e-11, limit=200)[0]
        for k in l
    ]
    ref = 2 * np.pi * np.sqrt((2 * l + 1) / (4 * np.pi)) * np.array(integrals)
    # quad's tolerance plus the module's 1e-12 z_0 floor
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-10 * ref[0])


def test_sg_zonal_integral_and_extremes():
    lam = np.array([1e-3, 1.0, 100.0, 1e4, 1e6])
    z0 = sh.sg_zonal(lam, 3)[:, 0]
    # docs/conventions.md: integral of G = 2 pi (1 - e^{-2 lam}) / lam = sqrt(4 pi) z_0
    np.testing.assert_allclose(
        math.sqrt(4 * np.pi) * z0, 2 * np.pi * -np.expm1(-2 * lam) / lam, rtol=1e-12
    )
    # lam = 0 is the constant 1: sqrt(4 pi) in band 0, nothing else
    # (Gauss–Legendre rounding on P_l over [-1, 1]: measured 2e-14)
    np.testing.assert_allclose(
        sh.sg_zonal(np.array([0.0]), 5)[0], [math.sqrt(4 * np.pi), 0, 0, 0, 0], atol=1e-12
    )
    # float32 with a huge lam: no overflow, positive low bands
    z32 = sh.sg_zonal(torch.tensor([1e4, 1e6]), 10)
    assert z32.dtype == torch.float32 and torch.isfinite(z32).all() and (z32[:, :3] > 0).all()
    with pytest.raises(InputError, match="lam"):
        sh.sg_zonal(np.array([-1.0]), 3)


def test_clamped_cosine_matches_ramamoorthi_hanrahan():
    order = 20
    got = sh.clamped_cosine_zonal(order, dtype=torch.float64)
    l = np.arange(order)
    a_hat = np.zeros(order)  # A_l = sqrt(4 pi/(2l+1)) z_l, closed form (RH 2001, eq. 8)
    a_hat[0], a_hat[1] = np.pi, 2 * np.pi / 3
    for k in range(2, order, 2):
        a_hat[k] = (
            2
            * np.pi
            * (-1) ** (k // 2 - 1)
            / ((k + 2) * (k - 1))
            * math.factorial(k)
            / (2**k * math.factorial(k // 2) ** 2)
        )
    ref = a_hat / np.sqrt(4 * np.pi / (2 * l + 1))
    # exact-quadrature polynomial integrals: rounding only
    np.testing.assert_allclose(got.numpy(), ref, rtol=0, atol=1e-14)


def test_zonal_to_sh_matches_projection_of_sg():
    lam, order = 3.0, 10
    axis = np.array([0.2, 0.9, -0.4]) / np.linalg.norm([0.2, 0.9, -0.4])
    dirs, w = sphere_rule(40, 80)  # SG is smooth at lam = 3: converged far below 1e-12
    ref = sh.project(np.exp(lam * (dirs @ axis - 1)), dirs, w, order)
    got = sh.zonal_to_sh(sh.sg_zonal(np.array([lam]), order)[0], axis)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-11)


@pytest.mark.parametrize("lam", [1.0, 5.0])
def test_zonal_convolve_matches_brute_force_cube_convolution(lam):
    rng = np.random.default_rng(15)
    res, order = 8, 24
    cube = rng.random((6, res, res, 3))
    # SH route: project the texel sum, scale by the SG kernel, evaluate
    zonal = sh.sg_zonal(np.array([lam]), order)[0]  # (order,)
    coeffs = sh.zonal_convolve(sh.project_cubemap(cube, order), zonal)
    dirs = random_dirs(7, rng)
    got = sh.reconstruct(coeffs, dirs)
    # brute force: sum over texels L_t Omega_t exp(lam (w . t - 1))
    t = cubemap.texel_directions(res, dtype=torch.float64).numpy().reshape(-1, 3)
    omega = cubemap.texel_solid_angles(res, dtype=torch.float64).numpy().reshape(-1)
    ref = np.exp(lam * (dirs @ t.T - 1)) @ (omega[:, None] * cube.reshape(-1, 3))
    # both sides are the same texel sum; the only difference is the SG's SH tail beyond band 23,
    # below 1e-15 for lam <= 5 (e^{-lam} i_24(lam) ~ lam^24 / 49!!)
    np.testing.assert_allclose(got, ref, rtol=1e-10, atol=0)


def test_zonal_convolve_batched_kernels():
    c = np.random.default_rng(16).normal(size=(16, 3))
    zonal = sh.sg_zonal(np.array([1.0, 10.0]), 4)  # (2, 4)
    got = sh.zonal_convolve(c, zonal)
    assert got.shape == (2, 16, 3)
    scale = np.sqrt(4 * np.pi / (2 * np.arange(4) + 1)) * zonal[1]
    np.testing.assert_allclose(
        got[1], np.repeat(scale, 2 * np.arange(4) + 1)[:, None] * c, rtol=1e-15
    )
    with pytest.raises(InputError, match="zonal"):
        sh.zonal_convolve(c, zonal[:, :3])


# ------------------------------------------------------------------------------------------------
# backends, dtypes, devices, errors


def test_numpy_in_numpy_out():
    rng = np.random.default_rng(17)
    d = random_dirs(5, rng).astype(np.float32)
    c = rng.normal(size=(9, 3)).astype(np.float32)
    outs = [
        sh.basis(d, 3),
        sh.project(rng.random((5, 3)).astype(np.float32), d, np.ones(5, np.float32), 3),
        sh.reconstruct(c, d),
        sh.rotation_matrix(np.eye(3, dtype=np.float32), 3),
        sh.rotate(c, np.eye(3, dtype=np.float32)),
        sh.sg_zonal(np.float32([2.0]), 3),
        sh.zonal_convolve(c, np.float32([1, 2, 3])),
        sh.zonal_to_sh(np.float32([1, 2, 3]), d),
        sh.project_cubemap(np.ones((6, 2, 2, 1), np.float32), 3),
    ]
    for out in outs:
        assert isinstance(out, np.ndarray) and out.dtype == np.float32


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_torch_keeps_dtype_and_device(device, dtype):
    kw = {"device": device, "dtype": dtype}
    d = torch.nn.functional.normalize(torch.randn(5, 3, **kw), dim=-1)
    c = torch.randn(9, 3, **kw)
    R = torch.tensor(random_rotations(1, seed=18)[0], **kw)
    outs = [
        sh.basis(d, 3),
        sh.project(torch.rand(5, 3, **kw), d, torch.ones(5, **kw), 3),
        sh.reconstruct(c, d),
        sh.rotation_matrix(R, 3),
        sh.rotate(c, R),
        sh.sg_zonal(torch.tensor([2.0], **kw), 3),
        sh.zonal_convolve(c, torch.tensor([1.0, 2.0, 3.0], **kw)),
        sh.zonal_to_sh(torch.tensor([1.0, 2.0, 3.0], **kw), d),
        sh.project_cubemap(torch.ones(6, 2, 2, 1, **kw), 3),
        sh.clamped_cosine_zonal(3, **kw),
    ]
    for out in outs:
        assert isinstance(out, torch.Tensor)
        assert out.dtype == dtype and out.device.type == device
    # same numbers on every device (float32 rounding)
    torch.testing.assert_close(
        sh.reconstruct(c, d).cpu(), sh.reconstruct(c.cpu(), d.cpu()), rtol=1e-5, atol=1e-5
    )


def test_basis_and_rotation_are_differentiable():
    # float64 gradcheck: analytic gradients against finite differences (fitting will use them)
    d = torch.randn(4, 3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda x: sh.basis(x, 4), (d,))
    R = torch.tensor(random_rotations(1, seed=19)[0], requires_grad=True)
    # finite-difference steps (1e-6) leave R orthogonal well within the 1e-3 input check
    assert torch.autograd.gradcheck(lambda r: sh.rotation_matrix(r, 3), (R,))


def test_bad_inputs_name_the_input():
    with pytest.raises(InputError, match="dirs"):
        sh.basis(np.zeros((4, 2)), 3)
    with pytest.raises(InputError, match="order"):
        sh.basis(np.zeros((4, 3)), 0)
    with pytest.raises(InputError, match="coeffs"):
        sh.reconstruct(np.zeros(10), np.zeros((4, 3)))
    with pytest.raises(InputError, match="weights"):
        sh.project(np.zeros(4), np.zeros((4, 3)), np.zeros(3), 2)
    with pytest.raises(InputError, match="cube"):
        sh.project_cubemap(np.zeros((5, 4, 4, 3)), 2)
