"""Scenes: meshes, per-vertex materials, environment and camera.

- :func:`load` a built-in name, a scene file (TOML/JSON, see :mod:`._scene`) or a bare mesh;
  :func:`builtin` the scenes that need no files (``"knot"``, ``"sphere"``).
- :class:`Mesh` welded, cleaned triangles with area-weighted vertex normals and CSR adjacency;
  :func:`load_mesh` / :func:`mesh_from_arrays` check their input and name the problem.
- :class:`Materials` Lambert albedo plus one specular model of :mod:`lobelight.brdf` with
  per-vertex parameters; :func:`uniform` and :func:`gradient` build them from plain specs.
"""

from ._materials import SPECULAR_MODELS, Materials, gradient, uniform
from ._mesh import Mesh, load_mesh, mesh_from_arrays, triangle_areas
from ._scene import BUILTIN_SCENES, Scene, builtin, load

__all__ = [
    "BUILTIN_SCENES",
    "SPECULAR_MODELS",
    "Materials",
    "Mesh",
    "Scene",
    "builtin",
    "gradient",
    "load",
    "load_mesh",
    "mesh_from_arrays",
    "triangle_areas",
    "uniform",
]
