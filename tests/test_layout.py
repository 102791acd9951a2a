"""The package's import graph: no circles, and no module importing one of a higher layer.

Every ``import`` in every module counts, function-local ones included (they hide the graph from
readers, not from this test). The layers, lowest first, are those of ``DEVELOPERS.md``:
foundations, geometry, lobes, BRDFs, inputs, transport, the model, the fits (the PRT fit and
the two companion methods), the renderers, ground truth, studies, the command line.
"""

from __future__ import annotations

import ast
from pathlib import Path

import lobelight

ROOT = Path(lobelight.__file__).parent

#: Top-level modules and packages by layer, lowest first.
LAYERS: list[tuple[str, ...]] = [
    (
        "errors",
        "_backend",
        "_checks",
        "_tol",
        "_io",
        "_cache",
        "_memory",
        "_container",
        "_lazy",
        "progress",
        "data",
    ),
    ("geometry",),
    ("lobes",),
    ("brdf",),
    ("envmap", "scene"),
    ("transport",),
    ("model",),
    ("fit", "sgbrdf", "cosine"),
    ("render",),
    ("web",),
    ("reference",),
    ("studies", "bench"),
    ("cli", "__main__"),
]


def _modules() -> dict[str, Path]:
    out = {}
    for p in ROOT.rglob("*.py"):
        parts = p.relative_to(ROOT.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        out[name] = p
    return out


def _import_targets(node: ast.AST, package: str) -> list[str] | None:
    """The dotted names an import statement brings in: a module, or ``module.name``."""
    if isinstance(node, ast.Import):
        return [a.name for a in node.names]
    if not isinstance(node, ast.ImportFrom):
        return None
    if node.level:
        base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
        mod = ".".join(base) + (f".{node.module}" if node.module else "")
    else:
        mod = node.module or ""
    return [f"{mod}.{a.name}" for a in node.names]


def _package(name: str, path: Path) -> str:
    return name if path.name == "__init__.py" else name.rsplit(".", 1)[0]


def _imports(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The lobelight modules ``name`` imports (a package's ``__init__`` for a package)."""
    package = _package(name, path)
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        targets = _import_targets(node, package)
        if targets is None:
            continue
        for t in targets:
            while t not in modules and "." in t:
                t = t.rsplit(".", 1)[0]
            if t in modules and t != name:
                found.add(t)
    return found


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    return {name: _imports(name, path, modules) for name, path in modules.items()}


def _rank(name: str) -> int:
    parts = name.split(".")
    top = parts[1] if len(parts) > 1 else "__init__"
    if parts[-1] == "__main__":  # python -m entry points are command lines
        top = "__main__"
    for i, layer in enumerate(LAYERS):
        if top in layer:
            return i
    raise AssertionError(f"{name} is in no layer: add its top-level name to LAYERS")


def test_every_module_has_a_layer():
    for name in _modules():
        if name != "lobelight":
            _rank(name)


def test_no_import_circles():
    graph = _graph()
    state: dict[str, int] = {}  # 1 on the current path, 2 done
    path: list[str] = []
    circles = []

    def visit(v: str) -> None:
        state[v] = 1
        path.append(v)
        for w in sorted(graph[v]):
            if state.get(w) == 1:
                circles.append([*path[path.index(w) :], w])
            elif w not in state:
                visit(w)
        path.pop()
        state[v] = 2

    for v in sorted(graph):
        if v not in state:
            visit(v)
    assert not circles, "import circles: " + "; ".join(" -> ".join(c) for c in circles)


def test_no_module_imports_a_higher_layer():
    bad = []
    for a, targets in _graph().items():
        if a == "lobelight":
            continue
        bad += [f"{a} -> {b}" for b in sorted(targets) if b != "lobelight" and _rank(b) > _rank(a)]
    assert not bad, "imports from a lower layer to a higher one:\n" + "\n".join(bad)


def _home_package(name: str, modules: dict[str, Path]) -> str:
    """``lobelight.X`` for a module under the subpackage X, ``""`` for a root module."""
    parts = name.split(".")
    if len(parts) < 2:
        return ""
    sub = f"lobelight.{parts[1]}"
    return sub if modules[sub].name == "__init__.py" else ""


def _private_reaches(name: str, path: Path, modules: dict[str, Path]) -> list[str]:
    """Where module ``name`` uses a private module or name of another subpackage: imported
    (``from ..a._b import c``, ``from ..a.b import _c``) or reached by attribute (``b._c``).
    The root package's own modules (``lobelight._io``, ``_checks``, ...) are the shared
    foundations and count as public to every subpackage."""
    home = _home_package(name, modules)
    bound: dict[str, str] = {}  # local name -> the lobelight module it is bound to
    bad = []
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        for full in _import_targets(node, _package(name, path)) or []:
            mod = full
            while mod not in modules and "." in mod:
                mod = mod.rsplit(".", 1)[0]
            if mod not in modules:
                continue
            other = _home_package(mod, modules)
            if other and other != home:
                inner = full[len(other) + 1 :].split(".")
                if any(s.startswith("_") and not s.startswith("__") for s in inner):
                    bad.append(f"{name}:{node.lineno}: {full}")
            if full in modules and isinstance(node, ast.ImportFrom):
                alias = next(a for a in node.names if full.endswith("." + a.name))
                bound[alias.asname or alias.name] = full
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Attribute)
            and isinstance(node.value, ast.Name)
            and node.value.id in bound
            and node.attr.startswith("_")
            and not node.attr.startswith("__")
        ):
            other = _home_package(bound[node.value.id], modules)
            if other and other != home:
                bad.append(f"{name}:{node.lineno}: {bound[node.value.id]}.{node.attr}")
    return bad


def test_no_package_reaches_into_another_packages_private_names():
    """A façade means what it says: a subpackage uses another subpackage's public names only
    (those its ``__init__`` or its public modules export), never a ``_module`` or ``_name``."""
    modules = _modules()
    bad = [hit for name, path in modules.items() for hit in _private_reaches(name, path, modules)]
    assert not bad, "private names used across packages:\n" + "\n".join(sorted(bad))


def test_every_function_local_import_is_an_optional_dependency():
    """Imports sit at the top; inside a function only an optional dependency's, with a comment
    on its line (or the line above) that names which."""
    bad = []
    for name, path in _modules().items():
        lines = path.read_text().splitlines()
        for fn in ast.walk(ast.parse(path.read_text())):
            if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            for node in ast.walk(fn):
                if isinstance(node, (ast.Import, ast.ImportFrom)):
                    here = lines[node.lineno - 1] + lines[node.lineno - 2]
                    if "optional" not in here:
                        bad.append(f"{name}:{node.lineno}: {ast.unparse(node)}")
    assert not bad, "function-local imports:\n" + "\n".join(bad)


def test_only_the_process_module_changes_the_process():
    """Environment variables and the allocator are the process owner's (the command line's,
    through :mod:`lobelight.cli._process`), never set by library code as a side effect."""
    bad = []
    for name, path in _modules().items():
        if name in ("lobelight.cli._process", "lobelight.cli"):
            continue
        text = path.read_text()
        for needle in ("os.environ[", "os.environ.setdefault", "os.putenv", "mallopt"):
            if needle in text:
                bad.append(f"{name}: {needle}")
    assert not bad, "\n".join(bad)
