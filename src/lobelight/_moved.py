"""Old import paths that keep working: a module or name that has a new home resolves to it.

The package's layout (``DEVELOPERS.md``) gives each concept one home. Code written against an
earlier layout (``lobelight.sg``, ``lobelight.sgbrdf.compare_brdf``) still runs: the old module
path is an alias of the new module (the same object, not a copy) and the old attribute is looked
up in its new module, each with a :class:`DeprecationWarning` that names the new home.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings
from types import ModuleType
from typing import Any

__all__ = ["ATTRIBUTES", "MODULES", "attribute", "install", "renamed"]

#: Old module path -> its home (a package's submodules follow their package).
MODULES: dict[str, str] = {
    "lobelight.sphere": "lobelight.geometry.sphere",
    "lobelight.cubemap": "lobelight.geometry.cubemap",
    "lobelight.camera": "lobelight.geometry.camera",
    "lobelight.raycast": "lobelight.geometry.raycast",
    "lobelight.sg": "lobelight.lobes.sg",
    "lobelight.sh": "lobelight.lobes.sh",
    "lobelight.haar": "lobelight.lobes.haar",
    "lobelight.mitsuba_export": "lobelight.reference.mitsuba",
    "lobelight.compare": "lobelight.studies.compare",
    "lobelight.energy": "lobelight.studies.energy",
    "lobelight.figure5": "lobelight.studies.figure5",
    "lobelight.bench": "lobelight.studies.bench",
    "lobelight.demo": "lobelight.studies.demo",
    "lobelight.gallery": "lobelight.studies.gallery",
}

#: Package -> {name it exported: the module that holds it now}.
ATTRIBUTES: dict[str, dict[str, str]] = {
    "lobelight.sgbrdf": {
        "compare_brdf": "lobelight.studies.compare_brdf",
        "METHODS": "lobelight.studies.compare_brdf",
        "default_envmap": "lobelight.studies.compare_brdf",
        "bench_fit": "lobelight.studies.bench_brdf_fit",
        "shade_reference": "lobelight.reference.sgbrdf",
    },
    "lobelight.render": {
        "bench_gl": "lobelight.studies.bench_sgbrdf_gl",
    },
    "lobelight.cosine": {
        "bench_lobes": "lobelight.studies.bench_lobes",
        "bench_tables": "lobelight.studies.bench_lobes",
        "lobes_demo": "lobelight.studies.lobes_demo",
        "score": "lobelight.studies.lobes_score",
        "table_error": "lobelight.studies.lobes_score",
        "calibrate_weights": "lobelight.studies.lobes_calibrate",
        "write_weights": "lobelight.studies.lobes_calibrate",
        "direct_mc": "lobelight.reference.cosine",
    },
}


def _home(fullname: str) -> str | None:
    for old, new in MODULES.items():
        if fullname == old or fullname.startswith(old + "."):
            return new + fullname[len(old) :]
    return None


def _warn(old: str, new: str, stacklevel: int) -> None:
    warnings.warn(
        f"{old} is now {new}; import it from there", DeprecationWarning, stacklevel=stacklevel
    )


class _Alias(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds an old module path and loads it as the module at its new home."""

    def find_spec(self, fullname: str, path: Any = None, target: Any = None):
        new = _home(fullname)
        if new is None:
            return None
        home = importlib.util.find_spec(new)
        if home is None:
            return None
        return importlib.util.spec_from_loader(
            fullname, self, is_package=home.submodule_search_locations is not None
        )

    def get_code(self, fullname: str):
        # runpy asks for the code of `python -m OLD`: the module's relative imports would not
        # resolve under the old name, so say the new one
        old, new = fullname.removesuffix(".__main__"), _home(fullname).removesuffix(".__main__")
        raise ImportError(f"{old} is now {new}: run python -m {new}")

    def create_module(self, spec) -> ModuleType:
        new = _home(spec.name)
        _warn(spec.name, new, 2)
        module = importlib.import_module(new)
        # the import machinery stamps the alias's spec on the module it is given: keep the
        # module's own, so that it still knows its one true name
        self._spec = module.__spec__
        return module

    def exec_module(self, module: ModuleType) -> None:
        module.__spec__ = self._spec


_ALIAS = _Alias()


def install() -> None:
    """Resolve the old module paths from now on (idempotent; ``lobelight`` calls it)."""
    if _ALIAS not in sys.meta_path:
        # first: an old package's submodule would otherwise be found again through the new
        # package's __path__ and loaded a second time under the old name
        sys.meta_path.insert(0, _ALIAS)


def attribute(package: str, name: str) -> Any:
    """A name ``package`` exported before it moved, from its new module (for ``__getattr__``).

    Raises ``AttributeError`` for a name that never moved, as a missing attribute does.
    """
    new = ATTRIBUTES.get(package, {}).get(name)
    if new is None:
        raise AttributeError(f"module {package!r} has no attribute {name!r}")
    _warn(f"{package}.{name}", f"{new}.{name}", 4)  # the caller of __getattr__
    return getattr(importlib.import_module(new), name)


def renamed(old: str, new: str) -> None:
    """Warn that ``old`` (an attribute or keyword still accepted) is now called ``new``."""
    warnings.warn(f"{old} is now {new}", DeprecationWarning, stacklevel=3)
