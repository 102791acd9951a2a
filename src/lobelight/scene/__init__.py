"""Scenes: meshes, per-vertex materials, environment and camera.

- :func:`load` a built-in name, a scene file (TOML/JSON, see :mod:`._scene`) or a bare mesh;
  :func:`builtin` the scenes that need no files (``"knot"``, ``"sphere"``). A glTF mesh brings
  its own materials (per-vertex factors averaged as :data:`GLTF_AVERAGE` says), which a scene
  file may override by name (:data:`MATERIAL_OVERRIDE_KEYS`); :attr:`Scene.material_records`
  lists them.
- :class:`Mesh` welded, cleaned triangles with area-weighted vertex normals and CSR adjacency;
  :func:`load_mesh` / :func:`mesh_from_arrays` check their input and name the problem.
- :func:`load_gltf` a glTF 2.0 asset (``.gltf``/``.glb``) as a :class:`GltfAsset`: the welded
  mesh with its UVs, vertex colours and per-vertex material index, and :class:`GltfMaterial`
  records (metallic-roughness factors, :class:`Texture` s with their :class:`Sampler`);
  :func:`vertex_factors` its base colour, metallic and roughness per vertex,
  :func:`sample_texture` a texture at UVs, :func:`read_gltf` the file unwelded;
  :func:`gltf_materials` turns those per-vertex factors into :class:`Materials`;
  :class:`AlbedoTexture` (:func:`albedo_texture`) its base colour textures read per pixel
  (:attr:`Scene.albedo`).
- :class:`Materials` Lambert albedo plus one specular model of :mod:`lobelight.brdf` with
  per-vertex parameters; :func:`uniform` and :func:`gradient` build them from plain specs,
  :func:`parse_material` from a one-line spec (``"ggx:alpha=0.1,diffuse=0.5"``).

The scene-file format is described in docs/scene-format.md.
"""

from ._albedo import WRAP_MODES, AlbedoTexture, albedo_texture, srgb_decode, srgb_encode
from ._gltf import (
    GLTF_SUFFIXES,
    GltfGeometry,
    GltfMaterial,
    Sampler,
    Texture,
    read_gltf,
    sample_texture,
    wrap_texels,
)
from ._materials import (
    LOBE_PARAMS,
    MODEL_PARAMS,
    SPECULAR_MODELS,
    Materials,
    gltf_materials,
    gradient,
    material_table,
    parse_material,
    uniform,
)
from ._mesh import (
    MAX_EXTENT,
    MAX_FACES,
    MAX_OFFSET,
    MAX_WELD_LOSS,
    MESH_SUFFIXES,
    MIN_EXTENT,
    GltfAsset,
    Mesh,
    VertexFactors,
    check_precision,
    load_gltf,
    load_mesh,
    mesh_from_arrays,
    triangle_areas,
    vertex_factors,
    weld_arrays,
)
from ._scene import (
    BARE_MESH_MATERIAL,
    BUILTIN_SCENES,
    GLTF_AVERAGE,
    GLTF_QUADRATURE,
    GRADIENT_KEYS,
    MATERIAL_OVERRIDE_KEYS,
    SCENE_FILE_MATERIAL,
    SCENE_KEYS,
    Scene,
    builtin,
    default_camera,
    load,
)

__all__ = [
    "BARE_MESH_MATERIAL",
    "BUILTIN_SCENES",
    "GLTF_AVERAGE",
    "GLTF_QUADRATURE",
    "GLTF_SUFFIXES",
    "GRADIENT_KEYS",
    "LOBE_PARAMS",
    "MATERIAL_OVERRIDE_KEYS",
    "MAX_EXTENT",
    "MAX_FACES",
    "MAX_OFFSET",
    "MAX_WELD_LOSS",
    "MESH_SUFFIXES",
    "MIN_EXTENT",
    "MODEL_PARAMS",
    "SCENE_FILE_MATERIAL",
    "SCENE_KEYS",
    "SPECULAR_MODELS",
    "WRAP_MODES",
    "AlbedoTexture",
    "GltfAsset",
    "GltfGeometry",
    "GltfMaterial",
    "Materials",
    "Mesh",
    "Sampler",
    "Scene",
    "Texture",
    "VertexFactors",
    "albedo_texture",
    "builtin",
    "check_precision",
    "default_camera",
    "gltf_materials",
    "gradient",
    "load",
    "load_gltf",
    "load_mesh",
    "material_table",
    "mesh_from_arrays",
    "parse_material",
    "read_gltf",
    "sample_texture",
    "srgb_decode",
    "srgb_encode",
    "triangle_areas",
    "uniform",
    "vertex_factors",
    "weld_arrays",
    "wrap_texels",
]
