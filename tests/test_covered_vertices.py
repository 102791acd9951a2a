"""Vertices whose ray origins are covered (lobelight.transport.vertex_origins).

A floor meeting a wall at a hard edge (split vertices: one position, two normals): the floor
vertex's normal lies in the wall's plane, so rays lifted along it start on the wall. A quad whose
corners lie under a frame just above its rim: the corners see nothing although the quad's
interior is open. A convex sphere: nothing covers anything, nothing may change.
"""

from __future__ import annotations

import math

import torch

from lobelight import envmap, model, scene, transport
from lobelight.geometry import cubemap, octahedral, sphere
from lobelight.reference import paths as reference
from lobelight.scene import Materials, Mesh, Scene


def _grid(origin, du, dv, nu: int, nv: int, normal):
    """A planar grid of ``(nu + 1) x (nv + 1)`` vertices from ``origin`` along ``du, dv``:
    positions (N, 3), faces (M, 3) counter-clockwise about ``normal``, normals (N, 3)."""
    o, du, dv = (torch.tensor(x, dtype=torch.float32) for x in (origin, du, dv))
    i, j = torch.meshgrid(torch.arange(nu + 1), torch.arange(nv + 1), indexing="ij")
    pos = o + (i.reshape(-1, 1) / nu) * du + (j.reshape(-1, 1) / nv) * dv
    k = (i * (nv + 1) + j)[:-1, :-1].reshape(-1)
    a, b, c, d = k, k + (nv + 1), k + (nv + 1) + 1, k + 1  # (i,j) (i+1,j) (i+1,j+1) (i,j+1)
    faces = torch.cat([torch.stack([a, b, c], 1), torch.stack([a, c, d], 1)])
    n = torch.tensor(normal, dtype=torch.float32)
    if float(torch.linalg.cross(du, dv) @ n) < 0:
        faces = faces.flip(1)
    return pos, faces, n.expand_as(pos).clone()


def _join(*parts, name: str) -> Mesh:
    """One mesh of several grids, their vertices kept apart (split at shared positions)."""
    pos, faces, nrm, base = [], [], [], 0
    for p, f, n in parts:
        pos.append(p)
        faces.append(f + base)
        nrm.append(n)
        base += p.shape[0]
    return Mesh(torch.cat(pos), torch.cat(faces), torch.cat(nrm), name)


def _scene(mesh: Mesh, albedo: float = 0.8) -> Scene:
    diffuse = torch.full((mesh.n_vertices, 3), albedo)
    return Scene(mesh, Materials(diffuse), "constant")


def _find(mesh: Mesh, point, normal) -> int:
    """The vertex at ``point`` with ``normal``."""
    p = torch.tensor(point, dtype=torch.float32)
    n = torch.tensor(normal, dtype=torch.float32)
    hit = ((mesh.vertices - p).norm(dim=-1) < 1e-6) & ((mesh.normals - n).norm(dim=-1) < 1e-6)
    return int(hit.nonzero()[0, 0])


def _cosine_visibility(tr: transport.Transport, vidx: torch.Tensor) -> torch.Tensor:
    """Cosine-weighted visible fraction ``(B,)`` on a 32^2 cube map, normalised by the same
    quadrature of the open hemisphere (so an open vertex gets 1 exactly)."""
    d = cubemap.texel_directions(32).reshape(-1, 3)
    om = cubemap.texel_solid_angles(32).reshape(-1)
    cos = (tr.mesh.normals[vidx] @ d.T).clamp_min(0) * om  # (B, D)
    return (cos * tr.visibility(vidx, d)).sum(-1) / cos.sum(-1)


def _room(walls: int) -> Mesh:
    """A floor (z = 0, normal +z) over x in [0, 2], y in [-2, 2] and a wall at x = 0 (normal
    +x), with ``walls=2`` a second one at y = -2 (normal +y), both 2 high, each its own
    vertices (hard edges: the positions they share are split, one normal each)."""
    floor = _grid((0, -2, 0), (2, 0, 0), (0, 4, 0), 4, 8, (0, 0, 1))
    wall_x = _grid((0, -2, 0), (0, 4, 0), (0, 0, 2), 8, 4, (1, 0, 0))
    wall_y = _grid((0, -2, 0), (2, 0, 0), (0, 0, 2), 4, 4, (0, 1, 0))
    return _join(floor, wall_x, *([wall_y] if walls == 2 else []), name="room")


def test_floor_vertex_at_a_walls_foot_sees_half_its_hemisphere():
    # regression: the floor vertex's lift along +z kept its origin in the wall's plane x = 0,
    # so every ray started on the wall and hit it at distance 0 (visibility 0, a black seam)
    one, two = _room(1), _room(2)
    foot = _find(one, (0, 0, 0), (0, 0, 1))  # the floor at the foot of the wall
    wall_foot = _find(one, (0, 0, 0), (1, 0, 0))  # the wall at the floor, the other side
    corner = _find(two, (0, -2, 0), (0, 0, 1))  # the floor in the corner of both walls
    tr1, tr2 = transport.Transport(_scene(one)), transport.Transport(_scene(two))
    got = torch.cat(
        [_cosine_visibility(tr1, torch.tensor([foot, wall_foot])),
         _cosine_visibility(tr2, torch.tensor([corner]))]
    )  # fmt: skip
    # closed forms: a plane through the vertex hides the half-space behind it, whose share of
    # the cosine-weighted hemisphere is 1/2 (the wall for the floor, the floor for the wall);
    # two walls at right angles leave a quarter, 1/4. The cube map's texel boundaries lie on
    # the planes x = 0, y = 0 and z = 0, so the quadrature splits exactly (the normalisation
    # is the same quadrature's); what remains is the sky seen past the planes' far edges
    # from the origin's offset (1e-4 of the diagonal) away: a share of order 1e-4
    want = torch.tensor([0.5, 0.5, 0.25])
    assert torch.allclose(got.double(), want.double(), atol=2e-3), got
    # the rays from the vertices themselves start on the other plane: nothing seen
    for mesh, v in ((one, foot), (one, wall_foot), (two, corner)):
        plain = transport.Transport(_scene(mesh), origins=transport.VertexOrigins.at_vertices(mesh))
        assert float(_cosine_visibility(plain, torch.tensor([v]))[0]) < 0.01, v
    # no exposed points: the faces' points near these vertices see about as little
    assert transport.vertex_origins(one).n_exposed == 0
    assert transport.vertex_origins(two).n_exposed == 0


def test_visibility_and_hit_tiles_start_where_the_transport_does():
    # the tiles a renderer reads per pixel cast from the same origins: the floor vertex at the
    # wall's foot sees the sky exactly where a ray leaves away from the wall and upward, and
    # the wall where it heads into it (no ray grazes the wall's plane: the nearest has
    # |d.x| > 0.03, so from the origin's 5e-4 off the wall it meets the plane within 0.02 of
    # the floor, far below the wall's top at 2)
    mesh = _room(1)
    foot = _find(mesh, (0, 0, 0), (0, 0, 1))
    res, sub = 16, 2
    d = octahedral.texel_directions(res, sub=sub)  # (res, res, sub^2, 3)
    want = ((d[..., 0] > 0) & (d[..., 2] > 0)).float().mean(-1)
    tiles = model.visibility_tiles(mesh, res=res, sub=sub)
    assert torch.equal(tiles[foot], (want * 255).round().to(torch.uint8))
    face, _ = model.hit_tiles(mesh, res=res)
    c = octahedral.texel_directions(res)[:, :, 0]  # (res, res, 3) texel centres
    wall = (face[foot] >= 64) & (face[foot] < 128)  # the wall's faces follow the floor's 64
    assert torch.equal(wall, (c[..., 0] < 0) & (c[..., 2] > 0))
    assert torch.equal(face[foot] == -1, ~wall)


def _framed_quad(half: float, split: bool) -> Mesh:
    """A quad of side ``2 half`` at z = 0 (normal +z; two triangles, or four around a centre
    vertex when ``split``) under a square frame at z = 0.01 from 0.2 inside its rim to 0.3
    outside it: its corners are covered, its middle open."""
    h, z = half, 0.01
    if split:
        pos = torch.tensor([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0], [0, 0, 0]])
        faces = torch.tensor([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])
    else:
        pos = torch.tensor([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]])
        faces = torch.tensor([[0, 1, 2], [0, 2, 3]])
    a, b = h - 0.2, h + 0.3  # the frame's inner and outer half-widths
    ring = torch.tensor([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=torch.float32)
    frame = torch.cat([ring * a, ring * b])  # inner 0..3, outer 4..7
    frame = torch.cat([frame, torch.full((8, 1), z)], 1)
    k = torch.arange(4)
    k1 = (k + 1) % 4
    fr = torch.cat([torch.stack([k, k + 4, k1 + 4], 1), torch.stack([k, k1 + 4, k1], 1)])
    up = torch.tensor([0.0, 0.0, 1.0])
    n = pos.shape[0]
    return Mesh(
        torch.cat([pos.float(), frame]),
        torch.cat([faces, fr + n]),
        up.expand(n + 8, 3).clone(),
        "framed quad",
    )


def test_covered_corners_take_the_light_of_their_exposed_faces():
    # regression: corners under a frame see about nothing, and their transport interpolated
    # across the open quad made its middle black
    half = 10.0
    mesh = _framed_quad(half, split=False)
    sc = _scene(mesh)
    env = envmap.EnvMap(torch.ones(16, 32, 3), layout="latlong", name="constant")
    origins = transport.vertex_origins(mesh)
    assert origins.exposed.tolist() == [True] * 4 + [False] * 8
    # the rendered surface at the quad's centre is the blend of corners 0 and 2 (the
    # diagonal's midpoint); constant light L = 1 has only L_00 = sqrt(4 pi)
    view = torch.tensor([[0.0, 0.0, 1.0]])

    def centre(tr) -> torch.Tensor:
        tb = transport.sample(sc, [0, 2], view, res=32, indirect=False, transport=tr)
        return tb.diffuse[:, 0].mean(0) * math.sqrt(4 * math.pi)

    got = centre(transport.Transport(sc))
    before = centre(transport.Transport(sc, origins=transport.VertexOrigins.at_vertices(mesh)))
    split = _framed_quad(half, split=True)
    mean, se = reference.radiance_at(_scene(split), env, [4], view, spp=4096, max_depth=2)
    ref = mean[0, 0]
    assert float(ref.min()) > 0.75  # the middle is open: albedo 0.8 times almost all the sky
    assert float(before.max()) < 0.05 * float(ref.min())
    # the exposed points lie 1/20 of the way to their faces' centres, 0.13 inside the frame's
    # edge under its 0.01 gap (less the 0.003 lift): the edge hides the cosine-weighted share
    # of the directions beyond ~86 degrees toward it, ~0.3 %; the 32^2 cube quadrature of
    # the open hemisphere is within 0.5 %; and 4 standard errors of the reference
    tol = 0.01 * ref + 4 * se[0, 0]
    assert bool(((got - ref).abs() <= tol).all()), (got, ref, tol)


def test_convex_sphere_moves_nothing_and_its_transport_is_unchanged():
    sc = scene.builtin("sphere", subdivisions=2, model="ggx", roughness=0.3)
    origins = transport.vertex_origins(sc.mesh)
    assert origins.n_exposed == 0
    views = sphere.geodesic_views()[:6]
    vid = torch.arange(0, sc.mesh.n_vertices, 7)
    plain = transport.VertexOrigins.at_vertices(sc.mesh)
    a = transport.sample(sc, vid, views, res=8, paths=8, transport=transport.Transport(sc))
    b = transport.sample(
        sc, vid, views, res=8, paths=8, transport=transport.Transport(sc, origins=plain)
    )
    for name in ("visibility", "glossy", "indirect", "diffuse"):
        assert torch.equal(getattr(a, name), getattr(b, name)), name
