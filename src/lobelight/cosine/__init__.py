"""Cosine lobes for dynamic direct lighting with sphere-set soft shadows (the cosine-lobes paper).

Every term of the rendering equation as sums of lobes ``c(w) = s max(a.w, 0)^e``, multiplied and
integrated through scene-independent tables.

Lobes (:mod:`._lobe`)
    :func:`evaluate`, :func:`integral` (``2 pi s/(e+1)``, exact: no integral table is needed),
    :func:`from_vector` (Lafortune's non-unit lobe vectors), :func:`product_peak` (the product
    lobe's axis, in closed form), :func:`product_integral` (``∫ c1 c2``, exact up to quadrature).

Tables (:mod:`._tables`)
    :func:`get_tables` loads the tables from the disk cache (:func:`lobelight._cache.cache_dir`:
    ``$LOBELIGHT_CACHE``, else the platform's user cache folder), building them once when
    missing or of another version;
    :class:`LobeTables` looks up the product lobe (``partial scale, exponent``) and the
    spherical-cap exponent, trilinearly, on any device. :func:`product` multiplies two lobes
    given by axes, exponents and scales (the paper's L2-best scale, or with
    ``preserve_integral=True`` the scale that keeps the product's exact integral);
    :func:`cap_exponent` is the lobe of a spherical cap.
    :func:`fit_product` and :func:`fit_cap_exponent` are the direct fits the tables store;
    :func:`build_tables`, :func:`save_tables` and :func:`load_tables` complete the set.

Direct lighting with soft shadows (method note ``docs/cosine-lobes.md``)
    :class:`SphereLight` (centre, radius, RGB radiance) is one cap lobe per point
    (:func:`light_lobes`; its scale makes the lobe's integral the cap's solid angle, the paper's
    scale 1 is off by -6.9..+4 %); :func:`brdf_lobes` turns Lambert, Phong and Lafortune
    (spatially varying, and their Sums) into lobe sums of ``f_r cos``; :func:`sphere_set` fits
    ``n`` spheres to a closed mesh (volume k-means, radii by a coverage/fit objective);
    :func:`shadow_leaves` builds the paper's hierarchical visibility masks (quad-tree over the
    square facing the light, leaves of one of the :data:`MASK_MODES`) and :func:`shade_points`
    shades a set of points in the paper's order, reflectance x lighting then visibility with
    the eq. (39) weights (per leaf depth and per ``dist`` in :data:`DIST_NODES`; the package
    data file ``weights.json``, read by :mod:`._calibration`), culling products below the
    threshold ``t``; it returns radiance and products per point (the paper's Figure 16).
    :func:`shadow_features` gives what the weights multiply, for their calibration;
    :func:`cpu_threads` sets torch's CPU threads for a block. :func:`default_scene` and
    :func:`gbuffer` build the paper's kind of scene (its torus laid flat by
    :data:`FLAT_ROTATION`; :func:`rotation_about_y` turns it).

Elsewhere: the independent Monte Carlo reference is :func:`lobelight.reference.cosine.direct_mc`;
the score against it (and of the tables against adaptive quadrature) is
:mod:`lobelight.studies.lobes_score`, the benchmarks (the paper's two timed configurations, the
tables' build) :mod:`lobelight.bench.cosine`, the animation to PNGs/GIF
:mod:`lobelight.studies.lobes_demo`, and the calibration of the weights (which writes
``weights.json``) the source tree's ``tools/calibrate_cosine_weights.py``.
"""

from ._brdf_lobes import brdf_lobes
from ._light import SphereLight, cap_lobe, light_lobes
from ._lobe import evaluate, from_vector, integral, product_integral, product_peak
from ._lobeset import Lobes
from ._scene import FLAT_ROTATION, LobeScene, default_scene, gbuffer, rotation_about_y
from ._shade import ShadeResult, shade_points, shadow_features
from ._spheres import SphereSet, sphere_set, winding_number
from ._tables import (
    FORMAT_VERSION,
    LobeTables,
    TableParams,
    build_tables,
    cache_dir,
    cap_exponent,
    cpu_threads,
    default_path,
    fit_cap_exponent,
    fit_product,
    get_tables,
    load_tables,
    product,
    save_tables,
)
from ._visibility import DIST_NODES, MASK_MODES, shadow_leaves

__all__ = [
    "DIST_NODES",
    "FLAT_ROTATION",
    "FORMAT_VERSION",
    "MASK_MODES",
    "LobeScene",
    "LobeTables",
    "Lobes",
    "ShadeResult",
    "SphereLight",
    "SphereSet",
    "TableParams",
    "brdf_lobes",
    "build_tables",
    "cache_dir",
    "cap_exponent",
    "cap_lobe",
    "cpu_threads",
    "default_path",
    "default_scene",
    "evaluate",
    "fit_cap_exponent",
    "fit_product",
    "from_vector",
    "gbuffer",
    "get_tables",
    "integral",
    "light_lobes",
    "load_tables",
    "product",
    "product_integral",
    "product_peak",
    "rotation_about_y",
    "save_tables",
    "shade_points",
    "shadow_features",
    "shadow_leaves",
    "sphere_set",
    "winding_number",
]
