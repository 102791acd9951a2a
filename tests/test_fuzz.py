"""Fuzzing the file loaders: mutated files give one InputError naming the file, or load cleanly.

Every loader of user files (model, scene, mesh, environment map, cosine lobe tables) is fed
thousands of mutated versions of a small valid file: byte flips, truncations, insertions and
deletions anywhere (biased towards the headers at both ends, where containers keep their
structure), and structured mutations that keep the container valid but break what it holds
(arrays of the wrong shape or dtype, NaN, negative widths, out-of-range indices, JSON values of
the wrong type, unknown keys, missing files). The only acceptable outcomes are an
:class:`~lobelight.errors.InputError` whose message names the file, or a successful load whose
result is sane (finite numbers, indices in range) - never another exception type, and never a
hang (each load runs under an alarm).

Hypothesis runs with ``derandomize=True`` and no example database, so CI sees the same inputs
every time; the example counts keep the whole file within about a minute on a 2-core machine.
The long run (``tools/fuzz.py``, not in CI) runs the same tests with random inputs and its own
counts (``LOBELIGHT_FUZZ_EXAMPLES``), a memory limit per process (``LOBELIGHT_FUZZ_MEMORY_GB``)
and a tally of the outcomes per test (``LOBELIGHT_FUZZ_TALLY``: a JSON file written at the end).
"""

from __future__ import annotations

import collections
import contextlib
import copy
import io
import json
import math
import os
import resource
import signal
import tempfile
import time
import warnings
from pathlib import Path

import cv2
import numpy as np
import OpenEXR
import pytest
import torch
import trimesh
from hypothesis import HealthCheck, Phase, example, given, settings
from hypothesis import strategies as st

from conftest import tiny_table_params
from lobelight import cli, cosine, envmap, fit, model, scene
from lobelight.cli import _commands
from lobelight.errors import InputError
from lobelight.fit import Gaussians, MeshFit, _checkpoint
from lobelight.geometry import sphere
from lobelight.model import _format as _model_format
from lobelight.scene._mesh import MAX_WELD_LOSS
from test_gltf import Gltf, _checker, two_material_quads

# one load may take this long before it counts as a hang (loads here take milliseconds)
LOAD_SECONDS = 10.0

#: The long run's settings (tools/fuzz.py); unset in CI.
LONG_EXAMPLES = int(os.environ.get("LOBELIGHT_FUZZ_EXAMPLES", "0"))
TALLY_FILE = os.environ.get("LOBELIGHT_FUZZ_TALLY")
if os.environ.get("LOBELIGHT_FUZZ_MEMORY_GB"):
    # a load that asks for more raises MemoryError, which fails the test: a memory blow-up
    _limit = int(float(os.environ["LOBELIGHT_FUZZ_MEMORY_GB"]) * (1 << 30))
    resource.setrlimit(resource.RLIMIT_AS, (_limit, _limit))

#: Per test: loads that gave a clean InputError, and loads that were accepted (and sane).
TALLY: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)


def _tally(outcome: str) -> None:
    test = os.environ.get("PYTEST_CURRENT_TEST", "?").split("::")[-1].split(" ")[0]
    TALLY[test][outcome] += 1


@pytest.fixture(scope="module", autouse=True)
def _write_tally():
    yield
    if TALLY_FILE:
        Path(TALLY_FILE).write_text(json.dumps({k: dict(v) for k, v in TALLY.items()}))


def fuzz(n: int):
    """Deterministic hypothesis settings for ``n`` examples (no database, no deadline); in the
    long run, ``LOBELIGHT_FUZZ_EXAMPLES`` random examples instead.

    No shrinking: a failing example is already a handful of mutations of a small file, and
    shrinking a loader fuzz can take minutes; the first failure is reported as generated.
    """
    return settings(
        max_examples=LONG_EXAMPLES or n,
        deadline=None,
        derandomize=not LONG_EXAMPLES,
        database=None,
        phases=(Phase.explicit, Phase.generate),
        report_multiple_bugs=False,
        suppress_health_check=[
            HealthCheck.function_scoped_fixture,  # files are rewritten at each example
            HealthCheck.too_slow,
            HealthCheck.data_too_large,
        ],
    )


class Hang(BaseException):
    """A load ran past :data:`LOAD_SECONDS` (not an Exception: loaders' handlers let it pass)."""


@contextlib.contextmanager
def _time_limit(seconds: float):
    def on_alarm(signum, frame):
        raise Hang(f"load took more than {seconds} s")

    alarm = hasattr(signal, "setitimer")  # POSIX; elsewhere only the elapsed time is checked
    if alarm:
        old = signal.signal(signal.SIGALRM, on_alarm)
        signal.setitimer(signal.ITIMER_REAL, seconds)
    t0 = time.perf_counter()
    try:
        yield
    finally:
        if alarm:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, old)
    # a hang inside C code is not interrupted by the alarm, but is still caught here
    assert time.perf_counter() - t0 < seconds, "load hung"


def load_or_input_error(loader, path: Path, *names: str):
    """``loader(path)``, or None when it raises InputError naming the file (or one of ``names``).

    Any other exception propagates and fails the test.
    """
    with _time_limit(LOAD_SECONDS):
        try:
            result = loader(path)
        except InputError as exc:
            msg = str(exc)
            assert any(n in msg for n in (str(path), *names)), f"message names no file: {msg}"
            assert "\n" not in msg, f"not a one-line error: {msg!r}"
            _tally("clean_errors")
            return None
    _tally("accepted")
    return result


# --------------------------------------------------------------------------------------------
# byte mutations

_BYTE_OPS = ("flip", "set", "truncate", "delete", "insert", "zero", "dup")
# positions: near the start (magic numbers, headers), near the end (zip central directory,
# trailers), or anywhere; taken modulo the length, so negative ones count from the end
_POS = st.one_of(st.integers(0, 127), st.integers(-512, -1), st.integers(0, 1 << 30))
byte_ops = st.lists(
    st.tuples(st.sampled_from(_BYTE_OPS), _POS, st.integers(0, 255)), min_size=1, max_size=4
)


def mutate_bytes(data: bytes, ops) -> bytes:
    """Apply byte-level mutations (see :data:`byte_ops`) to ``data``."""
    b = bytearray(data)
    for kind, pos, val in ops:
        if not b:
            break
        i = pos % len(b)
        if kind == "flip":
            b[i] ^= 1 << (val % 8)
        elif kind == "set":
            b[i] = val
        elif kind == "truncate":
            del b[i:]
        elif kind == "delete":
            del b[i : i + 1 + val % 16]
        elif kind == "insert":
            b[i:i] = bytes([val]) * (1 + val % 8)
        elif kind == "zero":
            k = min(len(b) - i, 1 + val % 32)
            b[i : i + k] = bytes(k)
        else:  # dup: repeat a chunk in place
            b[i:i] = b[i : i + 1 + val % 64]
    return bytes(b)


# random JSON-like values: every type a parser can hand to a loader, including NaN and huge ints
_json_scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(2**70), 2**70),
    st.sampled_from([0, 1, -1, 2, 3, 12, 10**400, -(10**400)]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=8),
)
json_values = st.recursive(
    _json_scalars,
    lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=6), c, max_size=4),
    max_leaves=8,
)


def _paths(d, prefix=()):
    """Every key path into nested dicts and lists (lists only to depth 1 element)."""
    out = []
    items = d.items() if isinstance(d, dict) else enumerate(d) if isinstance(d, list) else ()
    for k, v in items:
        out.append((*prefix, k))
        out.extend(_paths(v, (*prefix, k)))
    return out


def mutate_json(doc, ops):
    """Apply ``(op, path index, value)`` mutations to a deep copy of a JSON document."""
    doc = copy.deepcopy(doc)
    for op, which, value in ops:
        value = copy.deepcopy(value)  # sampled values are shared objects: never alias them
        paths = _paths(doc)
        if not paths:
            break
        path = paths[which % len(paths)]
        parent = doc
        for k in path[:-1]:
            parent = parent[k]
        key = path[-1]
        if op == "delete":
            del parent[key]
        elif op == "replace":
            parent[key] = value
        elif op == "add" and isinstance(parent, dict):
            parent[str(value)[:8] + "_x"] = value
        elif op == "wrap":
            parent[key] = [parent[key]]
    return doc


_JSON_OPS = ["delete", "replace", "replace", "add", "wrap"]
#: The edits of the glTF and scene documents: replacing weighs more there.
_DOC_OPS = ["delete", "replace", "replace", "replace", "add", "wrap"]


def _edits(values, names=_JSON_OPS):
    """Lists of one to three (operation, position, value) edits of a JSON-like document."""
    return st.lists(
        st.tuples(st.sampled_from(names), st.integers(0, 999), values), min_size=1, max_size=3
    )


json_ops = _edits(json_values)


def _finite(t) -> bool:
    return bool(torch.isfinite(torch.as_tensor(t)).all())


# --------------------------------------------------------------------------------------------
# model files


def _tiny_fit(v: int, j: int, n: int) -> MeshFit:
    g = torch.Generator().manual_seed(1)
    w = torch.rand(v, j, n, 3, generator=g)
    w[:, : j // 2] = 0  # some records dropped
    mu = torch.nn.functional.normalize(torch.randn(v, j, n, 3, generator=g), dim=-1)
    lam = torch.rand(v, j, n, generator=g) * 100 + 1
    diffuse = torch.rand(v, 9, 3, generator=g)
    views = sphere.geodesic_views()[:j]  # a model's views are the 92 geodesic ones
    return MeshFit(Gaussians(w, mu, lam), diffuse, views, torch.zeros(v))


@pytest.fixture(scope="module")
def model_files(tmp_path_factory):
    """Small valid model files: float32 (uncompressed-size friendly) and float16."""
    d = tmp_path_factory.mktemp("model")
    sc = scene.builtin("sphere", subdivisions=0, model="ggx", roughness=0.2)
    mf = _tiny_fit(sc.mesh.n_vertices, 92, 2)
    out = _Files()
    for half in (False, True):
        p = d / f"m{int(half)}.npz"
        model.save(p, sc.mesh, sc.materials, mf, float16=half, provenance={"scene": "s"})
        assert model.load(p).mesh.n_vertices == sc.mesh.n_vertices
        with np.load(p, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        out[half] = (p.read_bytes(), arrays)
    return out


class _Files(dict):
    """Fixture data, with a short repr for hypothesis' failure reports."""

    def __repr__(self) -> str:
        return f"<{len(self)} files>"


def _check_model(m) -> None:
    g = m.gaussians
    assert _finite(g.w) and _finite(g.mu) and _finite(g.lam) and _finite(m.diffuse)
    assert bool((g.lam > 0).all()) and bool((g.w >= 0).all())
    assert _finite(m.mesh.vertices) and _finite(m.mesh.normals)
    f = m.mesh.faces
    assert f.numel() == 0 or (int(f.min()) >= 0 and int(f.max()) < m.mesh.n_vertices)
    assert m.materials.n_vertices == m.mesh.n_vertices


def _load_model(path: Path) -> None:
    m = load_or_input_error(model.load, path)
    if m is not None:
        _check_model(m)


def _npz_bytes(arrays: dict, compressed: bool = False) -> bytes:
    buf = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(buf, **arrays)
    return buf.getvalue()


@fuzz(600)
@given(half=st.booleans(), ops=byte_ops)
def test_fuzz_model_bytes(tmp_path, model_files, half, ops):
    data, _ = model_files[half]
    p = tmp_path / "m.npz"
    p.write_bytes(mutate_bytes(data, ops))
    _load_model(p)


_DTYPES = [
    np.int8, np.uint8, np.int32, np.int64, np.float16, np.float32, np.float64,
    np.complex64, np.bool_, "<U3", "S2", "<M8[s]", [("a", "<f4"), ("b", "<i2")],
]  # fmt: skip
_ARRAY_OPS = ("shape", "dtype", "bad_value", "scalar", "missing", "transpose", "empty")
_BAD_VALUES = [np.nan, np.inf, -np.inf, -1.0, 0.0, -1e30, 1e30, 1e-30, 65504.0, 2**31 - 1, 12]


@st.composite
def array_mutation(draw, keys):
    key = draw(st.sampled_from(keys))
    op = draw(st.sampled_from(_ARRAY_OPS))
    shape = tuple(draw(st.lists(st.integers(0, 5), max_size=3)))
    dtype = draw(st.sampled_from(range(len(_DTYPES))))
    value = draw(st.sampled_from(_BAD_VALUES))
    where = draw(st.integers(0, 1 << 20))
    return key, op, shape, dtype, value, where


def apply_array_mutation(arrays: dict, mutation) -> dict:
    key, op, shape, dtype, value, where = mutation
    arrays = dict(arrays)
    a = arrays[key]
    if op == "shape":
        arrays[key] = np.zeros(shape, a.dtype)
    elif op == "dtype":
        dt = np.dtype(_DTYPES[dtype])
        try:
            arrays[key] = np.zeros(a.shape, dt) if dt.fields or dt.kind == "M" else a.astype(dt)
        except (TypeError, ValueError):  # text that is no number
            arrays[key] = np.zeros(a.shape, dt)
    elif op == "bad_value":
        b = a.copy()
        if b.size:
            flat = b.reshape(-1)
            with np.errstate(all="ignore"):
                try:
                    flat[where % flat.size] = value
                except (ValueError, OverflowError):  # NaN or -1 into integers: wrap around
                    flat[where % flat.size] = np.array(value).astype(b.dtype)
        arrays[key] = b
    elif op == "scalar":
        arrays[key] = np.array(value)
    elif op == "missing":
        del arrays[key]
    elif op == "transpose":
        arrays[key] = a.T.copy()
    else:
        arrays[key] = a[:0] if a.ndim else np.zeros(0, a.dtype)
    return arrays


_MODEL_KEYS = ("vertices", "faces", "normals", "views", "keep", "gaussians", "diffuse", "meta")


@fuzz(500)
@given(half=st.booleans(), muts=st.lists(array_mutation(_MODEL_KEYS), min_size=1, max_size=2))
def test_fuzz_model_arrays(tmp_path, model_files, half, muts):
    _, arrays = model_files[half]
    for mut in muts:
        if mut[0] in arrays:
            arrays = apply_array_mutation(arrays, mut)
    p = tmp_path / "m.npz"
    p.write_bytes(_npz_bytes(arrays))
    _load_model(p)


@st.composite
def meta_mutation(draw):
    kind = draw(st.sampled_from(["json", "json", "json", "raw", "version", "top"]))
    if kind == "json":
        return kind, draw(json_ops)
    if kind == "raw":  # the JSON text itself damaged
        return kind, draw(byte_ops)
    if kind == "version":
        return kind, draw(st.tuples(json_values, json_values))
    return kind, draw(json_values)  # something other than an object at the top


def mutated_meta(meta: dict, mut, pair: tuple[str, str]) -> bytes:
    """The metadata's JSON text after a :func:`meta_mutation` (its "version" kind replaces the
    two keys ``pair``: the format and version of a model, the stage and next chunk of a
    checkpoint)."""
    kind, arg = mut
    if kind == "json":
        return json.dumps(mutate_json(meta, arg)).encode()
    if kind == "raw":
        return mutate_bytes(json.dumps(meta).encode(), arg)
    if kind == "version":
        return json.dumps({**meta, pair[0]: arg[0], pair[1]: arg[1]}).encode()
    return json.dumps(arg).encode()


@fuzz(500)
@given(half=st.booleans(), mut=meta_mutation())
def test_fuzz_model_meta(tmp_path, model_files, half, mut):
    _, arrays = model_files[half]
    meta = json.loads(bytes(arrays["meta"]).decode())
    text = mutated_meta(meta, mut, ("format", "version"))
    arrays = {**arrays, "meta": np.frombuffer(text, dtype=np.uint8)}
    p = tmp_path / "m.npz"
    p.write_bytes(_npz_bytes(arrays))
    _load_model(p)


# --------------------------------------------------------------------------------------------
# meshes


def _mesh_texts() -> dict[str, bytes]:
    m = trimesh.creation.icosphere(0)
    out = {}
    for ext in ("obj", "off", "ply", "stl"):
        out[ext] = (
            m.export(file_type=ext, encoding="ascii") if ext == "ply" else m.export(file_type=ext)
        )
    out["stl_ascii"] = trimesh.exchange.stl.export_stl_ascii(m)
    out["ply_binary"] = m.export(file_type="ply")
    return {k: v.encode() if isinstance(v, str) else bytes(v) for k, v in out.items()}


MESHES = _mesh_texts()
_SUFFIX = {"stl_ascii": "stl", "ply_binary": "ply"}
_TOKENS = [
    "nan", "inf", "-inf", "1e39", "1e308", "-1e308", "-1", "0", "1", "2", "3", "12", "99999",
    "2147483648", "-2147483649", "1e999", "abc", "", "1.5", "0x10", "\x00", "3 4", "-0",
]  # fmt: skip


def mutate_text(data: bytes, ops) -> bytes:
    """Token- and line-level mutations of a text file: numbers replaced by bad ones, lines
    deleted, duplicated or swapped."""
    lines = data.split(b"\n")
    for kind, pos, val in ops:
        if not lines:
            break
        i = pos % len(lines)
        if kind == "token":
            toks = lines[i].split(b" ")
            toks[val % len(toks)] = _TOKENS[val % len(_TOKENS)].encode()
            lines[i] = b" ".join(toks)
        elif kind == "delete":
            del lines[i]
        elif kind == "dup":
            lines.insert(i, lines[i])
        elif kind == "swap":
            j = val % len(lines)
            lines[i], lines[j] = lines[j], lines[i]
        else:  # truncate
            del lines[i:]
    return b"\n".join(lines)


text_ops = st.lists(
    st.tuples(
        st.sampled_from(["token", "token", "token", "delete", "dup", "swap", "truncate"]),
        st.integers(0, 1 << 16),
        st.integers(0, 1 << 16),
    ),
    min_size=1,
    max_size=4,
)


def _check_mesh(m) -> None:
    assert m.n_faces > 0 and _finite(m.vertices) and _finite(m.normals)
    assert int(m.faces.min()) >= 0 and int(m.faces.max()) < m.n_vertices
    assert math.isfinite(m.scale) and m.scale > 0


@fuzz(500)
@given(
    kind=st.sampled_from(["obj", "off", "ply", "stl_ascii"]),
    ops=text_ops,
    also_bytes=st.one_of(st.none(), byte_ops),
)
def test_fuzz_mesh_text(tmp_path, kind, ops, also_bytes):
    data = mutate_text(MESHES[kind], ops)
    if also_bytes is not None:
        data = mutate_bytes(data, also_bytes)
    p = tmp_path / f"m.{_SUFFIX.get(kind, kind)}"
    p.write_bytes(data)
    m = load_or_input_error(scene.load_mesh, p)
    if m is not None:
        _check_mesh(m)


@fuzz(500)
@given(kind=st.sampled_from(["ply_binary", "stl", "obj", "off"]), ops=byte_ops)
def test_fuzz_mesh_bytes(tmp_path, kind, ops):
    p = tmp_path / f"m.{_SUFFIX.get(kind, kind)}"
    p.write_bytes(mutate_bytes(MESHES[kind], ops))
    m = load_or_input_error(scene.load_mesh, p)
    if m is not None:
        _check_mesh(m)


# --------------------------------------------------------------------------------------------
# glTF assets


@pytest.fixture(scope="module")
def gltf_files(tmp_path_factory):
    """A two-material textured glTF (tests/test_gltf.py's builder) as .glb bytes and as a
    .gltf document with an external .bin and .png beside it."""
    d = tmp_path_factory.mktemp("gltf")
    g = Gltf()
    two_material_quads(g)
    _, png = g.image(_checker(), uri="albedo.png")
    g.doc["materials"][1]["normalTexture"] = {"index": len(g.doc["textures"]) - 1}
    (d / "albedo.png").write_bytes(png)
    g.write(d / "a.glb", "glb")
    g.write(d / "a.gltf", "external")
    assert scene.load_gltf(d / "a.glb").mesh.n_vertices == 8
    return _Files(dir=d, glb=(d / "a.glb").read_bytes(), doc=json.loads((d / "a.gltf").read_text()))


def _check_asset(a) -> None:
    _check_mesh(a.mesh)
    v = a.mesh.n_vertices
    assert a.uvs.shape == (v, 2) and a.colors.shape == (v, 4) and a.material.shape == (v,)
    assert _finite(a.uvs) and _finite(a.colors)
    assert int(a.material.min()) >= 0 and int(a.material.max()) < len(a.materials)
    for m in a.materials:
        for t in (m.base_color_texture, m.metallic_roughness_texture, m.normal_texture):
            assert t is None or (_finite(t.image) and t.image.ndim == 3)
    f = scene.vertex_factors(a)
    assert _finite(f.base_color) and _finite(f.metallic) and _finite(f.roughness)


def _load_asset(path: Path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # features named and not used
        a = load_or_input_error(scene.load_gltf, path)
    if a is not None:
        _check_asset(a)


@fuzz(200)
@given(ops=byte_ops)
# found by the long run: a UV's top byte set to 0xFF, -1.7e38, overflowed the texture read
@example(ops=[("set", -225, 255)])
def test_fuzz_glb_bytes(gltf_files, ops):
    p = gltf_files["dir"] / "m.glb"  # beside albedo.png, which it names
    p.write_bytes(mutate_bytes(gltf_files["glb"], ops))
    _load_asset(p)


# values a glTF writer might get wrong: indices, counts, offsets, enums, URIs
_GLTF_VALUES = st.one_of(
    json_values,
    st.sampled_from(
        [0, 1, 2, 3, 4, 5, 6, 7, -1, 99, 2**31, 2**40, 2**64, 5120, 5121, 5123, 5125, 5126, 9728,
         33071, 33648, "VEC2", "VEC3", "SCALAR", "MAT4", "missing.bin", "albedo.png", "a.bin",
         "data:application/octet-stream;base64,AAAA", "data:,x", "http://x/y.bin", [],
         [0, 0, 0], [1, 0, 0, 0], [-1, 1, 1], [0.0] * 16, [1e308] * 3, {"KHR_x": {}},
         {"KHR_texture_transform": {"scale": [1e308, 0]}}, "BLEND", True, 0.5]
    ),
)  # fmt: skip


@fuzz(200)
@given(ops=_edits(_GLTF_VALUES, _DOC_OPS))
def test_fuzz_gltf_structured(gltf_files, ops):
    doc = mutate_json(gltf_files["doc"], ops)
    p = gltf_files["dir"] / "m.gltf"  # beside a.bin and albedo.png, which it may name
    p.write_text(json.dumps(doc))
    _load_asset(p)


# --------------------------------------------------------------------------------------------
# scene files

_SCENE = {
    "name": "ball",
    "mesh": "ball.obj",
    "environment": "builtin",
    "material": {"diffuse": [0.5] * 3, "model": "ggx", "specular": [0.8] * 3, "alpha": 0.1},
    "camera": {"origin": [0, 0, 4], "target": [0, 0, 0], "up": [0, 1, 0], "fov": 40},
}  # fmt: skip
_SCENE_GRADIENT = {
    "mesh": "ball.obj",
    "gradient": {
        "axis": [0, 1, 0],
        "from": {"diffuse": [0.8, 0.7, 0.1]},
        "to": {"diffuse": [0.1] * 3, "model": "phong", "specular": [0.3] * 3, "exponent": 20},
    },
}  # fmt: skip
# values a scene file's author might plausibly get wrong
_SCENE_VALUES = st.one_of(
    json_values,
    st.sampled_from(
        [
            "missing.obj", "", ".", "..", "/", "ball.obj\x00", "other.json", "env.hdr", "folder",
            "glass",
            "GGX", "none", -1, -0.5, 0, 1e308, float("nan"), float("inf"), 1e-300, 2**64,
            [1, 2], [0.5, 0.5, 0.5, 0.5], [[0.5, 0.5, 0.5]] * 3, {"diffuse": 2},
        ]
    ),
)  # fmt: skip


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        return ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v if x is not None) + "]"
    if isinstance(v, dict):
        items = (f"{json.dumps(k)} = {_toml_value(x)}" for k, x in v.items() if x is not None)
        return "{" + ", ".join(items) + "}"
    raise TypeError(type(v))


def to_toml(d: dict) -> str:
    """A TOML rendering of a JSON document (None dropped, tables inline)."""
    return "".join(f"{json.dumps(k)} = {_toml_value(v)}\n" for k, v in d.items() if v is not None)


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("scene")
    # every file a mutated scene may name exists or not from the start, so examples replay
    (d / "ball.obj").write_bytes(MESHES["obj"])
    (d / "env.hdr").write_bytes(_hdr_bytes(_img(4, 8)))
    (d / "other.json").write_text(json.dumps(_SCENE))
    (d / "folder").mkdir()
    return d


@fuzz(500)
@given(
    base=st.sampled_from([_SCENE, _SCENE_GRADIENT]),
    ops=_edits(_SCENE_VALUES, _DOC_OPS),
    fmt=st.sampled_from(["json", "toml"]),
)
def test_fuzz_scene_structured(scene_dir, base, ops, fmt):
    doc = mutate_json(base, ops)
    p = scene_dir / f"scene.{fmt}"
    p.write_text(json.dumps(doc) if fmt == "json" else to_toml(doc), encoding="utf-8")
    sc = load_or_input_error(scene.load, p, str(scene_dir))
    if sc is not None:
        _check_mesh(sc.mesh)
        assert _finite(sc.materials.diffuse) and isinstance(sc.name, str)
        spec = sc.materials.specular
        if spec is not None:
            assert all(_finite(v) for v in spec.params.values())


@fuzz(250)
@given(fmt=st.sampled_from(["json", "toml"]), base=st.sampled_from([_SCENE, _SCENE_GRADIENT]),
       ops=byte_ops, garbage=st.booleans(), noise=st.binary(max_size=64))  # fmt: skip
def test_fuzz_scene_bytes(scene_dir, fmt, base, ops, garbage, noise):
    text = (json.dumps(base) if fmt == "json" else to_toml(base)).encode()
    p = scene_dir / f"scene.{fmt}"
    p.write_bytes(noise if garbage else mutate_bytes(text, ops))
    sc = load_or_input_error(scene.load, p, str(scene_dir))
    if sc is not None:
        _check_mesh(sc.mesh)


# --------------------------------------------------------------------------------------------
# environment maps


def _img(h: int, w: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(0.01, 20.0, (h, w, 3)).astype(np.float32)


def _hdr_bytes(img: np.ndarray) -> bytes:
    ok, enc = cv2.imencode(".hdr", np.ascontiguousarray(img[..., ::-1]))
    assert ok
    return enc.tobytes()


def _exr_bytes(tmp: Path, img: np.ndarray, compression=OpenEXR.ZIP_COMPRESSION) -> bytes:
    p = tmp / "x.exr"
    OpenEXR.File({"compression": compression, "type": OpenEXR.scanlineimage}, {"RGB": img}).write(
        str(p)
    )
    return p.read_bytes()


@pytest.fixture(scope="module")
def env_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("env")
    lat, cross = _img(8, 16), _img(16, 12, 1)
    return _Files(
        hdr=[_hdr_bytes(lat), _hdr_bytes(cross), _hdr_bytes(_img(4, 8, 2))],  # RLE and flat
        exr=[
            _exr_bytes(d, lat),
            _exr_bytes(d, cross, OpenEXR.NO_COMPRESSION),
            _exr_bytes(d, lat, OpenEXR.PIZ_COMPRESSION),
        ],
    )


def _check_env(env) -> None:
    assert _finite(env.data) and bool((env.data >= 0).all())


@fuzz(600)
@given(which=st.integers(0, 2), ops=byte_ops, layout=st.sampled_from([None, None, "latlong"]))
def test_fuzz_envmap_hdr_bytes(tmp_path, env_files, which, ops, layout):
    p = tmp_path / "e.hdr"
    p.write_bytes(mutate_bytes(env_files["hdr"][which], ops))
    env = load_or_input_error(lambda q: envmap.load(q, layout=layout), p)
    if env is not None:
        _check_env(env)


@fuzz(600)
@given(which=st.integers(0, 2), ops=byte_ops)
def test_fuzz_envmap_exr_bytes(tmp_path, env_files, which, ops):
    p = tmp_path / "e.exr"
    p.write_bytes(mutate_bytes(env_files["exr"][which], ops))
    env = load_or_input_error(envmap.load, p)
    if env is not None:
        _check_env(env)


@fuzz(120)
@given(
    h=st.integers(1, 9),
    w=st.integers(1, 20),
    bad=st.lists(
        st.tuples(st.integers(0, 1 << 16), st.sampled_from([np.nan, np.inf, -np.inf, -1.0, 1e38])),
        max_size=3,
    ),
    ext=st.sampled_from(["hdr", "exr"]),
    sanitize=st.booleans(),
)
def test_fuzz_envmap_pixels_and_aspect(tmp_path, h, w, bad, ext, sanitize):
    img = _img(h, w)
    flat = img.reshape(-1)
    for pos, v in bad:
        flat[pos % flat.size] = v
    p = tmp_path / f"e.{ext}"
    p.write_bytes(_hdr_bytes(img) if ext == "hdr" else _exr_bytes(tmp_path, img))
    env = load_or_input_error(lambda q: envmap.load(q, sanitize=sanitize), p)
    if env is not None:
        _check_env(env)


# --------------------------------------------------------------------------------------------
# cosine lobe tables


@pytest.fixture(scope="module")
def table_file(tiny_table_path):
    with np.load(tiny_table_path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    return _Files(data=tiny_table_path.read_bytes(), arrays=arrays)


def _load_tables(path: Path) -> None:
    t = load_or_input_error(cosine.load_tables, path)
    if t is not None:
        assert _finite(t.product_table) and _finite(t.cap_table)


@fuzz(500)
@given(ops=byte_ops)
def test_fuzz_tables_bytes(tmp_path, table_file, ops):
    p = tmp_path / "t.npz"
    p.write_bytes(mutate_bytes(table_file["data"], ops))
    _load_tables(p)


@st.composite
def table_mutation(draw):
    kind = draw(st.sampled_from(["array", "array", "params", "params", "info"]))
    if kind == "array":
        return kind, draw(array_mutation(("format_version", "params", "info", "product", "cap")))
    if kind == "params":
        key = draw(st.sampled_from([*tiny_table_params().to_dict(), "extra"]))
        value = draw(
            st.one_of(
                json_values,
                st.sampled_from([0, -1, 1e300, 1e308, 10**400, 2**63, 0.5, 1e-300, "16"]),
            )
        )
        return kind, (key, value)
    return kind, draw(json_values)


@fuzz(200)
@given(mut=table_mutation())
def test_fuzz_tables_structured(tmp_path, table_file, mut):
    arrays = dict(table_file["arrays"])
    kind, arg = mut
    if kind == "array":
        arrays = apply_array_mutation(arrays, arg)
    elif kind == "params":
        params = {**tiny_table_params().to_dict(), arg[0]: arg[1]}
        arrays["params"] = np.array(json.dumps(params))
    else:
        arrays["info"] = np.array(json.dumps(arg))
    p = tmp_path / "t.npz"
    p.write_bytes(_npz_bytes(arrays))
    _load_tables(p)


# --------------------------------------------------------------------------------------------
# bake checkpoints


class _Stop(Exception):
    pass


@pytest.fixture(scope="module")
def checkpoint_file(tmp_path_factory):
    """A real checkpoint: a bake of a 12-vertex sphere stopped after its first chunk."""
    sc = scene.builtin("sphere", subdivisions=0, model="phong", exponent=200.0)
    path = tmp_path_factory.mktemp("ckpt") / "bake.ckpt.npz"

    def stop(stage, done, total):
        if stage == "fit" and done == 1:
            raise _Stop

    with pytest.raises(_Stop):
        fit.fit_mesh(sc, n=1, batch=2, checkpoint=path, checkpoint_every=0, progress=stop)
    with np.load(path, allow_pickle=False) as z:
        key = json.loads(bytes(z["meta"]).decode())["key"]
        shapes = {k: (z[k].shape, z[k].dtype) for k in z.files if k != "meta"}
    return path.read_bytes(), key, shapes, _checkpoint


def _resume_or_start_afresh(tmp_path, checkpoint_file, data: bytes) -> None:
    """A damaged checkpoint is moved aside and the bake starts afresh; a whole one resumes
    into finite state: never an exception, never a NaN model."""
    _, key, shapes, ff = checkpoint_file
    path = tmp_path / "bake.ckpt.npz"
    path.write_bytes(data)
    (tmp_path / "bake.ckpt.npz.corrupt").unlink(missing_ok=True)
    state = {k: torch.zeros(s, dtype=torch.from_numpy(np.zeros(0, d)).dtype) for k, (s, d) in
             shapes.items()}  # fmt: skip
    with _time_limit(LOAD_SECONDS):
        stage, nxt, fb, fa = ff.Checkpoint(path, key).resume(state)
    assert stage in ff.STAGES and nxt >= 0
    assert all(isinstance(x, int) for x in (*fb, *fa))
    if (stage, nxt) == ff.START[:2]:
        _tally("clean_errors")
    else:
        assert all(_finite(t) for t in state.values() if t.is_floating_point())
        _tally("accepted")


@fuzz(300)
@given(ops=byte_ops)
def test_fuzz_checkpoint_bytes(tmp_path, checkpoint_file, ops):
    _resume_or_start_afresh(tmp_path, checkpoint_file, mutate_bytes(checkpoint_file[0], ops))


@fuzz(200)
@given(mut=meta_mutation())
def test_fuzz_checkpoint_meta(tmp_path, checkpoint_file, mut):
    raw = checkpoint_file[0]
    with np.load(io.BytesIO(raw), allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(bytes(arrays["meta"]).decode())
    text = mutated_meta(meta, mut, ("stage", "next"))
    arrays["meta"] = np.frombuffer(text, dtype=np.uint8)
    _resume_or_start_afresh(tmp_path, checkpoint_file, _npz_bytes(arrays))


# --------------------------------------------------------------------------------------------
# command-line arguments


class _WorkStarted(BaseException):
    """Raised by the heavy steps a command reaches once its arguments are checked."""


#: The steps each command's work starts with, stood in for so that an input is a parse and
#: the checks, not a bake or a render.
_WORK = [
    "fit_model", "Renderer", "turntable", "view", "compare", "compare_brdf", "figure5",
    "gallery_main", "lobes_demo", "demo", "bench_lobes", "bench_tables", "bench_brdf_fit",
]  # fmt: skip
_BENCH_WORK = ["bench_prefilter", "bench_transport", "bench_fit", "bench_render"]
_COMMANDS = [
    "bake", "info", "render", "view", "compare", "compare-brdf", "figure5", "gallery",
    "lobes-demo", "bench", "demo", "nope",
]  # fmt: skip
_FLAGS = [
    "--json", "-q", "--device", "-o", "--out", "--width", "--height", "--size", "--spp", "--sun",
    "--no-sun", "--backend", "--gaussians", "--bounces", "--indirect-paths",
    "--float16", "--seed", "--checkpoint-every", "--env", "--material", "--camera", "--rotate",
    "--exposure", "--samples", "--turntable", "--spin", "--parts", "--tonemap", "--base-res",
    "--model", "--baselines", "--frames", "--fused", "--repeats", "--scene", "--refs", "--data",
]  # fmt: skip
_WORDS = [
    "0", "1", "2", "3", "-1", "nan", "inf", "1e309", "abc", "", "8x8", "16", "0x0", "cpu",
    "cuda", "cuda:7", "bogus", "auto", "gl", "torch", "both", "builtin", "knot", "sphere:0",
    "prefilter", "fit", "render", "lobes", "list", "ggx:alpha=0.1", "diffuse:color=2",
    "0,0,4:0,0,0:40", "1,2:3", "glossy", "aces", "x.png", "x.jpg", "x.gif", "x.bmp",
    "/dev/null", "/etc/passwd",
]  # fmt: skip
_ARG_VALUES = st.one_of(st.sampled_from(_WORDS), st.text(max_size=12), st.floats().map(repr))
#: Paths the arguments may name (filled in with the fixture's folder).
_PATHS = ["{m}", "{s}", "{t}", "{d}", "{d}/missing.npz", "{o}/x.png", "x"]


@st.composite
def argv_strategy(draw):
    argv = [draw(st.sampled_from(_COMMANDS))]
    if draw(st.booleans()):
        argv.append(draw(st.sampled_from(_PATHS)))
    for _ in range(draw(st.integers(0, 5))):
        argv.append(draw(st.sampled_from(_FLAGS)))
        if draw(st.booleans()):
            argv.append(draw(st.one_of(st.sampled_from(_PATHS), _ARG_VALUES)))
    return argv


@pytest.fixture(scope="module")
def cli_files(tmp_path_factory, model_files):
    """A real model and scene, a text file, and a folder, for the arguments to name."""
    d = tmp_path_factory.mktemp("cli")
    (d / "m.npz").write_bytes(model_files[False][0])
    trimesh.creation.icosphere(0).export(d / "ball.obj")
    (d / "s.toml").write_text('mesh = "ball.obj"\n')
    (d / "notes.txt").write_text("not a model")
    (d / "out").mkdir()
    return d


@fuzz(300)
@given(argv=argv_strategy())
def test_fuzz_cli_arguments(cli_files, monkeypatch, capsys, argv):
    """Any command line: a bad argument ends with exit 2 and one line on stderr (and under
    --json stdout holds the JSON error alone) before any work starts; good ones reach the work
    (stood in for) or, for info, succeed."""
    d = cli_files
    argv = [
        a.replace("{m}", str(d / "m.npz")).replace("{s}", str(d / "s.toml"))
        .replace("{t}", str(d / "notes.txt")).replace("{o}", str(d / "out")).replace("{d}", str(d))
        for a in argv
    ]  # fmt: skip

    def work(*args, **kwargs):
        raise _WorkStarted

    with monkeypatch.context() as mp:
        for name in _WORK:
            mp.setattr(_commands, name, work)
        for name in _BENCH_WORK:
            mp.setattr(_commands.bench, name, work)
        capsys.readouterr()
        with _time_limit(LOAD_SECONDS):
            try:
                code = cli.main(argv)
            except _WorkStarted:
                _tally("accepted")
                return
    out, err = capsys.readouterr()
    if code == 0:
        _tally("accepted")
        return
    assert code == 2, (argv, code, err)
    lines = [x for x in err.splitlines() if x.startswith("lobelight: error")]
    assert len(lines) == 1 and err.strip() == lines[0].strip(), (argv, err)
    if "--json" in argv:
        assert set(json.loads(out)) == {"error"}, (argv, out)
    _tally("clean_errors")


# --------------------------------------------------------------------------------------------
# structured targets: what a careful user's unusual but well-formed inputs look like
#
# Meshes with far, tiny, flipped and stray parts; model files whose metadata claims large
# sizes; the command line's numeric flags at the limits of their types; outputs aimed at
# inputs. Each input is well formed, so the outcomes are stricter than a clean error: a mesh
# is refused or kept faithfully (its shape, its vertices, its outward winding), a model file
# is refused or read within a stated memory bound, a flag is refused before any work or within
# its stated range, and an output aimed at an input is refused with the input unchanged.

#: What any load may add to the process's peak resident memory (MB) besides what its model
#: needs: a model file is read within this plus a small multiple (:data:`MODEL_PEAK_FACTOR`)
#: of its arrays' bytes (the Gaussians expanded to every vertex and view included), and a
#: claim past the reader's limit is refused before anything of that size is allocated.
MODEL_PEAK_MB = 256
#: Copies of a model's arrays a load may hold at once (the file's, float32 and the tensors).
MODEL_PEAK_FACTOR = 3
#: What one command line may add to the peak before its work starts (MB): the libraries a
#: command loads on first use (a ray engine, the model reader's tensors) and no more; a flag
#: at its limit must be refused, not allocated.
CLI_PEAK_MB = 1024


def _peak_rss_kb() -> int | None:
    """This process's peak resident memory since the last reset (VmHWM, kB), or None where the
    platform does not tell."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1])
    except OSError:
        return None
    return None


@contextlib.contextmanager
def _peak_within(mb: float):
    """Fails when the peak resident memory grows by more than ``mb`` within the block (Linux:
    the peak is reset by writing 5 to /proc/self/clear_refs; elsewhere not measured)."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        base = _peak_rss_kb()
    except OSError:
        base = None
    yield
    if base is not None:
        peak = _peak_rss_kb()
        grew = (peak - base) / 1024
        _tally_peak(grew)
        assert grew <= mb, f"peak memory grew by {grew:.0f} MB, over the bound of {mb} MB"


def _tally_peak(mb: float) -> None:
    test = os.environ.get("PYTEST_CURRENT_TEST", "?").split("::")[-1].split(" ")[0]
    TALLY[test]["peak_mb"] = max(TALLY[test]["peak_mb"], math.ceil(mb))


# -- meshes: far, tiny, flipped and stray parts ----------------------------------------------

_AXES = [(1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 1), (-1, 0.5, 0.25)]


@st.composite
def mesh_scene(draw):
    """A closed icosphere moved ``10**offset`` along an axis and scaled by ``10**scale``, maybe
    inside out, with stray unreferenced vertices and an extra triangle, tiny or large, far away."""
    return {
        "sub": draw(st.integers(0, 2)),
        "offset": draw(st.one_of(st.none(), st.integers(-3, 12))),
        "axis": draw(st.sampled_from(_AXES)),
        "scale": draw(st.integers(-16, 16)),
        "flip": draw(st.booleans()),
        "stray": draw(st.lists(st.tuples(st.integers(0, 12), st.sampled_from(_AXES)), max_size=3)),
        "extra": draw(
            st.one_of(st.none(), st.tuples(st.integers(-12, 12), st.integers(0, 12)))
        ),  # (its size, its distance) as powers of ten
        "fmt": draw(st.sampled_from(["obj", "ply", "off"])),
    }


def _mesh_arrays(spec) -> tuple[np.ndarray, np.ndarray, int]:
    """(V, 3) float64 vertices, (F, 3) faces and the main part's vertex count."""
    ico = trimesh.creation.icosphere(spec["sub"])
    v = np.asarray(ico.vertices, np.float64) * 10.0 ** spec["scale"]
    if spec["offset"] is not None:
        axis = np.asarray(spec["axis"], np.float64)
        v = v + axis / np.linalg.norm(axis) * 10.0 ** spec["offset"]
    f = np.asarray(ico.faces, np.int64)
    if spec["flip"]:
        f = f[:, ::-1]
    main = len(v)
    parts_v, parts_f = [v], [f]
    if spec["extra"] is not None:
        size, dist = spec["extra"]
        tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float64) * 10.0**size
        parts_v.append(tri + 10.0**dist)
        parts_f.append(np.arange(3)[None] + main)
    for dist, axis in spec["stray"]:  # unreferenced
        parts_v.append(np.asarray(axis, np.float64)[None] * 10.0**dist)
    return np.concatenate(parts_v), np.concatenate(parts_f), main


def _mesh_file(v: np.ndarray, f: np.ndarray, fmt: str) -> bytes:
    """The mesh as OBJ, ASCII PLY or OFF text, coordinates written exactly (``repr``)."""
    vs = "\n".join(" ".join(repr(float(x)) for x in row) for row in v)
    if fmt == "obj":
        text = "\n".join("v " + r for r in vs.split("\n"))
        text += "\n" + "\n".join("f " + " ".join(str(i + 1) for i in t) for t in f)
    elif fmt == "off":
        text = f"OFF\n{len(v)} {len(f)} 0\n{vs}\n" + "\n".join(
            "3 " + " ".join(map(str, t)) for t in f
        )
    else:
        head = (
            f"ply\nformat ascii 1.0\nelement vertex {len(v)}\nproperty double x\n"
            f"property double y\nproperty double z\nelement face {len(f)}\n"
            "property list uchar int vertex_indices\nend_header\n"
        )
        text = head + vs + "\n" + "\n".join("3 " + " ".join(map(str, t)) for t in f)
    return (text + "\n").encode()


def _normalised(x: np.ndarray) -> np.ndarray:
    """Points moved to their mean and scaled to unit RMS radius (shape up to similarity)."""
    x = x - x.mean(0)
    return x / max(float(np.sqrt((x**2).sum(1).mean())), 1e-300)


def _signed_volume(v: np.ndarray, f: np.ndarray) -> float:
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6)


def _area(v: np.ndarray, f: np.ndarray) -> float:
    """The surface area of the faces ``f`` over the square of their vertices' bounding-box
    diagonal: the same for a mesh moved or scaled as a whole."""
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    used = v[np.unique(f)]
    diag = float(np.linalg.norm(used.max(0) - used.min(0)))
    area = float(np.linalg.norm(np.cross(b - a, c - a), axis=1).sum() / 2)
    return area / max(diag, 1e-300) ** 2


def _check_faithful(m, v: np.ndarray, f: np.ndarray, main: int, spec) -> None:
    """An accepted mesh kept what the file holds: every vertex referenced (stray ones dropped),
    its surface area but for the share a weld may collapse (``MAX_WELD_LOSS``, and 1e-3 for
    float32 storage); without an extra part, its shape (up to a move and a scale, 1e-3 of its
    radius: float32 storage of a recentred part is exact to 1e-7, a weld at 1e-6 of the
    diagonal moves nothing further) and its outward winding (a closed part's signed volume is
    positive once an inside-out file is fixed)."""
    _check_mesh(m)
    used = torch.zeros(m.n_vertices, dtype=torch.bool)
    used[m.faces.reshape(-1)] = True
    assert bool(used.all()), "unreferenced vertices kept"
    got = m.vertices.detach().cpu().double().numpy()
    kept = _area(got, m.faces.detach().cpu().numpy()) / max(_area(v, f), 1e-300)
    assert kept >= 1 - MAX_WELD_LOSS - 1e-3, f"the weld collapsed {1 - kept:.1%} of the area"
    if spec["extra"] is not None:
        return
    assert m.n_vertices == main, f"{m.n_vertices} vertices for a part of {main}"
    want, have = _normalised(v[:main]), _normalised(got)
    d = np.sqrt(((want[:, None] - have[None]) ** 2).sum(-1)).min(1)  # (main,) nearest
    assert float(d.max()) < 1e-3, f"the shape moved by {float(d.max()):.2g} of its radius"
    vol = _signed_volume(have, m.faces.detach().cpu().numpy())
    assert vol > 0, "inside out: the closed mesh's signed volume is negative"


@fuzz(60)
@given(spec=mesh_scene())
def test_fuzz_mesh_structured(tmp_path, spec):
    v, f, main = _mesh_arrays(spec)
    p = tmp_path / f"m.{spec['fmt']}"
    p.write_bytes(_mesh_file(v, f, spec["fmt"]))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # an inside-out mesh is fixed with a warning
        m = load_or_input_error(scene.load_mesh, p)
    if m is not None:
        _check_faithful(m, v, f, main, spec)


# -- model files whose metadata claims large sizes -------------------------------------------


@st.composite
def model_claim(draw):
    """Counts a model file claims: vertices, Gaussians per view (direct and indirect), the SH
    order, how many records hold weight, and whether the arrays follow the claim (sparse,
    compressed: a small file) or keep their real size (the claim contradicts them)."""
    follow = draw(st.booleans())
    small = [12, 1000, 20_000]
    large = [150_000, 500_000, 2_000_000, 2**31 - 1, 2**40, 10**30]
    v = draw(st.sampled_from(small if follow else small + large))
    # a model that follows its claim stays within a few hundred MB (the long run's address
    # space is a few GB); a claim the arrays contradict may be anything
    counts = [1, 2, 3, 8] + ([64] if v <= 1000 or not follow else [2**20, 2**62])
    return {
        "v": v,
        "n": draw(st.sampled_from(counts)),
        "ni": draw(st.sampled_from([0, 1, 8, 2**20])),
        "sh_order": draw(st.sampled_from([3, 5, 7, 30, 2**20])),
        "live": draw(st.integers(0, 4)),
        "follow": follow,
        "big_views": draw(st.sampled_from([None, 10**6, 2**40])),
    }


def _claiming_model(arrays: dict, claim) -> dict:
    """The model's arrays and metadata with ``claim``'s counts."""
    meta = json.loads(bytes(arrays["meta"]).decode())
    meta.update(n_vertices=claim["v"], n_gaussians=claim["n"], indirect_gaussians=claim["ni"],
                sh_order=claim["sh_order"])  # fmt: skip
    if claim["big_views"] is not None:
        meta["n_views"] = claim["big_views"]
    meta["materials"]["diffuse"] = [0.1, 0.1, 0.1]  # one colour for every vertex
    out = dict(arrays)
    if claim["follow"]:
        v, real = claim["v"], len(arrays["vertices"])
        n_all = min(claim["n"] + claim["ni"], 64)
        k = min(claim["live"], v)
        out["vertices"] = np.zeros((v, 3), np.float32)
        out["vertices"][: min(v, real)] = arrays["vertices"][: min(v, real)]
        out["normals"] = np.tile(np.float32([0, 0, 1]), (v, 1))
        out["faces"] = arrays["faces"][(arrays["faces"] < v).all(1)]
        keep = np.zeros((v, len(arrays["views"])), bool)
        keep.reshape(-1)[:k] = True
        out["keep"] = keep
        g = np.zeros((k, n_all, 7), np.float32)
        g[..., :3], g[..., 5], g[..., 6] = 0.5, 1.0, 10.0  # weights, +z lobes, sharpness 10
        out["gaussians"] = g
        sh = min(claim["sh_order"], 9) ** 2
        out["diffuse"] = np.zeros((v, sh, 3), np.float32)
    out["meta"] = np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)
    return out


def _model_need_mb(arrays: dict, claim) -> float:
    """The memory a model of ``claim``'s counts legitimately takes (MB): its arrays and its
    Gaussians expanded to every vertex, view and lobe (28 bytes each)."""
    views = claim["big_views"] or len(arrays["views"])
    dense = 28 * claim["v"] * views * (claim["n"] + claim["ni"])
    return (sum(a.nbytes for a in arrays.values()) + dense) / 2**20


@fuzz(40)
@given(claim=model_claim())
def test_fuzz_model_claims(tmp_path, model_files, claim):
    """A small file whose metadata claims large sizes: refused, or read within a bound set by
    what the claim legitimately needs; a claim past the reader's limit is always refused."""
    _, arrays = model_files[False]
    built = _claiming_model(arrays, claim)
    p = tmp_path / "m.npz"
    p.write_bytes(_npz_bytes(built, compressed=True))
    need = _model_need_mb(built, claim)
    over = need * 2**20 > _model_format.MAX_READ_BYTES
    with _peak_within(MODEL_PEAK_MB + (0 if over else MODEL_PEAK_FACTOR * need)):
        m = load_or_input_error(model.load, p)
    if m is not None:
        assert not over, f"a claim of {need:.0f} MB, past the reader's limit, was read"
        _check_model(m)


# -- the command line's numeric flags at the limits of their types ---------------------------

#: Values at the edges of the types a flag's number passes through: int32, int64, uint64,
#: float32 and float64 limits, their neighbours, signed zeros, NaN and the infinities, and
#: the stated maxima of the flags and one past them.
_EDGE_NUMBERS = [
    "0", "-0", "1", "-1", "2", "3", "255", "256", "257", "16383", "16384", "16385", "65535",
    "65536", str(2**31 - 1), str(2**31), str(-(2**31)), str(2**32), str(2**53 + 1),
    str(2**63 - 1), str(2**63), str(-(2**63)), str(2**64), str(10**400), "3.4028235e38",
    "3.5e38", "1e308", "1.7976931348623157e308", "-1e308", "1e-308", "5e-324", "1e-45", "inf",
    "-inf", "nan", "-nan", "0x10", "1_000", " 7", "7 ", "+8", "1e3", "2048", "4096", "4097",
    "64", "65", "-64", "-65", "1048576", "1048577", "3600", "3601", "10000", "10001",
]  # fmt: skip
#: Per command, its numeric flags (and a --size in each form).
_NUMERIC = {
    "render": ["--width", "--height", "--size", "--samples", "--base-res", "--exposure",
               "--rotate", "--turntable"],
    "bake": ["--bounces", "--indirect-paths", "--seed", "--checkpoint-every", "--memory-gb"],
    "compare": ["--width", "--height", "--size", "--spp", "--base-res", "--rotate"],
    "lobes-demo": ["--frames", "--size"],
    "compare-brdf": ["--size", "--spp"],
    "bench": ["--base-res", "--repeats", "--budget", "--memory-gb", "--samples"],
    "gallery": ["--spp", "--pass-spp", "--max-depth", "--seed", "--size", "--samples",
                "--base-res", "--sweep-max-spp"],
}  # fmt: skip
_POSITIONAL = {
    "render": ["{m}"], "bake": ["{obj}"], "compare": ["{obj}"], "lobes-demo": [],
    "compare-brdf": [], "bench": ["prefilter"], "gallery": ["references"],
}  # fmt: skip


@st.composite
def numeric_argv(draw):
    cmd = draw(st.sampled_from(sorted(_NUMERIC)))
    argv = [cmd, *_POSITIONAL[cmd]]
    for flag in draw(st.lists(st.sampled_from(_NUMERIC[cmd]), min_size=1, max_size=3)):
        value = draw(st.one_of(st.sampled_from(_EDGE_NUMBERS), st.integers().map(str),
                               st.floats().map(repr)))  # fmt: skip
        if flag == "--size" and draw(st.booleans()):
            value = f"{value}x{draw(st.sampled_from(_EDGE_NUMBERS))}"
        argv += [flag, value]
    if cmd == "render" and "--turntable" in argv:
        argv += ["-o", "{o}/spin"]
    return argv


def _within_stated_ranges(args) -> None:
    """The parsed values a command's work receives are within the ranges its help states."""
    from lobelight.cli import _limits

    w, h = getattr(args, "width", 1), getattr(args, "height", 1)
    if getattr(args, "size", None):
        w, h = _commands.parse_size(args.size)
    assert 1 <= w <= _limits.MAX_SIDE and 1 <= h <= _limits.MAX_SIDE, (w, h)
    assert w * h <= _limits.MAX_RENDER_PIXELS, (w, h)
    for name, lo, hi in [
        ("base_res", 1, _limits.MAX_BASE_RES), ("samples", 1, _limits.MAX_SAMPLES),
        ("spp", 1, _limits.MAX_SPP), ("bounces", 0, _limits.MAX_BOUNCES),
        ("indirect_paths", 0, _limits.MAX_INDIRECT_PATHS), ("seed", 0, _limits.MAX_SEED),
        ("refine", 0, _limits.MAX_REFINE_ROUNDS),
        ("frames", 1, _limits.MAX_FRAMES), ("turntable", 1, _limits.MAX_FRAMES),
        ("repeats", 1, _limits.MAX_REPEATS),
    ]:  # fmt: skip
        value = getattr(args, name, None)
        if name == "base_res" and value == "auto":
            continue
        assert value is None or lo <= value <= hi, (name, value)
    for name in ("rotate", "memory_gb", "budget"):
        value = getattr(args, name, None)
        assert value is None or math.isfinite(value), (name, value)
    exposure = getattr(args, "exposure", "auto")
    assert exposure == "auto" or abs(float(exposure)) <= _limits.MAX_EXPOSURE


@fuzz(150)
@given(argv=numeric_argv())
def test_fuzz_cli_numeric_limits(cli_files, monkeypatch, capsys, argv):
    """A numeric flag at the edge of its type: refused with one line (exit 2) before any
    work, or the work receives a value within the flag's stated range."""
    d = cli_files
    argv = [a.replace("{m}", str(d / "m.npz")).replace("{obj}", str(d / "ball.obj"))
            .replace("{o}", str(d / "out")) for a in argv]  # fmt: skip
    seen = {}

    def work(*args, **kwargs):
        raise _WorkStarted

    real_run = {}

    def catching(name):
        def run(args):
            seen["args"] = args
            return real_run[name](args)

        return run

    with monkeypatch.context() as mp:
        for name in _WORK:
            mp.setattr(_commands, name, work)
        for name in _BENCH_WORK:
            mp.setattr(_commands.bench, name, work)
        for name in [n for n in _commands.__all__ if n.startswith("run_")]:
            real_run[name] = getattr(_commands, name)
            mp.setattr(_commands, name, catching(name))
        capsys.readouterr()
        with _time_limit(LOAD_SECONDS), _peak_within(CLI_PEAK_MB):
            try:
                code = cli.main(argv)
            except _WorkStarted:
                _within_stated_ranges(seen["args"])
                _tally("accepted")
                return
    _, err = capsys.readouterr()
    assert code in (0, 2), (argv, code, err)
    if code == 0:
        _tally("accepted")
        return
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("lobelight: error"), (argv, err)
    _tally("clean_errors")


# -- outputs aimed at inputs -----------------------------------------------------------------

#: How an output may name an input: the same path, another spelling of it, a symbolic link, a
#: link to a link, a hard link.
_ALIASES = ["same", "dot", "parent", "absolute", "symlink", "symlink2", "hardlink", "fresh"]


@st.composite
def output_at_input(draw):
    cmd = draw(st.sampled_from(["bake-mesh", "bake-scene", "render", "render-turntable"]))
    inputs = {
        "bake-mesh": ["ball.obj"],
        "bake-scene": ["s.toml", "ball.obj", "env.hdr"],
        "render": ["m.npz", "env.hdr"],
        "render-turntable": ["m.npz", "env.hdr"],
    }[cmd]
    return cmd, draw(st.sampled_from(inputs)), draw(st.sampled_from(_ALIASES))


def _alias(d: Path, target: str, how: str, k: int) -> str:
    """A name in ``d`` for the file ``target`` (made fresh per example ``k``)."""
    t = d / target
    if how == "same":
        return target
    if how == "dot":
        return f"./{target}"
    if how == "parent":
        return f"sub/../{target}"
    if how == "absolute":
        return str(t)
    if how == "fresh":
        return f"new{k}.png"
    link = d / f"link{k}{t.suffix if t.suffix in ('.hdr', '.png') else '.png'}"
    if how == "hardlink":
        os.link(t, link)
    elif how == "symlink":
        link.symlink_to(t)
    else:
        (d / f"hop{k}").symlink_to(t)
        link.symlink_to(d / f"hop{k}")
    return link.name


@fuzz(80)
@given(case=output_at_input())
def test_fuzz_outputs_aimed_at_inputs(tmp_path, model_files, monkeypatch, capsys, case):
    """Every output that resolves to an input is refused (exit 2, one line) before any work,
    with every input unchanged; an output elsewhere reaches the work."""
    cmd, target, how = case
    d = Path(tempfile.mkdtemp(dir=tmp_path))  # a folder per example
    k = 0
    (d / "sub").mkdir()
    (d / "m.npz").write_bytes(model_files[False][0])
    (d / "ball.obj").write_bytes(MESHES["obj"])
    (d / "env.hdr").write_bytes(_hdr_bytes(_img(4, 8)))
    (d / "s.toml").write_text('mesh = "ball.obj"\nenvironment = "env.hdr"\n')
    monkeypatch.chdir(d)
    out = _alias(d, target, how, k)
    if how == "fresh" and cmd.startswith("bake"):
        out = f"new{k}.npz"  # a model file's name
    argv = {
        "bake-mesh": ["bake", "ball.obj", "-o", out],
        "bake-scene": ["bake", "s.toml", "-o", out],
        "render": ["render", "m.npz", "--env", "env.hdr", "-o", out],
        "render-turntable": ["render", "m.npz", "--env", "env.hdr", "--turntable", "2", "-o", "."],
    }[cmd]
    if cmd == "render-turntable" and how != "fresh":  # a frame's name aimed at the input
        (d / "frame_001.png").unlink(missing_ok=True)
        os.link(d / target, d / "frame_001.png") if how == "hardlink" else (
            d / "frame_001.png").symlink_to(d / target)  # fmt: skip
    before = {p.name: p.read_bytes() for p in d.iterdir() if p.is_file() and not p.is_symlink()}

    def work(*args, **kwargs):
        raise _WorkStarted

    with monkeypatch.context() as mp:
        for name in _WORK:
            mp.setattr(_commands, name, work)
        capsys.readouterr()
        with _time_limit(LOAD_SECONDS):
            try:
                code = cli.main([*argv, "-q"])
            except _WorkStarted:
                code = None
    _, err = capsys.readouterr()
    after = {n: (d / n).read_bytes() for n in before}
    assert after == before, f"{argv}: an input changed"
    if how == "fresh":
        assert code is None, (argv, err)
        _tally("accepted")
        return
    assert code == 2, (argv, code, err)
    lines = err.strip().splitlines()
    # refused as the input, or for what its name says (a model's name is no image name)
    assert len(lines) == 1 and lines[0].startswith("lobelight: error"), (argv, err)
    if Path(out).suffix in (".png", ".hdr") or cmd.startswith("bake"):
        assert "is the input" in lines[0], (argv, err)
    _tally("clean_errors")
