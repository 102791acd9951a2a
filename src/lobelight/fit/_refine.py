"""The bake mesh: the scene's mesh with its edges split where the two ends see the environment
differently.

Transport is stored per vertex and interpolated across a triangle, so a triangle whose corners
see different things draws a linear ramp between them where the truth has a step somewhere in
between. An asset's long, thin triangles (a bottle's body in strips from the shoulder to the
foot, crossed by the edge of a sleeve that covers their lower ends) give one corner little of
the sky and the other all of it, and the whole strip a blend of the two. Each round measures,
for every edge, how differently its two ends see the environment: the share of the directions
above both ends' horizons in which one end's ray escapes and the other's does not
(:func:`lobelight.model.visibility_tiles`, coarse tiles), and splits at its midpoint each edge
where that share is at least :data:`REFINE_DIFFERENCE` and the edge is longer than
:data:`REFINE_MIN_EDGE` of the mesh's diagonal; the triangles are split to match (one, two or
three split edges: two, three or four triangles, their winding kept), and the next round looks
at the new edges. A convex mesh, or one fine enough, is left as it is.

A midpoint takes the mean of its edge's ends: position, normal (normalised), diffuse albedo,
per-vertex BRDF parameters, and a glTF asset's UVs, vertex colours and albedo-texture
coordinates; its material index and texture layer are its first end's (an edge never joins two
materials: the asset's vertices are split where materials meet). So the refined mesh renders
as the original does until its transport is baked, and the surface, its UV mapping and the
materials are unchanged.
"""

from __future__ import annotations

import dataclasses

import torch

from ..geometry import octahedral
from ..model import visibility_tiles
from ..scene import Materials, Mesh, Scene

__all__ = [
    "REFINE_DIFFERENCE",
    "REFINE_MAX_GROWTH",
    "REFINE_MIN_EDGE",
    "REFINE_ROUNDS",
    "refine_scene",
]

#: Rounds of splitting (each halves the edges it splits).
REFINE_ROUNDS = 3
#: An edge is split where at least this share of the directions above both ends' horizons
#: escapes from one end and not from the other.
REFINE_DIFFERENCE = 0.1
#: Edges no longer than this fraction of the mesh's bounding-box diagonal are kept.
REFINE_MIN_EDGE = 0.01
#: At most this many new vertices per vertex of the scene's mesh, over all rounds (the edges
#: whose ends differ most, times their length, first).
REFINE_MAX_GROWTH = 1.0
#: Tile resolution and rays per texel side of the visibility the rounds compare (coarser than
#: the renderer's: the test needs the share, not the shape).
_RES, _SUB = 16, 1
#: Edges compared per batch (bounded memory: two tiles of floats per edge).
_EDGE_BATCH = 1 << 15


def refine_scene(scene: Scene, *, rounds: int = REFINE_ROUNDS,
                 max_growth: float = REFINE_MAX_GROWTH) -> tuple[Scene, dict]:  # fmt: skip
    """The scene on its bake mesh (module docstring), with at most ``max_growth`` new vertices
    per vertex, and a record of the refinement: ``rounds`` (those that split), ``vertices``
    (before, after), ``edges_split`` per round."""
    before = scene.mesh.n_vertices
    budget = int(max_growth * before)
    split_counts: list[int] = []
    for _ in range(rounds):
        edges, face_edges = _edges(scene.mesh.faces)
        split = _edges_to_split(scene.mesh, edges, budget)
        n = int(split.sum())
        if n == 0:
            break
        scene = _split(scene, edges, face_edges, split)
        budget -= n
        split_counts.append(n)
    record = {
        "rounds": len(split_counts),
        "vertices": [before, scene.mesh.n_vertices],
        "edges_split": split_counts,
    }
    return scene, record


def _edges(faces: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The mesh's unique edges ``(E, 2)`` (ends sorted) and each face's three edges ``(F, 3)``
    (``v0 v1``, ``v1 v2``, ``v2 v0``)."""
    pairs = torch.stack([faces, faces.roll(-1, dims=1)], -1).reshape(-1, 2)  # (3F, 2)
    edges, inverse = torch.unique(pairs.sort(-1).values, dim=0, return_inverse=True)
    return edges, inverse.reshape(-1, 3)


def _edges_to_split(mesh: Mesh, edges: torch.Tensor, budget: int) -> torch.Tensor:
    """(E,) bool: the edges whose ends see the environment differently (module docstring),
    at most ``budget`` of them."""
    if budget <= 0 or edges.shape[0] == 0:
        return torch.zeros(edges.shape[0], dtype=torch.bool, device=edges.device)
    v = mesh.vertices
    diag = float((v.amax(0) - v.amin(0)).norm())
    length = (v[edges[:, 0]] - v[edges[:, 1]]).norm(dim=-1)
    long = length > REFINE_MIN_EDGE * diag
    differ = torch.zeros(edges.shape[0], device=v.device)
    cand = long.nonzero().squeeze(-1)
    if cand.numel():
        tiles = visibility_tiles(mesh, res=_RES, sub=_SUB)
        tiles = tiles.reshape(tiles.shape[0], -1)  # (V, D) uint8
        dirs = octahedral.texel_directions(_RES, device=v.device).reshape(-1, 3)  # (D, 3)
        above = (mesh.normals @ dirs.T) > 0  # (V, D)
        for s in range(0, cand.numel(), _EDGE_BATCH):
            e = edges[cand[s : s + _EDGE_BATCH]]
            both = above[e[:, 0]] & above[e[:, 1]]
            gap = (tiles[e[:, 0]].float() - tiles[e[:, 1]].float()).abs() / 255.0
            n = both.sum(-1)
            share = (gap * both).sum(-1) / n.clamp_min(1)
            differ[cand[s : s + _EDGE_BATCH]] = torch.where(n > 0, share, 0.0)
    split = long & (differ >= REFINE_DIFFERENCE)
    if int(split.sum()) > budget:  # the most different, longest first
        keep = (differ * length * split).topk(budget).indices
        split = torch.zeros_like(split)
        split[keep] = True
    return split


#: Per count of split edges in canonical order (the face rolled so that the split edges are
#: the first ones), the new triangles as indices into (v0, v1, v2, m01, m12, m20).
_PATTERNS = {
    1: ((0, 3, 2), (3, 1, 2)),
    2: ((0, 3, 4), (3, 1, 4), (0, 4, 2)),
    3: ((0, 3, 5), (3, 1, 4), (5, 4, 2), (3, 4, 5)),
}


def _split(scene: Scene, edges: torch.Tensor, face_edges: torch.Tensor, split: torch.Tensor):
    """The scene with the edges ``split`` split at their midpoints (module docstring)."""
    mesh = scene.mesh
    nv = mesh.n_vertices
    k = split.nonzero().squeeze(-1)
    a, b = edges[k, 0], edges[k, 1]
    mid = torch.full((edges.shape[0],), -1, dtype=torch.int64, device=edges.device)
    mid[k] = nv + torch.arange(k.numel(), device=edges.device)
    flags = split[face_edges]  # (F, 3)
    count = flags.sum(1)
    out = [mesh.faces[count == 0]]
    for c, tris in _PATTERNS.items():
        sel = (count == c).nonzero().squeeze(-1)
        if sel.numel() == 0:
            continue
        f, fe, fl = mesh.faces[sel], face_edges[sel], flags[sel]
        # roll each face so that its split edges come first: one split edge to slot 0, two
        # with the kept edge in slot 2 (rolling keeps the winding)
        rot = fl.float().argmax(1) if c == 1 else ((~fl).float().argmax(1) + 1) % 3
        idx = (torch.arange(3, device=f.device)[None] + rot[:, None]) % 3
        f, fe = f.gather(1, idx), fe.gather(1, idx)
        corners = torch.cat([f, mid[fe]], 1)  # (n, 6): v0 v1 v2 m01 m12 m20 (-1: not split)
        for t in tris:
            out.append(corners[:, list(t)])
    faces = torch.cat(out)

    def extend(x: torch.Tensor) -> torch.Tensor:
        return torch.cat([x, 0.5 * (x[a] + x[b])])

    normals = extend(mesh.normals)
    normals = torch.nn.functional.normalize(normals, dim=-1)
    new_mesh = Mesh(vertices=extend(mesh.vertices), faces=faces, normals=normals, name=mesh.name)
    mats = scene.materials
    spec = mats.specular
    if spec is not None:
        spec = spec.map_params(lambda t, kind: t if t.ndim <= kind else extend(t))
    changes: dict = {"mesh": new_mesh, "materials": Materials(extend(mats.diffuse), spec)}
    if scene.gltf is not None:
        g = scene.gltf
        changes["gltf"] = dataclasses.replace(
            g, mesh=new_mesh, uvs=extend(g.uvs), colors=extend(g.colors),
            material=torch.cat([g.material, g.material[a]]),
        )  # fmt: skip
    if scene.albedo is not None:
        al = scene.albedo
        changes["albedo"] = dataclasses.replace(
            al, uvs=extend(al.uvs), layer=torch.cat([al.layer, al.layer[a]]),
            factor=extend(al.factor),
        )  # fmt: skip
    return dataclasses.replace(scene, **changes)
