"""The gallery's references: Mitsuba 3 renders and their masks, cached with a checked manifest.

A references folder holds, per scene, ``NAME.npz`` (``image`` and ``stderr``, ``(H, W, 3)``
float32 linear radiance and its per-pixel standard error; ``mask``, ``(H, W)`` bool, the pixels
fully covered by the object), a preview ``NAME.png`` at the display exposure, and
``manifest.json``: for each scene the file's sha256, the scene's hash
(:func:`~lobelight.studies.gallery.scene_hash`), the prepared mesh's hash and the settings that made
it (samples, depth, size, seed, mask grid, Mitsuba variant and version). An entry is fresh when
its file's checksum, its scene hash and its render settings match; anything else is rendered
again. The variant and version are recorded, not compared: every variant renders the same
image up to noise.
"""

from __future__ import annotations

import dataclasses
import json
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..._cache import UNREADABLE
from ..._io import atomic_writer
from ..._tol import DIVISOR_F32
from ...errors import InputError
from ...geometry.camera import Camera
from ...geometry.raycast import RayCaster
from ...progress import resolve
from ...reference.mitsuba import scene_dict
from ...render import save_image
from ...scene import Mesh, Scene
from ._scenes import (
    GalleryScene,
    data_folder,
    geometry_sha256,
    prepare_mesh,
    scene_hash,
    select,
    sha256_file,
    to_scene,
)
from ._score import display_exposure
from ._settings import VARIANTS, ReferenceSettings

__all__ = [
    "FORMAT",
    "MANIFEST",
    "Reference",
    "coverage_mask",
    "load_reference",
    "read_manifest",
    "reference_status",
    "render_references",
    "scene_settings",
    "write_reference",
]

FORMAT = "lobelight-gallery-references"
VERSION = 1
MANIFEST = "manifest.json"
#: The command that renders references, for messages.
COMMAND = "lobelight gallery references --data DIR --refs DIR"


@dataclass(frozen=True)
class Reference:
    """A loaded reference: ``image``, ``stderr`` ``(H, W, 3)`` float32, ``mask`` ``(H, W)`` bool,
    and its manifest ``entry``."""

    image: torch.Tensor
    stderr: torch.Tensor
    mask: torch.Tensor
    entry: dict[str, Any]


def coverage_mask(mesh: Mesh, camera: Camera, width: int, height: int, *, grid: int = 4):
    """``(H, W)`` bool: the pixels whose every ray of a ``grid x grid`` grid of cell centres hits
    ``mesh`` (the pixels fully covered by it, up to features narrower than ``1 / grid``
    pixel)."""
    caster = RayCaster(mesh, offset=0.0)
    full = torch.ones(height, width, dtype=torch.bool)
    for i in range(grid):
        for j in range(grid):
            off = torch.tensor([(i + 0.5) / grid, (j + 0.5) / grid], dtype=torch.float64)
            o, d = camera.rays(width, height, offsets=off.expand(height, width, 2))
            full &= caster.occluded(o, d).cpu()  # (H, W): this ray hits the mesh
    return full


def read_manifest(refs: Path) -> dict[str, Any]:
    """The folder's manifest (an empty one when there is none or it is unreadable)."""
    empty = {"format": FORMAT, "version": VERSION, "entries": {}}
    try:
        m = json.loads((Path(refs) / MANIFEST).read_text())
    except (OSError, ValueError):
        return empty
    if (
        not isinstance(m, dict)
        or m.get("format") != FORMAT
        or not isinstance(m.get("entries"), dict)
    ):
        return empty
    return m


def _write_json(path: Path, d: dict) -> None:
    with atomic_writer(path) as f:
        f.write(json.dumps(d, indent=2, allow_nan=False).encode())


def write_reference(
    refs, scene: GalleryScene, image, stderr, mask, *, entry: dict[str, Any]
) -> dict[str, Any]:
    """Store one reference (``image``, ``stderr`` ``(H, W, 3)``, ``mask`` ``(H, W)`` bool) and
    its manifest entry (``entry`` plus the file's name, checksum and object pixel count);
    returns the entry. Both files are written atomically."""
    refs = Path(refs)
    image = np.ascontiguousarray(np.asarray(image, dtype=np.float32))
    stderr = np.ascontiguousarray(np.asarray(stderr, dtype=np.float32))
    mask = np.ascontiguousarray(np.asarray(mask, dtype=bool))
    if image.ndim != 3 or image.shape[-1] != 3 or stderr.shape != image.shape:
        raise InputError("reference", f"expected (H, W, 3) images, got {image.shape}")
    if mask.shape != image.shape[:2]:
        raise InputError("mask", f"expected {image.shape[:2]}, got {mask.shape}")
    path = refs / f"{scene.name}.npz"
    with atomic_writer(path) as f:
        np.savez_compressed(f, image=image, stderr=stderr, mask=mask)
    entry = {**entry, "file": path.name, "sha256": sha256_file(path)}
    entry["object_pixels"] = int(mask.sum())
    if mask.any():
        save_image(refs / f"{scene.name}.png", image, exposure=_exposure(image, mask))
    manifest = read_manifest(refs)
    manifest["entries"][scene.name] = entry
    _write_json(refs / MANIFEST, manifest)
    return entry


def _exposure(image: np.ndarray, mask: np.ndarray) -> float:
    try:
        return display_exposure(torch.from_numpy(image), torch.from_numpy(mask))
    except InputError:
        return 0.0


def scene_settings(settings: ReferenceSettings, scene: GalleryScene) -> ReferenceSettings:
    """The settings ``scene``'s reference is rendered with: ``settings`` with the scene's
    :attr:`~lobelight.studies.gallery.GalleryScene.reference_samples` times their samples per
    pixel."""
    return dataclasses.replace(settings, spp=settings.spp * scene.reference_samples)


def reference_status(
    refs, scene: GalleryScene, data, settings: ReferenceSettings | None = None
) -> tuple[str, str]:
    """``(status, why)``: ``"ok"``, ``"missing"``, ``"corrupt"`` (the file's checksum differs
    from the manifest's) or ``"stale"`` (the scene, its files or, given ``settings``, the render
    settings changed since: the scene's own, :func:`scene_settings`)."""
    entry = read_manifest(Path(refs))["entries"].get(scene.name)
    if not isinstance(entry, dict):
        return "missing", "not in the manifest"
    path = Path(refs) / str(entry.get("file", ""))
    if not path.is_file():
        return "missing", f"no file {path.name!r}"
    if sha256_file(path) != entry.get("sha256"):
        return "corrupt", f"{path.name}: its sha256 is not the manifest's"
    if entry.get("scene_hash") != scene_hash(scene, data_folder(data)):
        return "stale", "the scene's definition, mesh or map changed"
    if settings is not None:
        want = scene_settings(settings, scene).to_dict()
        if entry.get("settings") != want:
            return "stale", f"rendered with {entry.get('settings')}, asked for {want}"
    return "ok", ""


def load_reference(refs, scene: GalleryScene, data) -> Reference:
    """The scene's reference, checked (:func:`reference_status`); InputError naming the scene
    when it is missing, corrupt or stale."""
    status, why = reference_status(refs, scene, data)
    if status != "ok":
        raise InputError(f"{scene.name}: reference", f"{status} ({why}); render it: {COMMAND}")
    entry = read_manifest(Path(refs))["entries"][scene.name]
    try:
        with np.load(Path(refs) / entry["file"], allow_pickle=False) as z:
            image, stderr, mask = z["image"], z["stderr"], z["mask"]
    except UNREADABLE as exc:
        problem = f"unreadable ({exc}); render it: {COMMAND}"
        raise InputError(f"{scene.name}: reference", problem) from None
    return Reference(
        torch.from_numpy(image.astype(np.float32)),
        torch.from_numpy(stderr.astype(np.float32)),
        torch.from_numpy(mask.astype(bool)),
        entry,
    )


def _mitsuba(variant: str | None):
    """``(mi, variant, note)``: Mitsuba with ``variant`` set, else the first of :data:`VARIANTS`
    that runs; ``note`` says why the earlier ones did not."""
    try:
        import drjit as dr  # optional: the reference extra (Mitsuba's)
        import mitsuba as mi  # optional: the reference extra
    except ImportError as exc:
        raise InputError("mitsuba", f"is not installed ({exc}); pip install mitsuba") from None
    notes = []
    for v in (variant,) if variant else VARIANTS:
        try:
            mi.set_variant(v)
            if v.startswith("llvm"):  # a first kernel: proof that LLVM loads
                dr.eval(dr.llvm.Float(1.0) + 1.0)
            note = "; ".join(notes)
            return mi, v, note
        except Exception as exc:  # no LLVM library, a variant this build lacks
            notes.append(
                f"{v} unavailable ({str(exc).strip().splitlines()[0] if str(exc) else exc!r}; "
                "for llvm: apt-get install -y libllvm19 and set DRJIT_LIBLLVM_PATH)"
            )
    raise InputError("--variant", "; ".join(notes))


def _render_mitsuba(mi, variant: str, scene: Scene, settings: ReferenceSettings, progress):
    """``(image, stderr)`` ``(H, W, 3)`` float32: the mean of ``spp / pass_spp`` passes and
    its standard error from their spread."""
    with tempfile.TemporaryDirectory(prefix="lobelight-gallery-") as work:
        d = scene_dict(
            scene,
            scene.environment,
            scene.camera,
            width=settings.width,
            height=settings.height,
            spp=settings.pass_spp,
            max_depth=settings.max_depth,
            seed=settings.seed,
            workdir=work,
            variant=variant,
        )
        s = mi.load_dict(d)
        n = settings.spp // settings.pass_spp
        acc = np.zeros((settings.height, settings.width, 3))
        acc2 = np.zeros_like(acc)
        for k in range(n):
            img = np.asarray(
                mi.render(s, spp=settings.pass_spp, seed=settings.seed * n + k), dtype=np.float64
            )  # (H, W, 3)
            acc += img
            acc2 += img * img
            if progress is not None:
                progress("reference", (k + 1) * settings.pass_spp, settings.spp)
        del s
    mean = acc / n
    var = np.maximum(acc2 / n - mean * mean, 0) * n / (n - 1)  # a pass's variance
    return mean.astype(np.float32), np.sqrt(var / n).astype(np.float32)


def render_references(
    scenes=None,
    *,
    data=None,
    refs,
    settings: ReferenceSettings | None = None,
    variant: str | None = None,
    force: bool = False,
    progress=True,
) -> dict[str, Any]:
    """Render the references of ``scenes`` (names or :class:`GalleryScene`; default all) that
    are missing, corrupt or stale in ``refs`` (all of them with ``force``).

    Parameters
    ----------
    data : the data folder (default ``$LOBELIGHT_DATA``)
    refs : the references folder (created)
    variant : a Mitsuba variant; default ``llvm_ad_rgb``, else ``scalar_rgb`` (with a note)

    Returns
    -------
    dict: ``variant``, ``mitsuba`` (version), ``note``, ``rendered`` and ``kept`` (scene names),
    ``status`` (why each was rendered), ``seconds`` (per rendered scene), ``refs``
    """
    settings = settings or ReferenceSettings()
    data = data_folder(data)
    chosen = select(scenes)
    refs = Path(refs).expanduser()
    if refs.exists() and not refs.is_dir():
        raise InputError("--refs", f"is not a folder: {str(refs)!r}")
    refs.mkdir(parents=True, exist_ok=True)
    progress = resolve(progress)
    note = getattr(progress, "note", None) or (lambda _: None)
    out: dict[str, Any] = {"refs": str(refs), "rendered": [], "kept": [], "status": {}}
    out["seconds"] = {}
    mi = None
    for sc in chosen:
        status, why = reference_status(refs, sc, data, settings)
        if status == "ok" and not force:
            out["kept"].append(sc.name)
            continue
        out["status"][sc.name] = "forced" if status == "ok" else f"{status}: {why}"
        if mi is None:
            mi, var, why_not = _mitsuba(variant)
            out.update(variant=var, mitsuba=mi.__version__, note=why_not)
            if why_not:
                note(f"Mitsuba: {why_not}; rendering with {var}")
        note(f"reference {sc.name} ({out['status'][sc.name]})")
        t = time.perf_counter()
        mesh = prepare_mesh(sc, data)
        scene = to_scene(sc, data, mesh)
        own = scene_settings(settings, sc)
        w, h = own.width, own.height
        mask = coverage_mask(mesh, scene.camera, w, h, grid=own.mask_grid)
        image, stderr = _render_mitsuba(mi, out["variant"], scene, own, progress)
        seconds = time.perf_counter() - t
        m = mask.numpy()
        noise = (
            float(stderr[m].mean() / max(float(image[m].mean()), DIVISOR_F32)) if m.any() else None
        )
        entry = {
            "scene_hash": scene_hash(sc, data),
            "geometry_sha256": geometry_sha256(mesh),
            "vertices": mesh.n_vertices,
            "settings": own.to_dict(),
            "variant": out["variant"],
            "mitsuba": mi.__version__,
            "seconds": seconds,
            "reference_noise": noise,
            "definition": sc.to_dict(),
        }
        write_reference(refs, sc, image, stderr, mask, entry=entry)
        out["rendered"].append(sc.name)
        out["seconds"][sc.name] = seconds
    return out
