"""Cosine lobes for dynamic direct lighting (the cosine-lobes paper, ``papers/`` in shared).

Every term of the rendering equation as sums of lobes ``c(w) = s max(a.w, 0)^e``, multiplied and
integrated through scene-independent tables.

Lobes (:mod:`._lobe`)
    :func:`evaluate`, :func:`integral` (``2 pi s/(e+1)``, exact: no integral table is needed),
    :func:`from_vector` (Lafortune's non-unit lobe vectors), :func:`product_peak` (the product
    lobe's axis, in closed form), :func:`product_integral` (``∫ c1 c2``, exact up to quadrature).

Tables (:mod:`._tables`)
    :func:`get_tables` loads the tables from the disk cache (``$LOBELIGHT_CACHE`` or
    ``~/.cache/lobelight``), building them once (seconds) when missing or of another version;
    :class:`LobeTables` looks up the product lobe (``partial scale, exponent``) and the
    spherical-cap exponent, trilinearly, on any device. :func:`product` multiplies two lobes
    given by axes, exponents and scales (the paper's L2-best scale, or with
    ``preserve_integral=True`` the scale that keeps the product's exact integral);
    :func:`cap_exponent` is the lobe of a spherical cap.
    :func:`fit_product` and :func:`fit_cap_exponent` are the direct fits the tables store;
    :func:`build_tables`, :func:`save_tables`, :func:`load_tables` and :func:`bench_tables`
    complete the set.
"""

from ._lobe import evaluate, from_vector, integral, product_integral, product_peak
from ._tables import (
    FORMAT_VERSION,
    LobeTables,
    TableParams,
    bench_tables,
    build_tables,
    cache_dir,
    cap_exponent,
    default_path,
    fit_cap_exponent,
    fit_product,
    get_tables,
    load_tables,
    product,
    save_tables,
)

__all__ = [
    "FORMAT_VERSION",
    "LobeTables",
    "TableParams",
    "bench_tables",
    "build_tables",
    "cache_dir",
    "cap_exponent",
    "default_path",
    "evaluate",
    "fit_cap_exponent",
    "fit_product",
    "from_vector",
    "get_tables",
    "integral",
    "load_tables",
    "product",
    "product_integral",
    "product_peak",
    "save_tables",
]
