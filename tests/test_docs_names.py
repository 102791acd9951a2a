"""The docs and docstrings name only what exists: every dotted ``lobelight.…`` name in the
README, DEVELOPERS.md, docs/ and the package's own source, and every relative Sphinx reference
(``:func:`~._module.name```) in a docstring, resolves to a module or an attribute of one today.

A rename that leaves a reference behind fails here, naming the file and line."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

import lobelight
from conftest import ROOT

PACKAGE = Path(lobelight.__file__).parent

#: ``lobelight.a.b.c`` — a dotted name, stopped before a trailing dot or a file suffix.
_DOTTED = re.compile(r"(?<![\w./-])lobelight(?:\.[A-Za-z_]\w*)+")
#: A relative Sphinx reference in a docstring: ``:func:`~._mod.name``` or ``:mod:`.sub```.
_RELATIVE = re.compile(r":(?:mod|func|class|meth|attr|data|obj):`~?(\.+[\w.]*)`")


def _resolves(dotted: str) -> bool:
    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for name in parts[i:]:
            if not hasattr(obj, name):
                # a module not yet imported as an attribute of its package
                try:
                    obj = importlib.import_module(f"{obj.__name__}.{name}")
                except (ImportError, AttributeError):
                    return False
            else:
                obj = getattr(obj, name)
        return True
    return False


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _docs() -> list[Path]:
    return [ROOT / "README.md", ROOT / "DEVELOPERS.md", *sorted((ROOT / "docs").glob("*.md"))]


def _sources() -> list[Path]:
    return sorted(PACKAGE.rglob("*.py"))


def _dangling(path: Path, text: str, names: list[tuple[int, str]]) -> list[str]:
    return [f"{path.name}:{line}: {name}" for line, name in names if not _resolves(name)]


@pytest.mark.parametrize("path", _docs() + _sources(), ids=lambda p: p.name)
def test_every_dotted_name_resolves(path):
    text = path.read_text()
    names = [
        (text.count("\n", 0, m.start()) + 1, m.group(0).rstrip(".")) for m in _DOTTED.finditer(text)
    ]
    bad = _dangling(path, text, names)
    assert not bad, "names that do not resolve:\n" + "\n".join(bad)


@pytest.mark.parametrize("path", _sources(), ids=lambda p: _module_name(p))
def test_every_relative_reference_in_a_docstring_resolves(path):
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    text = path.read_text()
    names = []
    for m in _RELATIVE.finditer(text):
        ref = m.group(1)
        dots = len(ref) - len(ref.lstrip("."))
        base = package.split(".")[: len(package.split(".")) - (dots - 1)]
        rest = ref.lstrip(".")
        names.append(
            (text.count("\n", 0, m.start()) + 1, ".".join(base + ([rest] if rest else [])))
        )
    bad = _dangling(path, text, names)
    assert not bad, "references that do not resolve:\n" + "\n".join(bad)
