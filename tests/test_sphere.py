"""Tests of lobelight.geometry.sphere: the 92 geodesic views, view location, quadrature sets,
rotations.

References are independent of the code under test: the views are rebuilt here from the rule
written in the module docstring; areas use the Van Oosterom-Strackee solid-angle formula;
quadratures are checked against closed forms and scipy's adaptive quadrature.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import integrate, special

from conftest import F64, random_dirs, triple, unit
from lobelight.errors import InputError
from lobelight.geometry import sphere as S

# ---------------------------------------------------------------------------------------------
# the 92 views


def test_views_count_and_unit_norm():
    v64 = S.geodesic_views(dtype=F64)
    v32 = S.geodesic_views()
    assert v64.shape == (92, 3) and v64.dtype == F64
    assert v32.shape == (92, 3) and v32.dtype == torch.float32
    # float64 normalisation is exact to a few ulps; float32 to a few float32 ulps
    assert torch.allclose(
        torch.linalg.vector_norm(v64, dim=-1), torch.ones(92, dtype=F64), atol=1e-15
    )
    assert torch.allclose(torch.linalg.vector_norm(v32, dim=-1), torch.ones(92), atol=1e-6)
    # all distinct: the closest pair is one mesh edge (~20 degrees) apart
    cos = v64 @ v64.T - 2 * torch.eye(92, dtype=F64)
    assert cos.max() < math.cos(math.radians(19))


def test_views_follow_documented_order():
    """Rebuild the 92 views from the rule in the module docstring, independently."""
    v = S.geodesic_views(dtype=F64)
    ico = []
    ico.append((0.0, 1.0, 0.0))
    y = 1 / math.sqrt(5)
    r = 2 / math.sqrt(5)
    for k in range(5):
        p = math.radians(72 * k)
        ico.append((r * math.sin(p), y, r * math.cos(p)))
    for k in range(5):
        p = math.radians(72 * k + 36)
        ico.append((r * math.sin(p), -y, r * math.cos(p)))
    ico.append((0.0, -1.0, 0.0))
    ico = np.array(ico)
    # the icosahedron's edges are its 30 closest pairs (63.4 degrees), sorted (i, j), i < j
    edges = sorted((i, j) for i in range(12) for j in range(i + 1, 12) if ico[i] @ ico[j] > 0.4)
    assert len(edges) == 30
    pts = list(ico)
    for i, j in edges:
        pts.append(2 * ico[i] + ico[j])
        pts.append(ico[i] + 2 * ico[j])
    for a, b, c in S.ICOSAHEDRON_FACES:
        pts.append(ico[a] + ico[b] + ico[c])
    ref = np.array(pts)
    ref /= np.linalg.norm(ref, axis=1, keepdims=True)
    # float64 construction in both: agreement to rounding
    np.testing.assert_allclose(v.numpy(), ref, atol=1e-14)
    # the icosahedron faces are its 20 mutually adjacent triples, all oriented outward
    faces = np.array(S.ICOSAHEDRON_FACES)
    assert len({tuple(sorted(f)) for f in faces.tolist()}) == 20
    assert (np.linalg.det(ico[faces]) > 0).all()


def test_views_deterministic_and_fresh_copies():
    a = S.geodesic_views()
    a[0] = 7.0  # writing into a result must not change the cache
    b = S.geodesic_views()
    c = S.geodesic_views()
    assert torch.equal(b, c)
    assert torch.equal(b[0], torch.tensor([0.0, 1.0, 0.0]))
    n = S.geodesic_neighbors()
    n[0].append(99)
    assert len(S.geodesic_neighbors()[0]) == 5


def test_views_symmetries():
    """The set is closed under the antipodal map and under 72-degree turns about +Y."""
    v = S.geodesic_views(dtype=F64)
    for w in (-v, v @ S.rotation_y(torch.tensor(2 * math.pi / 5, dtype=F64)).T):
        # each image is (to rounding) one of the views
        d = torch.linalg.vector_norm(w[:, None] - v[None], dim=-1).min(-1).values
        assert d.max() < 1e-12


def test_view_spacing():
    v = S.geodesic_views(dtype=F64)
    e = S.geodesic_edges()
    ang = torch.rad2deg(torch.acos((v[e[:, 0]] * v[e[:, 1]]).sum(-1).clamp(-1, 1)))
    # Frequency-3 geodesic icosahedron: mesh edges span 20.1 to 23.8 degrees (ratio 1.19).
    # The icosahedron's own edge is 63.4 degrees, so a third of it is ~21; anything outside
    # [19, 25] would mean a wrong subdivision.
    assert ang.min() > 19 and ang.max() < 25
    assert ang.max() / ang.min() < 1.2
    # each view's nearest other view is one of its mesh neighbours
    nn = (v @ v.T - 2 * torch.eye(92, dtype=F64)).argmax(-1)
    nbrs = S.geodesic_neighbors()
    assert all(int(nn[i]) in nbrs[i] for i in range(92))


def test_neighbors_counts_symmetry_and_table():
    nbrs = S.geodesic_neighbors()
    assert len(nbrs) == 92
    assert [len(r) for r in nbrs] == [5] * 12 + [6] * 80
    for i, ring in enumerate(nbrs):
        assert len(set(ring)) == len(ring) and i not in ring
        for j in ring:
            assert i in nbrs[j]
    table = S.geodesic_neighbor_table()
    assert table.shape == (92, 6) and table.dtype == torch.int64
    for i, ring in enumerate(nbrs):
        assert table[i].tolist() == ring + [-1] * (6 - len(ring))
    edges = S.geodesic_edges()
    assert edges.shape == (270, 2)
    assert sum(len(r) for r in nbrs) == 2 * 270


def test_faces_topology_orientation_and_area():
    v = S.geodesic_views(dtype=F64)
    f = S.geodesic_faces()
    assert f.shape == (180, 3) and f.dtype == torch.int64
    # Euler characteristic of a sphere: V - E + F = 92 - 270 + 180 = 2
    edges = {
        tuple(sorted(e)) for t in f.tolist() for e in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))
    }
    assert 92 - len(edges) + 180 == 2
    # every directed edge appears once: consistently oriented closed surface
    directed = [e for t in f.tolist() for e in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))]
    assert len(set(directed)) == 540
    assert all((b, a) in set(directed) for a, b in directed)
    # outward: det(a, b, c) > 0
    tri = v[f]
    assert (torch.linalg.det(tri) > 0).all()
    # spherical triangle areas (Van Oosterom & Strackee 1983) sum to 4 pi: the faces tile
    # the sphere without gaps or overlaps. float64, 180 terms: 1e-12 is ~1000 ulps of 4 pi.
    a, b, c = tri.unbind(1)
    num = torch.linalg.det(tri)
    den = 1 + (a * b).sum(-1) + (b * c).sum(-1) + (c * a).sum(-1)
    area = 2 * torch.atan2(num, den)
    assert abs(area.sum().item() - 4 * math.pi) < 1e-12
    # the mesh edges are exactly the neighbour relation
    assert sorted(edges) == [tuple(e) for e in S.geodesic_edges().tolist()]


def test_neighbor_rings_are_counter_clockwise_fans():
    """Consecutive ring members form an outward face with the centre view."""
    faces = {tuple(t) for t in S.geodesic_faces().tolist()}
    rot = faces | {(b, c, a) for a, b, c in faces} | {(c, a, b) for a, b, c in faces}
    for i, ring in enumerate(S.geodesic_neighbors()):
        assert ring[0] == min(ring)
        for k in range(len(ring)):
            assert (i, ring[k], ring[(k + 1) % len(ring)]) in rot


# ---------------------------------------------------------------------------------------------
# locate_views


def _check_location(d: torch.Tensor, idx: torch.Tensor, bary: torch.Tensor, tol: float):
    v = S.geodesic_views(dtype=d.dtype)
    assert (bary >= 0).all() and (bary <= 1).all()
    assert torch.allclose(bary.sum(-1), torch.ones_like(bary[..., 0]), atol=tol)
    rec = torch.nn.functional.normalize((bary.unsqueeze(-1) * v[idx]).sum(-2), dim=-1)
    assert torch.allclose(rec, torch.nn.functional.normalize(d, dim=-1), atol=tol)
    # idx is one of the mesh triangles (as a set of corners)
    faces = {tuple(sorted(t)) for t in S.geodesic_faces().tolist()}
    assert all(tuple(sorted(t)) in faces for t in idx.reshape(-1, 3).tolist())


@settings(max_examples=200, deadline=None)
@given(triple)
def test_locate_views_property(t):
    d = unit(t)
    idx, bary = S.locate_views(d)
    assert idx.shape == (3,) and bary.shape == (3,)
    # float64 throughout: weights and reconstruction exact to ~1e-15; 1e-12 leaves margin
    _check_location(d, idx, bary, 1e-12)


def test_locate_views_batched_float32():
    d = random_dirs(20000, torch.float32).reshape(100, 200, 3)
    idx, bary = S.locate_views(d, chunk=4096)  # several chunks
    assert idx.shape == (100, 200, 3) and bary.shape == (100, 200, 3)
    assert idx.dtype == torch.int64 and bary.dtype == torch.float32
    # float32: a few ulps of the unit-length quantities
    _check_location(d, idx, bary, 2e-6)


def test_locate_views_exact_at_vertices():
    for dtype, tol in ((F64, 1e-14), (torch.float32, 1e-6)):  # rounding of the triple products
        v = S.geodesic_views(dtype=dtype)
        idx, bary = S.locate_views(v)
        w_self = (bary * (idx == torch.arange(92).unsqueeze(-1))).sum(-1)
        assert (w_self > 1 - tol).all()


def test_locate_views_on_edges_and_continuity():
    v = S.geodesic_views(dtype=F64)
    # On an edge midpoint, the two edge ends share the weight and the third corner gets 0.
    e = S.geodesic_edges()
    mid = torch.nn.functional.normalize(v[e[:, 0]] + v[e[:, 1]], dim=-1)
    idx, bary = S.locate_views(mid)
    on_edge = (idx == e[:, :1]) | (idx == e[:, 1:])
    assert (on_edge.sum(-1) == 2).all()
    assert (bary[~on_edge] < 1e-12).all()
    assert torch.allclose(bary[on_edge], torch.full((540,), 0.5, dtype=F64), atol=1e-12)

    # Interpolating random per-view values along great circles: no jumps. Barycentric
    # interpolation over triangles ~0.37 rad across with values in [0, 1] changes by at most
    # ~|grad| * step <= step / (triangle height ~0.3 rad); a jump at an edge would be O(0.1-1).
    f = torch.rand(92, dtype=F64)
    g = torch.Generator().manual_seed(1)
    n_steps = 20000
    t = torch.linspace(0, 2 * math.pi, n_steps, dtype=F64)
    for _ in range(5):
        a, b = torch.nn.functional.normalize(torch.randn(2, 3, generator=g, dtype=F64), dim=-1)
        b = torch.nn.functional.normalize(b - (a @ b) * a, dim=-1)
        path = t.cos().unsqueeze(-1) * a + t.sin().unsqueeze(-1) * b  # (n, 3)
        idx, bary = S.locate_views(path)
        vals = (bary * f[idx]).sum(-1)
        step = 2 * math.pi / (n_steps - 1)
        assert (vals[1:] - vals[:-1]).abs().max() < 5 * step


def test_locate_views_numpy_and_shapes():
    d = random_dirs(10).numpy()
    idx, bary = S.locate_views(d)
    assert isinstance(idx, np.ndarray) and isinstance(bary, np.ndarray)
    assert idx.dtype == np.int64 and bary.dtype == np.float64
    idx, bary = S.locate_views(torch.zeros(0, 3))
    assert idx.shape == (0, 3)
    with pytest.raises(InputError, match="dirs"):
        S.locate_views(torch.zeros(4, 2))


def test_locate_views_device(device):
    d = random_dirs(100, torch.float32).to(device)
    idx, bary = S.locate_views(d)
    assert idx.device.type == device and bary.device.type == device
    assert bary.dtype == torch.float32
    _, bary_c = S.locate_views(d.cpu())
    assert torch.allclose(bary.cpu(), bary_c, atol=1e-5)


# ---------------------------------------------------------------------------------------------
# quadrature: Fibonacci and local caps


def _sg_cap_reference(lam: float, beta: float, theta_max: float) -> float:
    """∫ over the cap theta <= theta_max about +axis of exp(lam (mu.w - 1)), mu at angle beta.

    Azimuth done in closed form (∫ exp(a cos phi) dphi = 2 pi I0(a)), polar angle by scipy's
    adaptive quadrature with the lobe's peak and width as break points.
    """

    def f(th):
        a = lam * math.sin(th) * math.sin(beta)
        return math.exp(lam * (math.cos(th - beta) - 1)) * special.i0e(a) * math.sin(th)

    w = 1 / math.sqrt(lam)
    pts = sorted({min(max(beta + k * w, 0.0), theta_max) for k in (-8, -3, -1, 0, 1, 3, 8)})
    val, _ = integrate.quad(f, 0, theta_max, points=pts, limit=400, epsabs=0, epsrel=1e-13)
    return 2 * math.pi * val


def test_fibonacci_sphere():
    d, w = S.fibonacci(20000, dtype=F64)
    assert d.shape == (20000, 3) and w.shape == (20000,)
    assert torch.allclose(torch.linalg.vector_norm(d, dim=-1), torch.ones(20000, dtype=F64))
    assert abs(w.sum().item() - 4 * math.pi) < 1e-10
    x, y, _ = d.unbind(-1)
    # Low-degree moments: ∫x² = ∫y² = 4π/3, ∫xy = ∫y = 0. Measured errors at n = 2e4 are
    # <= 3.3e-6 (Fibonacci error decays roughly like 1/n for smooth f); 2e-5 gives margin.
    assert abs((w * x * x).sum().item() - 4 * math.pi / 3) < 2e-5
    assert abs((w * y * y).sum().item() - 4 * math.pi / 3) < 2e-5
    assert abs((w * x * y).sum().item()) < 2e-5
    assert abs((w * y).sum().item()) < 1e-12  # equal-area bands: exact for functions of y
    d32, w32 = S.fibonacci(10)
    assert d32.dtype == torch.float32 and w32.dtype == torch.float32


def test_fibonacci_hemisphere():
    d, w = S.fibonacci(5000, hemisphere=True, dtype=F64)
    assert (d[:, 1] > 0).all()
    assert abs(w.sum().item() - 2 * math.pi) < 1e-10
    # ∫_{y>0} y dω = π; the y nodes are band midpoints, exact for functions linear in y
    assert abs((w * d[:, 1]).sum().item() - math.pi) < 1e-10
    with pytest.raises(InputError, match="n"):
        S.fibonacci(0)


@pytest.mark.parametrize("lam", [1e-3, 0.1, 1.0, 10.0, 100.0, 1e3, 1e4, 1e5])
def test_local_grid_integrates_centred_sg(lam):
    from lobelight.lobes import sg

    mu = random_dirs(4)
    for dtype, tol in ((F64, 1e-12), (torch.float32, 1e-5)):
        # float64: Gauss-Legendre on exp(-lam s) over lam s in [0, ln 1e6] is converged to
        # rounding with 16 nodes. float32: a 1e-5 bound; measured <= 6e-7 (rounding
        # of the float32 directions, to which the chord form of G is insensitive).
        dirs, w = S.local_grid(mu.to(dtype), lam)
        assert dirs.shape == (4, 512, 3) and w.shape == (4, 512) and dirs.dtype == dtype
        est = (w * sg.evaluate(dirs, mu.to(dtype).unsqueeze(-2), lam)).sum(-1).double()
        s_max = min(2.0, math.log(1e6) / lam)
        ref = 2 * math.pi * -math.expm1(-lam * s_max) / lam  # closed form over the cap
        assert ((est / ref) - 1).abs().max() < tol


def test_cap_grid_constant_polynomials_and_cosine_lobes():
    mu = random_dirs(3)
    tmax = torch.tensor([0.05, 1.0, math.pi], dtype=F64)
    dirs, w = S.cap_grid(mu, tmax, n_theta=8, n_phi=16)
    assert dirs.shape == (3, 128, 3)
    # inside the cap, unit length
    assert ((dirs * mu.unsqueeze(1)).sum(-1) >= torch.cos(tmax).unsqueeze(-1) - 1e-12).all()
    assert torch.allclose(torch.linalg.vector_norm(dirs, dim=-1), torch.ones(3, 128, dtype=F64))
    c0 = torch.cos(tmax)
    # constant: cap area 2π(1 - cos θmax)
    assert torch.allclose(w.sum(-1), 2 * math.pi * (1 - c0), rtol=1e-13)
    # cos^n lobe about the centre: ∫ c^n = 2π (1 - c0^(n+1)) / (n + 1) (for c0 >= 0; in general
    # the same antiderivative); exact for n <= 2 n_theta - 1 = 15
    c = (dirs * mu.unsqueeze(1)).sum(-1)
    for n in (1, 2, 5, 15):
        ref = 2 * math.pi * (1 - c0 ** (n + 1)) / (n + 1)
        assert torch.allclose((w * c**n).sum(-1), ref, rtol=1e-12, atol=1e-13)
    # an off-axis quadratic (a.ω)²: a = a_par mu + a_perp, ∫ = 2π a_par² ∫c² dc
    # + π |a_perp|² ∫(1 - c²) dc; degree 2 <= n_phi - 1, so exact
    a = torch.tensor([0.3, -1.2, 0.7], dtype=F64)
    a_par = mu @ a
    a_perp2 = (a * a).sum() - a_par**2
    i_c2 = (1 - c0**3) / 3
    i_1mc2 = (1 - c0) - i_c2
    ref = 2 * math.pi * a_par**2 * i_c2 + math.pi * a_perp2 * i_1mc2
    assert torch.allclose((w * (dirs @ a) ** 2).sum(-1), ref, rtol=1e-12)


@pytest.mark.parametrize("lam,beta_sigmas", [(3.0, 0.7), (200.0, 1.5), (1e4, 1.0), (1e4, 3.0)])
def test_cap_grid_off_centre_sg_against_scipy(lam, beta_sigmas):
    """An SG whose peak is off the cap centre: the product rule is not tailored to it."""
    from lobelight.lobes import sg

    beta = beta_sigmas / math.sqrt(lam)
    theta_max = min(
        math.pi, float(S.lobe_cap_angle(torch.tensor(lam, dtype=F64), eps=1e-10)) + beta
    )
    up = torch.tensor([0.0, 1.0, 0.0], dtype=F64)
    mu = torch.tensor([math.sin(beta), math.cos(beta), 0.0], dtype=F64)
    dirs, w = S.cap_grid(up, theta_max, n_theta=32, n_phi=64)
    est = (w * sg.evaluate(dirs, mu, lam)).sum().item()
    ref = _sg_cap_reference(lam, beta, theta_max)
    # 32 x 64 nodes on a cap a few lobe-widths wide: measured error <= 3e-14 (1e-9 with 16 x 32
    # when the peak is 3 widths off centre); 1e-10 leaves room for other BLAS summation orders
    assert abs(est / ref - 1) < 1e-10


def test_local_grid_batched_widths_match_single_calls():
    mu = random_dirs(6).reshape(2, 3, 3)
    lam = torch.tensor([[1.0, 50.0, 1e4], [1e-2, 3.0, 1e5]], dtype=F64)
    dirs, w = S.local_grid(mu, lam, n_theta=4, n_phi=6)
    assert dirs.shape == (2, 3, 24, 3) and w.shape == (2, 3, 24)
    for i in range(2):
        for j in range(3):
            d1, w1 = S.local_grid(mu[i, j], lam[i, j], n_theta=4, n_phi=6)
            assert torch.allclose(dirs[i, j], d1) and torch.allclose(w[i, j], w1)
    # one width shared by all centres broadcasts too
    d2, _ = S.local_grid(mu, 10.0, n_theta=4)
    assert d2.shape == (2, 3, 32, 3)


def test_lobe_cap_angle():
    lam = torch.tensor([1e-3, 1.0, 100.0, 1e5], dtype=F64)
    th = S.lobe_cap_angle(lam, eps=1e-6)
    g = torch.exp(lam * (torch.cos(th) - 1))
    wide = th >= math.pi - 1e-12
    assert torch.allclose(g[~wide], torch.full_like(g[~wide], 1e-6), rtol=1e-9)
    assert wide[:2].all()  # broad lobes cover the sphere
    # small-angle estimate sqrt(2 ln(1/eps)/lam) for sharp lobes (O(theta^2) relative)
    assert abs(th[-1].item() / math.sqrt(2 * math.log(1e6) / 1e5) - 1) < 1e-3


def test_local_grid_numpy_and_device(device):
    mu = np.array([[0.0, 0.0, 1.0]])
    d, w = S.local_grid(mu, np.array([10.0]))
    assert isinstance(d, np.ndarray) and d.dtype == np.float64 and d.shape == (1, 512, 3)
    mu_t = torch.tensor([[0.0, 0.0, 1.0]], device=device)
    d, w = S.local_grid(mu_t, 10.0)
    assert d.device.type == device and d.dtype == torch.float32 and w.dtype == torch.float32


# ---------------------------------------------------------------------------------------------
# frames and rotations


def _assert_rotation(R: torch.Tensor, tol: float) -> None:
    eye = torch.eye(3, dtype=R.dtype).expand_as(R)
    assert torch.allclose(R @ R.transpose(-1, -2), eye, atol=tol)
    assert torch.allclose(torch.linalg.det(R), torch.ones(R.shape[:-2], dtype=R.dtype), atol=tol)


@settings(max_examples=100, deadline=None)
@given(triple, st.floats(-10, 10))
def test_rotation_matrix_property(t, angle):
    k = unit(t)
    R = S.rotation_matrix(k, torch.tensor(angle, dtype=F64))
    _assert_rotation(R, 1e-13)
    assert torch.allclose(R @ k, k, atol=1e-14)  # the axis is fixed
    # rotation angle from the trace: 1 + 2 cos(angle)
    assert abs(torch.trace(R).item() - (1 + 2 * math.cos(angle))) < 1e-12


def test_rotation_y_and_spherical_convention():
    theta = torch.tensor([0.3, 1.2, 2.9], dtype=F64)
    phi = torch.tensor([-2.0, 0.1, 3.0], dtype=F64)
    a = torch.tensor(0.7, dtype=F64)
    d = S.spherical_to_direction(theta, phi)
    assert torch.allclose(d @ S.rotation_y(a).T, S.spherical_to_direction(theta, phi + a))
    up = torch.tensor([0.0, 1.0, 0.0], dtype=F64)
    assert torch.allclose(S.rotation_y(a), S.rotation_matrix(up, a))
    # documented anchors: theta = 0 is +Y; phi = 0 is +Z; phi = pi/2 is +X
    h = math.pi / 2
    anchors = S.spherical_to_direction(
        torch.tensor([0.0, h, h], dtype=F64), torch.tensor([0.0, 0.0, h], dtype=F64)
    )
    x_, y_, z_ = torch.eye(3, dtype=F64)
    assert torch.allclose(anchors, torch.stack([y_, z_, x_]), atol=1e-15)
    # right-handed: a quarter turn about +Y takes +Z to +X
    assert torch.allclose(S.rotation_y(torch.tensor(h, dtype=F64)) @ z_, x_, atol=1e-15)


@settings(max_examples=100, deadline=None)
@given(triple)
def test_spherical_round_trip(t):
    d = unit(t)
    theta, phi = S.direction_to_spherical(d)
    assert 0 <= theta <= math.pi and -math.pi <= phi <= math.pi
    assert torch.allclose(S.spherical_to_direction(theta, phi), d, atol=1e-14)


@settings(max_examples=100, deadline=None)
@given(triple, triple)
def test_rotation_between_property(ta, tb):
    a, b = unit(ta), unit(tb)
    R = S.rotation_between(a, b)
    _assert_rotation(R, 1e-13)
    assert torch.allclose(R @ a, b, atol=1e-13)
    # minimal: the angle is the angle between a and b, the axis is perpendicular to both
    cos_rot = (torch.trace(R) - 1) / 2
    assert abs(cos_rot - a @ b) < 1e-12


def test_rotation_between_antipodal_and_equal():
    a = random_dirs(50)
    for b, tol in (
        (-a, 1e-14),  # exactly opposite: a half-turn about a perpendicular axis
        (torch.nn.functional.normalize(-a + 1e-9 * random_dirs(50, seed=3), dim=-1), 1e-13),
        (a, 1e-15),  # identical: the identity
    ):
        R = S.rotation_between(a, b)
        _assert_rotation(R, 1e-13)
        assert torch.allclose((R @ a.unsqueeze(-1))[..., 0], b, atol=tol)
    assert torch.allclose(S.rotation_between(a, a), torch.eye(3, dtype=F64).expand(50, 3, 3))
    # float32 antipodal: still a proper rotation taking a to -a (float32 rounding)
    a32 = a.float()
    R = S.rotation_between(a32, -a32)
    _assert_rotation(R, 1e-5)
    assert torch.allclose((R @ a32.unsqueeze(-1))[..., 0], -a32, atol=1e-5)


@settings(max_examples=200, deadline=None)
@given(triple)
def test_frame_property(t):
    n = unit(t)
    tt, b, nn = S.frame(n)
    m = torch.stack([tt, b, nn])
    assert torch.allclose(m @ m.T, torch.eye(3, dtype=F64), atol=1e-14)
    assert torch.allclose(torch.linalg.cross(tt, b), n, atol=1e-14)  # right-handed, t x b = n
    local = S.to_local(n, n)
    assert torch.allclose(local, torch.tensor([0.0, 0.0, 1.0], dtype=F64), atol=1e-14)


def test_frame_poles_and_round_trip():
    # exact poles, including the -Z singularity of Frisvad's original and -0.0
    n = torch.tensor(
        [[0, 0, 1], [0, 0, -1], [1, 0, -0.0], [1, 0, 0], [0, -1, 0], [1e-20, 0, -1]], dtype=F64
    )
    t, b, nn = S.frame(n)
    for u, v in ((t, b), (b, nn), (nn, t)):
        assert ((u * v).sum(-1).abs() < 1e-14).all()
    assert torch.allclose(torch.linalg.cross(t, b), n, atol=1e-14)
    assert torch.isfinite(torch.cat([t, b])).all()
    v = random_dirs(len(n), seed=5) * 2.5
    assert torch.allclose(S.to_world(S.to_local(v, n), n), v, atol=1e-14)


def test_euler_to_matrix():
    ang = torch.tensor([[0.3, -1.1, 2.0], [0.0, 0.5, 0.0]], dtype=F64)
    e = torch.eye(3, dtype=F64)
    R = S.euler_to_matrix(ang)
    ref = (
        S.rotation_matrix(e[2], ang[:, 2])
        @ S.rotation_matrix(e[1], ang[:, 1])
        @ S.rotation_matrix(e[0], ang[:, 0])
    )
    assert torch.allclose(R, ref)
    assert torch.allclose(R[1], S.rotation_y(ang[1, 1]))
    R2 = S.euler_to_matrix(ang, order="YXY")
    ref2 = S.rotation_y(ang[:, 2]) @ S.rotation_matrix(e[0], ang[:, 1]) @ S.rotation_y(ang[:, 0])
    assert torch.allclose(R2, ref2)
    with pytest.raises(InputError, match="order"):
        S.euler_to_matrix(ang, order="xw")


def test_random_rotation_uniform():
    n = 20000
    R = S.random_rotation(n, generator=torch.Generator().manual_seed(0), dtype=F64)
    assert R.shape == (n, 3, 3)
    _assert_rotation(R, 1e-13)
    # Haar measure: E[R] = 0 and E[R_ij R_kl] = δ_ik δ_jl / 3. Each entry of the mean has
    # std sqrt(1/(3n)) = 0.0041; 0.025 is 6 sigma. Second moments: std of R_ij² is
    # sqrt(E[R_ij⁴] - 1/9) = sqrt(1/5 - 1/9) / sqrt(n) = 0.0021; 0.015 is 7 sigma.
    assert R.mean(0).abs().max() < 0.025
    assert ((R * R).mean(0) - 1 / 3).abs().max() < 0.015
    # a fixed vector lands uniformly: mean ~0, mean of y² ~1/3
    d = R @ torch.tensor([0.0, 1.0, 0.0], dtype=F64)
    assert d.mean(0).abs().max() < 0.025
    # the rotation angle has density (1 - cos a)/π: E[cos a] = -1/2, i.e. E[trace] = 0
    assert abs(R.diagonal(dim1=-2, dim2=-1).sum(-1).mean().item()) < 0.05  # std ~1/sqrt(n)
    # reproducible from a generator; float32 by default
    R1 = S.random_rotation(3, generator=torch.Generator().manual_seed(7))
    R2 = S.random_rotation(3, generator=torch.Generator().manual_seed(7))
    assert torch.equal(R1, R2) and R1.dtype == torch.float32


def test_rotation_functions_numpy_and_device(device):
    a = np.array([[1.0, 0.0, 0.0]])
    b = np.array([[0.0, 0.0, 1.0]])
    R = S.rotation_between(a, b)
    assert isinstance(R, np.ndarray) and R.shape == (1, 3, 3)
    np.testing.assert_allclose(R[0] @ a[0], b[0], atol=1e-15)
    at = torch.tensor([[1.0, 0.0, 0.0]], device=device)
    bt = torch.tensor([[0.0, 0.0, 1.0]], device=device)
    for out in (
        S.rotation_between(at, bt),
        S.rotation_matrix(at, 0.3),
        S.rotation_y(torch.tensor([0.2], device=device)),
        S.frame(at)[0],
        S.to_local(bt, at),
        S.spherical_to_direction(at[:, 0], at[:, 1]),
        S.random_rotation(2, device=device),
        S.geodesic_views(device=device),
    ):
        assert out.device.type == device and out.dtype == torch.float32
    t, _ = S.direction_to_spherical(np.array([0.0, 1.0, 0.0]))
    assert isinstance(t, np.ndarray) and t == 0.0


def test_triangle_candidates_hold_the_located_triangle():
    # the renderer tests only a texel's candidates: they must contain the triangle that the
    # full scan (locate_views) picks, for random directions and for the hard ones, next to the
    # geodesic vertices and edges (where several triangles and texels meet)
    from lobelight.geometry import cubemap, sphere

    res = 32
    cand = sphere.triangle_candidates(res)
    assert cand.shape[:3] == (6, res, res) and 1 <= cand.shape[-1] <= 8
    g = torch.Generator().manual_seed(5)
    views = sphere.geodesic_views(dtype=torch.float64)
    edges = sphere.geodesic_edges()
    t = torch.rand(4000, 1, generator=g, dtype=torch.float64)
    mid = views[edges[:, 0]] * t[:270] + views[edges[:, 1]] * (1 - t[:270])
    d = torch.cat(
        [
            torch.randn(100_000, 3, generator=g, dtype=torch.float64),
            views.repeat(50, 1) + 1e-3 * torch.randn(92 * 50, 3, generator=g, dtype=torch.float64),
            mid.repeat(20, 1) + 1e-4 * torch.randn(270 * 20, 3, generator=g, dtype=torch.float64),
        ]
    )
    d = torch.nn.functional.normalize(d, dim=-1)
    idx, _ = sphere.locate_views(d)
    f, u, v = cubemap.direction_to_face_uv(d)
    col = ((u + 1) * res / 2).floor().long().clamp(0, res - 1)
    row = ((v + 1) * res / 2).floor().long().clamp(0, res - 1)
    c = cand[f, row, col]  # (M, K)
    planes, faces = sphere.face_planes(torch.float64, torch.device("cpu"))
    m = (d @ planes).reshape(-1, 180, 3).amin(-1)
    mc = torch.where(c >= 0, m.gather(1, c.clamp_min(0)), torch.full(c.shape, -1e30).double())
    best = c.gather(1, mc.argmax(1, keepdim=True))[:, 0]
    # the same triangle, or one tied with it (a direction exactly on a shared edge)
    same = (faces[best] == idx).all(-1) | (m.gather(1, best[:, None])[:, 0] >= m.amax(1) - 1e-12)
    assert bool(same.all())
