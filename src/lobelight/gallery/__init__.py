"""A scored gallery of real scenes against Mitsuba 3 references.

The gallery is :data:`SCENES`: 8 (mesh, material) bakes — the Stanford bunny (decimated),
Spot, the teapot and Suzanne (Loop-subdivided); sharp and rough gold-coloured GGX metals, a
plain diffuse and a glossy plastic — each rendered under two of four maps (a park with an
unclipped sun, a studio, an overcast square and the Grace Cathedral probe), 16 scenes in all.
Meshes are centred and scaled to a bounding-box diagonal of 2 (:func:`prepare_mesh`) and read
from a data folder (``--data DIR`` or ``$LOBELIGHT_DATA``; ``meshes/`` and ``envmaps/`` in it).

- :func:`render_references` renders each scene's reference with Mitsuba 3's ``path``
  integrator (:func:`lobelight.mitsuba_export.scene_dict`: ``max_depth`` 8, 1024 spp, 512²,
  box pixel filter, ``llvm_ad_rgb`` else ``scalar_rgb``) and its mask, the pixels fully
  covered by the object (:func:`coverage_mask`), into a references folder with a checked
  manifest (:mod:`._references`); only stale, corrupt or missing entries are rendered.
- :func:`run` bakes each (mesh, material) once with :func:`lobelight.fit.fit_model` (a rerun
  loads the saved model), renders each scene with :class:`lobelight.render.Renderer` at its
  reference's size with ``samples`` points per pixel — a box filter over the pixel, as the
  reference's — and scores it on the reference's mask, less any pixel some of our samples
  missed (:func:`score`; one mask for both images), writing
  ``gallery.json`` and one strip ``reference | ours | error x 4`` per scene.
- :func:`score`: displayed PSNR at the exposure that maps the reference's 99th-percentile
  object luminance to 1 (object pixels, and the whole image), relative L2 of linear radiance
  and the energy ratio of the object's luminance (:mod:`._score`).
- :func:`add_arguments` and :func:`main_from_args` are the command line for any parser;
  ``python -m lobelight.gallery {list,references,run}`` is :func:`main`.

Installing Mitsuba's LLVM variant and rendering the references: DEVELOPERS.md.
"""

from ._cli import add_arguments, main, main_from_args
from ._references import (
    Reference,
    ReferenceSettings,
    coverage_mask,
    load_reference,
    read_manifest,
    reference_status,
    render_references,
    write_reference,
)
from ._run import METRICS, run, summarise
from ._scenes import (
    MAPS,
    MATERIALS,
    SCENES,
    GalleryScene,
    data_folder,
    default_camera,
    geometry_sha256,
    prepare_mesh,
    scene_hash,
    select,
    to_scene,
)
from ._score import LEGEND, display_exposure, energy_ratio, luminance, noise_psnr_display, score

__all__ = [
    "LEGEND",
    "MAPS",
    "MATERIALS",
    "METRICS",
    "SCENES",
    "GalleryScene",
    "Reference",
    "ReferenceSettings",
    "add_arguments",
    "coverage_mask",
    "data_folder",
    "default_camera",
    "display_exposure",
    "energy_ratio",
    "geometry_sha256",
    "load_reference",
    "luminance",
    "main",
    "main_from_args",
    "noise_psnr_display",
    "prepare_mesh",
    "read_manifest",
    "reference_status",
    "render_references",
    "run",
    "scene_hash",
    "score",
    "select",
    "summarise",
    "to_scene",
    "write_reference",
]
