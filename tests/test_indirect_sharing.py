"""Indirect glossy without noise: each vertex's paths shared across its views, and a Gaussian
no sharper than the lobe that gathers its light (``Transport.indirect_lobes``).

Checked here: the shared estimate of every view is unbiased against path tracing each view on
its own, and far less noisy; the Gaussians' sharpness never exceeds the gathering lobe's
(``transport.gathering_sharpness``), which matches a quadrature of the lobe; and on a rough
concave shape (a GGX metal box corner) the indirect light across the floor's vertices is
smooth, as the converged light is (the rough metal's mottled spots, where the object sees
itself: one Gaussian per view from its own few paths).
"""

from __future__ import annotations

import math

import pytest
import torch

from lobelight import brdf, scene, transport
from lobelight.geometry import cubemap, sphere
from lobelight.lobes import sg
from lobelight.scene import Materials, Scene
from test_interreflection import _corner, _nearest


def _metal_corner(alpha: float, n: int = 9):
    mesh, r = _corner(n)
    v_n = mesh.n_vertices
    spec = brdf.GGX(alpha=torch.full((v_n,), alpha), specular=torch.full((v_n, 3), 0.9))
    sc = Scene(
        mesh, Materials(torch.zeros(v_n, 3), spec), "builtin", scene.builtin("sphere:0").camera
    )
    return sc, r


def _carried(g) -> torch.Tensor:
    """(B, J, 3) the light the Gaussians carry: weight times integral."""
    return (g.w * sg.integral(g.lam)[..., None]).sum(2)


def test_shared_paths_are_unbiased_per_view_and_less_noisy():
    # every view's estimate from 16 paths per view, shared across the 92 views, against each
    # view path-traced on its own (the binned density of Transport.indirect, 2048 paths)
    sc, r = _metal_corner(0.3)
    tr = transport.Transport(sc)
    v = torch.tensor(
        [_nearest(sc.mesh, [0.25, 0.0, 0.25], r), _nearest(sc.mesh, [0.5, 0.5, 0.0], r)]
    )
    views = sphere.geodesic_views()
    om = cubemap.texel_solid_angles(8).reshape(-1)[:, None]
    ref = (tr.indirect(v, views, paths=2048, res=8, generator=torch.Generator().manual_seed(1))
           * om).sum(2).sum(-1)  # fmt: skip
    seeds = range(8)
    shared = torch.stack([
        _carried(tr.indirect_lobes(v, views, paths=16, generator=torch.Generator().manual_seed(s)))
        .sum(-1) for s in seeds
    ])  # fmt: skip
    own = torch.stack([
        (tr.indirect(v, views, paths=16, res=8, generator=torch.Generator().manual_seed(s))
         * om).sum(2).sum(-1) for s in seeds
    ])  # fmt: skip
    lit = ref > 0.1
    assert int(lit.sum()) >= 60  # the walls reflect a real share at most views
    # per view: the reference's relative noise ~4 % (2048 paths), the mean of 8 shared
    # estimates' ~3 % (measured ~8 % each): 25 % is 5 sigma of their difference
    ratio = shared.mean(0)[lit] / ref[lit]
    assert float((ratio - 1).abs().max()) < 0.25, ratio
    # all views together: their noise averages out (the shared estimates are correlated
    # across views, so not by the square root of their count)
    total = float(shared.mean(0)[lit].sum() / ref[lit].sum())
    assert abs(total - 1) < 0.03, total
    # the spread of one estimate: a view's own 16 paths ~0.44 of the light, shared ~0.08
    spread = lambda x: float((x.std(0)[lit] / ref[lit]).mean())  # noqa: E731
    assert spread(shared) < 0.4 * spread(own), (spread(shared), spread(own))


def test_the_indirect_gaussian_is_no_sharper_than_the_lobe_that_gathers_it():
    # the light reflected off the object reaches the vertex through its lobe: seen through
    # it, it is convolved with it, so its Gaussian is capped at the lobe's sharpness (with
    # the light kept: the weight grows as the Gaussian widens)
    sc, _ = _metal_corner(0.25)
    tr = transport.Transport(sc)
    v = torch.arange(0, sc.mesh.n_vertices, 5)
    views = sphere.geodesic_views()
    g = tr.indirect_lobes(v, views, paths=16, generator=torch.Generator().manual_seed(2))
    lit = g.w[:, :, 0].amax(-1) > 0  # (B, J)
    bi, ji = lit.nonzero(as_tuple=True)
    assert bi.numel() > 1000
    cap = transport.gathering_sharpness(
        sc.materials.specular.take(v[bi]), sc.mesh.normals[v[bi]], views[ji]
    )
    # the cap comes from a table by the view's elevation: within 3 % of the lobe's own
    assert bool((g.lam[bi, ji, 0] <= cap * 1.03).all())
    # and it binds: left alone, the paths make some Gaussians sharper than the lobe (lone
    # paths, a few paths close together; measured: 8 % of these)
    assert float((g.lam[bi, ji, 0] >= cap * 0.97).float().mean()) > 0.03


@pytest.mark.parametrize("alpha", [0.02, 0.1, 0.25, 0.5])
def test_gathering_sharpness_matches_a_quadrature(alpha):
    # ln 2 over the weighted median 1 - cos of f cos about its mean: from a 16^2 stratified
    # grid of samples against a 256^2-per-face cube-map quadrature of the lobe (texels of
    # under 0.5 degrees, a tenth of the sharpest lobe's median angle); the grid's median is
    # quantised to its 256 samples: within 20 % (measured: 15 %)
    spec = brdf.GGX(alpha=alpha, specular=torch.tensor([0.9, 0.8, 0.6]))
    d = cubemap.texel_directions(256).reshape(-1, 3)
    om = cubemap.texel_solid_angles(256).reshape(-1).double()
    n = torch.tensor([0.0, 0.0, 1.0])
    for deg in (0.0, 60.0, 80.0):
        t = math.radians(deg)
        view = torch.tensor([math.sin(t), 0.0, math.cos(t)])
        got = float(transport.gathering_sharpness(spec, n[None], view[None])[0])
        f = spec.eval(d, view.expand_as(d), n.expand_as(d)).sum(-1).double()
        dens = f * d[:, 2].double().clamp_min(0) * om
        mean = torch.nn.functional.normalize((dens[:, None] * d.double()).sum(0), dim=0)
        gap = 0.5 * ((d.double() - mean) ** 2).sum(-1)
        gap, order = gap.sort()
        cum = dens[order].cumsum(0)
        want = math.log(2) / float(gap[int((cum < 0.5 * cum[-1]).sum())])
        assert abs(got / want - 1) < 0.2, (deg, got, want)
    below = torch.tensor([[0.0, 0.6, -0.8]])
    assert math.isinf(float(transport.gathering_sharpness(spec, n[None], below)[0]))


def test_indirect_light_on_a_rough_concave_corner_is_smooth():
    # regression: on a rough metal (GGX 0.25) where the object sees itself, each (vertex,
    # view)'s Gaussian from its own 16 paths (one escaped path or none, made a narrow lobe)
    # mottled the glossy light with spots the path tracer's smooth blur lacks. The floor of a
    # metal box corner at one view, lit by two broad Gaussian lights: the indirect radiance's
    # vertex-to-vertex detail (the discrete Laplacian's energy over the floor's interior)
    # against the converged light's (4096 paths of that view alone)
    n = 9
    sc, r = _metal_corner(0.25, n)
    tr = transport.Transport(sc)
    floor = torch.arange(n * n)  # the floor's vertices come first, row by row
    views = sphere.geodesic_views()
    into = r @ torch.nn.functional.normalize(torch.tensor([1.0, 1.0, 1.0]), dim=0)
    j = int((views @ into).argmax())  # looking into the corner from above it
    lights = (r @ torch.tensor([[1.0, 0.3, 0.2], [0.2, 0.5, 1.0]]).T).T
    lights = torch.nn.functional.normalize(lights, dim=-1)
    lams, amps = torch.tensor([3.0, 10.0]), torch.tensor([1.0, 3.0])

    def radiance(g, k):  # (n * n,) the light the view-k Gaussians carry from the lights
        w, mu, lam = g.w[:, k, 0].sum(-1), g.mu[:, k, 0], g.lam[:, k, 0]
        return sum(w * amps[i] * sg.inner_product(mu, lam, lights[i], lams[i]) for i in range(2))

    def detail(x):
        x = x.reshape(n, n)
        lap = x[1:-1, 1:-1] - 0.25 * (x[:-2, 1:-1] + x[2:, 1:-1] + x[1:-1, :-2] + x[1:-1, 2:])
        return float((lap**2).sum())

    gen = torch.Generator().manual_seed(1)
    truth = radiance(tr.indirect_lobes(floor, views[j : j + 1], paths=4096, generator=gen), 0)
    ours = radiance(
        tr.indirect_lobes(floor, views, paths=16, generator=torch.Generator().manual_seed(10)), j
    )
    assert float(truth.mean()) > 0.3  # the walls send the floor a real share
    # unbiased on the whole: the 16-path estimate's noise summed over 81 vertices, ~2 %
    assert abs(float(ours.sum() / truth.sum()) - 1) < 0.05
    own = radiance(
        tr.indirect_lobes(
            floor, views[j : j + 1], paths=16, generator=torch.Generator().manual_seed(10)
        ),
        0,
    )
    # measured over six seeds: 26-60 times the converged light's detail (which holds its own
    # noise; the vertices at the walls' feet see the walls' light since their rays start off
    # the walls, transport.vertex_origins, and the converged light is smooth there); a
    # Gaussian per view from its own 16 paths: 150-230 times (sharing: 0.12-0.33 of that,
    # seed by seed)
    assert detail(ours) < 80 * detail(truth), (detail(ours), detail(truth))
    assert detail(ours) < 0.5 * detail(own), (detail(ours), detail(own))
