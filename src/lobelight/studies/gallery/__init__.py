"""A scored gallery of real scenes against Mitsuba 3 references.

The gallery is :data:`SCENES`: 10 (mesh, material) bakes — the Stanford bunny (decimated),
Spot, the teapot, Suzanne (Loop-subdivided) and a scorpion (decimated; thin legs, claws and
tail over deep gaps); sharp and rough gold-coloured GGX metals, a plain diffuse and a glossy
plastic — each rendered under three of six maps (a park with an unclipped sun, a studio, an
overcast square, the Grace Cathedral probe, a dawn sky with a soft sun on the horizon and a
lobby lit by ceiling lights and a bright glazed stairwell), 30 scenes; and four textured glTF
assets with their own materials (:data:`GLTF_MATERIAL`; the Khronos sample models
DamagedHelmet, CesiumMilkTruck, WaterBottle and Avocado), each under two maps: 38 scenes in
all. Meshes are centred and scaled to a bounding-box diagonal of 2 (:func:`prepare_mesh`). A
scene's files are read from the data folder (``--data DIR`` or ``$LOBELIGHT_DATA``; ``meshes/``
and ``envmaps/`` in it), else from the repository's ``gallery-data/`` (:data:`GALLERY_DATA`,
with the sources and licences of its files); a glTF asset ``NAME/NAME.glb`` from
``$LOBELIGHT_GLTF`` (:data:`GLTF_ENV`), else the data folder's ``gltf/``, else the repository's
``assets/gltf/`` (:data:`GLTF_ASSETS`, whose ``LICENSES.md`` names each file's source, licence
and checksum; the ``.glb`` files are fetched data, not kept in git).

- :func:`render_references` renders each scene's reference with Mitsuba 3's ``path``
  integrator (:func:`lobelight.reference.mitsuba.scene_dict`: ``max_depth`` 8, 1024 spp, or
  16,384 for the sharp metals (:data:`SHARP_REFERENCE_SAMPLES`, :func:`scene_settings`), 512²,
  box pixel filter, ``llvm_ad_rgb`` else ``scalar_rgb``) and its mask, the pixels fully
  covered by the object (:func:`coverage_mask`), into a references folder with a checked
  manifest (:mod:`._references`); only stale, corrupt or missing entries are rendered.
- :func:`run` bakes each (mesh, material) once with :func:`lobelight.fit.fit_model` (a rerun
  loads the saved model), renders each scene with :class:`lobelight.render.Renderer` at its
  reference's size with ``samples`` points per pixel — a box filter over the pixel, as the
  reference's — and scores it on the reference's mask, less any pixel some of our samples
  missed (:func:`score`; one mask for both images); it times our frame and, with Mitsuba,
  the samples per pixel and seconds a path tracer needs for the same score
  (:func:`mitsuba_sweep`, :func:`equal_quality`), writing ``gallery.json`` (with a ``table``,
  one row per scene: :data:`TABLE`) and one strip ``reference | ours | error x 4`` per scene.
- :func:`score`: displayed PSNR at the exposure that maps the reference's 99th-percentile
  object luminance to 1 (object pixels, and the whole image), relative L2 of linear radiance,
  the energy ratio of the object's luminance and the ratio of its fine detail (high-pass
  energy) to the reference's (:mod:`._score`).
- The command is ``lobelight gallery {list,references,run}`` (:mod:`lobelight.cli`).

Installing Mitsuba's LLVM variant and rendering the references: DEVELOPERS.md.
"""

from ..._lazy import lazy_names

#: Where each public name lives: the submodules load on first use (PEP 562), so that the
#: command line reads the reference settings' defaults for its parser without importing torch.
_HOMES = {
    "FRAME_REPEATS": "._run",
    "GALLERY_DATA": "._scenes",
    "GLTF_ASSETS": "._scenes",
    "GLTF_ENV": "._scenes",
    "GLTF_MATERIAL": "._scenes",
    "GalleryScene": "._scenes",
    "LEGEND": "._score",
    "GAUSSIANS": "._scenes",
    "MAPS": "._scenes",
    "MATERIALS": "._scenes",
    "METRICS": "._run",
    "Reference": "._references",
    "ReferenceSettings": "._settings",
    "SCENES": "._scenes",
    "SHARP_REFERENCE_SAMPLES": "._settings",
    "SWEEP_MAX_SPP": "._settings",
    "TABLE": "._run",
    "VARIANTS": "._settings",
    "coverage_mask": "._references",
    "data_folder": "._scenes",
    "default_camera": "._scenes",
    "display_exposure": "._score",
    "energy_ratio": "._score",
    "equal_quality": "._sweep",
    "find_map": "._scenes",
    "find_mesh": "._scenes",
    "geometry_sha256": "._scenes",
    "load_reference": "._references",
    "luminance": "._score",
    "mitsuba_sweep": "._sweep",
    "prepare_mesh": "._scenes",
    "read_manifest": "._references",
    "reference_status": "._references",
    "render_references": "._references",
    "run": "._run",
    "scene_hash": "._scenes",
    "scene_settings": "._references",
    "score": "._score",
    "select": "._scenes",
    "spp_levels": "._sweep",
    "summarise": "._run",
    "to_scene": "._scenes",
    "write_reference": "._references",
}


__getattr__, __dir__ = lazy_names(__name__, _HOMES)


__all__ = sorted(_HOMES)
