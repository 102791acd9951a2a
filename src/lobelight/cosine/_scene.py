"""The paper's kind of scene, and its G-buffer: a plane, a mesh object, spherical lights.

The object is a closed trimesh mesh (default: a torus) placed by a rotation and a translation
(so it can move from frame to frame without rebuilding anything); its occluder spheres are a
:func:`~._spheres.sphere_set` of the same mesh, moved with it. The G-buffer casts the camera's
rays against the plane (analytically) and the mesh (Embree,
:class:`lobelight.geometry.raycast.RayCaster`, rays moved into the object's frame), and gives the
points to shade: positions, interpolated normals, view directions, material ids and per-point BRDF
parameters (spatially varying).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import torch
import trimesh

from .. import brdf as _brdf
from ..geometry.camera import Camera
from ..geometry.raycast import RayCaster
from ..scene import mesh_from_arrays
from ._light import SphereLight
from ._spheres import SphereSet, sphere_set

__all__ = ["FLAT_ROTATION", "LobeScene", "default_scene", "gbuffer", "rotation_about_y"]


def rotation_about_y(angle: float) -> torch.Tensor:
    """(3, 3) rotation by ``angle`` radians about +Y."""
    c, s = math.cos(angle), math.sin(angle)
    return torch.tensor([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


#: (3, 3) a quarter turn about +X, ``(x, y, z) -> (x, -z, y)``: it lays trimesh's torus, which
#: lies in its xy plane, flat in the xz plane (the object's rotation in :func:`default_scene`).
FLAT_ROTATION = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


@dataclass
class LobeScene:
    """A plane ``y = 0`` (``|x|, |z| <= plane_half``), one object, lights and a camera.

    Attributes
    ----------
    vertices, faces : the object's mesh in its own frame, (V, 3) float64, (F, 3) int64
    spheres : its :class:`~._spheres.SphereSet`, in its own frame
    rotation, translation : (3, 3), (3,) the object's placement ``x -> R x + t``
    lights : list of :class:`~._light.SphereLight`;  camera :
    :class:`lobelight.geometry.camera.Camera` plane_albedo, object_albedo : RGB;  object_specular,
    object_exponent : modified Phong
    """

    vertices: np.ndarray
    faces: np.ndarray
    spheres: SphereSet
    rotation: torch.Tensor
    translation: torch.Tensor
    lights: list
    camera: Camera
    plane_half: float = 4.0
    plane_albedo: tuple = (0.75, 0.75, 0.72)
    object_albedo: tuple = (0.7, 0.25, 0.15)
    object_specular: float = 0.25
    object_exponent: float = 40.0
    _caster: Any = field(default=None, repr=False)

    def world_spheres(self) -> torch.Tensor:
        """(N, 4) occluder spheres in the world frame."""
        return self.spheres.transformed(self.rotation, self.translation).spheres

    def moved(self, *, rotation=None, translation=None, lights=None) -> LobeScene:
        """The same scene with the object placed anew and/or other lights (shares the BVH)."""
        return replace(
            self,
            rotation=self.rotation if rotation is None else torch.as_tensor(rotation).float(),
            translation=self.translation
            if translation is None
            else torch.as_tensor(translation).float(),
            lights=self.lights if lights is None else list(lights),
        )

    def caster(self):
        if self._caster is None:
            self._caster = RayCaster(mesh_from_arrays(self.vertices, self.faces, weld=False))
        return self._caster


def default_scene(*, spheres: int = 64, seed: int = 0) -> LobeScene:
    """A torus (64 spheres) over a plane, a light above and to the side, a camera looking down."""
    torus = trimesh.creation.torus(0.9, 0.3, major_sections=32, minor_sections=16)
    sset = sphere_set(torus, spheres, samples=12000, seed=seed)
    light = SphereLight((1.6, 3.2, 1.0), 0.45, (6.0, 6.0, 5.6))
    cam = Camera.look_at((0.0, 4.2, 5.4), (0.0, 0.3, 0.0), fov=50.0)
    return LobeScene(
        vertices=np.asarray(torus.vertices, dtype=np.float64),
        faces=np.asarray(torus.faces, dtype=np.int64),
        spheres=sset,
        rotation=FLAT_ROTATION.clone(),
        translation=torch.tensor([0.0, 0.75, 0.0]),
        lights=[light],
        camera=cam,
    )


def gbuffer(scene: LobeScene, width: int, height: int, *, device: Any = "cpu") -> dict:
    """Primary hits of every pixel: what :func:`~._shade.shade_points` shades.

    Returns
    -------
    dict with ``points``, ``normals``, ``wo`` (P, 3) float32 for the P pixels that hit
    something, ``pixel`` (P,) int64 flat pixel index (row-major, H x W), ``material`` (P,) int64
    (0 plane, 1 object), ``brdf`` (a per-point ``Sum(Lambert, Phong)``), ``shape`` (H, W)
    """
    o, d = scene.camera.rays(width, height, dtype=torch.float64)
    o, d = o.reshape(-1, 3), d.reshape(-1, 3)
    R = scene.rotation.double()
    T = scene.translation.double()
    # object: rays in its own frame (x_obj = R^T (x - T)), first hit by Embree
    tri, t_obj, bary = scene.caster().first_hit((o - T) @ R, d @ R)
    hit_obj = tri >= 0
    # plane y = 0 seen from above
    t_pl = torch.where(d[:, 1] < 0, -o[:, 1] / torch.where(d[:, 1] < 0, d[:, 1], -1.0), math.inf)
    x_pl = o + t_pl.unsqueeze(-1) * d
    inside = (x_pl[:, 0].abs() <= scene.plane_half) & (x_pl[:, 2].abs() <= scene.plane_half)
    t_pl = torch.where(inside & (t_pl > 0), t_pl, math.inf)
    t_obj = torch.where(hit_obj, t_obj.double(), math.inf)
    use_obj = t_obj < t_pl
    valid = torch.isfinite(torch.minimum(t_obj, t_pl))
    t = torch.where(use_obj, t_obj, t_pl)
    pts = o + t.unsqueeze(-1) * d
    # object normals: barycentric blend of the mesh's vertex normals, rotated to the world
    mesh = scene.caster().mesh
    vn = mesh.normals.double()[mesh.faces[tri.clamp_min(0)]]  # (R, 3, 3)
    n_obj = torch.nn.functional.normalize((bary.double().unsqueeze(-1) * vn).sum(1), dim=-1) @ R.T
    n = torch.where(
        use_obj.unsqueeze(-1), n_obj, torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)
    )
    pix = valid.nonzero(as_tuple=True)[0]
    mat = use_obj[pix].long()
    kw = {"dtype": torch.float32, "device": device}
    albedo = torch.where(
        mat.unsqueeze(-1) == 1,
        torch.tensor(scene.object_albedo),
        torch.tensor(scene.plane_albedo),
    )
    spec = (mat == 1).float() * scene.object_specular
    expo = torch.where(mat == 1, scene.object_exponent, 1.0)
    model = _brdf.Sum(
        _brdf.Lambert(albedo.to(**kw)),
        _brdf.Phong(spec.unsqueeze(-1).expand(-1, 3).contiguous().to(**kw), expo.to(**kw)),
    )
    return {
        "points": pts[pix].to(**kw),
        "normals": n[pix].to(**kw),
        "wo": (-d[pix]).to(**kw),
        "pixel": pix.to(device),
        "material": mat.to(device),
        "brdf": model,
        "shape": (height, width),
    }
