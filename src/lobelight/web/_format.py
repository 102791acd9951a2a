"""The web folder's data files: arrays as base64 inside JavaScript, and their reader.

A page opened from ``file://`` may not ``fetch`` (browsers refuse file URLs to scripts), but it
may load classic scripts: every data file is therefore a script, ``lobelight_data(KIND,
JSON);``, whose JSON holds a header and the arrays, each as ``{"dtype", "shape", "b64"}``
(little-endian, C order, base64), and ``"gzip": true`` where the bytes are gzip-compressed
before base64 (arrays of at least :data:`GZIP_MIN_BYTES` that compress to at most
:data:`GZIP_MAX_RATIO` of their size: a browser parses fewer bytes of script and inflates them
natively, ``DecompressionStream``). ``docs/web-viewer.md`` lists the files and arrays.
"""

from __future__ import annotations

import base64
import gzip
import json
import zlib
from pathlib import Path

import numpy as np

from ..errors import InputError

__all__ = [
    "DTYPES",
    "GZIP_MAX_RATIO",
    "GZIP_MIN_BYTES",
    "decode_array",
    "encode_array",
    "read_data_file",
    "write_data_file",
]

#: The array types the page reads (numpy dtype strings, little-endian).
DTYPES = ("<f4", "<f2", "<u4", "<i4", "|u1", "<i2")
#: Arrays smaller than this stay uncompressed (a stream's set-up costs more than it saves).
GZIP_MIN_BYTES = 1 << 16
#: An array is kept compressed where that leaves at most this share of its bytes.
GZIP_MAX_RATIO = 0.9
#: gzip's level: the fastest (the page's load, not the folder's last bytes, is the goal).
_GZIP_LEVEL = 1
#: The call a data file makes, before its JSON.
_PREFIX = "lobelight_data("


def encode_array(a: np.ndarray) -> dict:
    """``{"dtype", "shape", "b64"[, "gzip"]}`` of an array of one of :data:`DTYPES` (module
    docstring)."""
    a = np.ascontiguousarray(a)
    dt = a.dtype.newbyteorder("<").str
    if dt not in DTYPES:
        raise InputError("array", f"dtype {a.dtype} is not one the page reads ({DTYPES})")
    raw = a.astype(dt, copy=False).tobytes()
    rec = {"dtype": dt, "shape": list(a.shape)}
    if len(raw) >= GZIP_MIN_BYTES:
        packed = gzip.compress(raw, compresslevel=_GZIP_LEVEL, mtime=0)
        if len(packed) <= GZIP_MAX_RATIO * len(raw):
            return {**rec, "gzip": True, "b64": base64.b64encode(packed).decode("ascii")}
    return {**rec, "b64": base64.b64encode(raw).decode("ascii")}


def _inflate(packed: bytes, size: int, where: str) -> bytes:
    """The ``size`` bytes a gzip member holds, never more kept in memory (a record that
    inflates past its shape's size is refused before it is)."""
    d = zlib.decompressobj(wbits=31)
    try:
        raw = d.decompress(packed, max(size, 1))  # 0 would mean no limit
        if d.unconsumed_tail or not d.eof:
            raise InputError(where, f"inflates to more or less than its shape's {size} bytes")
    except zlib.error as e:
        raise InputError(where, f"holds damaged gzip data ({e})") from None
    if d.unused_data:
        raise InputError(where, "has bytes after its gzip data")
    return raw


def decode_array(rec: dict, where: str) -> np.ndarray:
    """The array of an :func:`encode_array` record, its size checked against its shape."""
    try:
        dt, shape, b64 = rec["dtype"], [int(s) for s in rec["shape"]], rec["b64"]
        packed = rec.get("gzip", False)
    except (KeyError, TypeError, ValueError, AttributeError):
        raise InputError(where, "is not an array record (dtype, shape, b64)") from None
    if dt not in DTYPES or any(s < 0 for s in shape) or not isinstance(packed, bool):
        raise InputError(where, f"has dtype {dt!r} and shape {shape}: not readable")
    try:
        raw = base64.b64decode(b64, validate=True)
    except (ValueError, TypeError):
        raise InputError(where, "holds no valid base64") from None
    n = int(np.prod(shape, dtype=np.int64))
    size = n * np.dtype(dt).itemsize
    if packed:
        raw = _inflate(raw, size, where)
    if len(raw) != size:
        raise InputError(where, f"holds {len(raw)} bytes, its shape {shape} needs {size}")
    return np.frombuffer(raw, dt).reshape(shape)


def write_data_file(path: Path, kind: str, header: dict, arrays: dict[str, np.ndarray]) -> int:
    """Write one data file (``lobelight_data(kind, {header, arrays});``); returns its size."""
    doc = {"header": header, "arrays": {k: encode_array(v) for k, v in arrays.items()}}
    text = f"{_PREFIX}{json.dumps(kind)}, {json.dumps(doc, separators=(',', ':'))});\n"
    path.write_text(text, encoding="ascii")
    return path.stat().st_size


def read_data_file(path: Path, kind: str) -> tuple[dict, dict[str, np.ndarray]]:
    """A data file's header and arrays; the file must be of ``kind``."""
    try:
        text = path.read_text(encoding="ascii")
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(str(path), f"cannot be read as a web data file ({e})") from None
    head = f"{_PREFIX}{json.dumps(kind)}, "
    if not text.startswith(head) or not text.rstrip().endswith(");"):
        raise InputError(str(path), f"is not a web data file of kind {kind!r}")
    try:
        doc = json.loads(text[len(head) : text.rstrip().rfind(")")])
        header, recs = doc["header"], doc["arrays"]
    except (ValueError, KeyError, TypeError):
        raise InputError(str(path), "holds no readable header and arrays") from None
    arrays = {k: decode_array(v, f"{path}: {k}") for k, v in recs.items()}
    return header, arrays
