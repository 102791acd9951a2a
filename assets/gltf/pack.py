"""Pack a glTF 2.0 asset (``.gltf`` with its ``.bin`` buffers and image files) into one ``.glb``.

Usage: ``python assets/gltf/pack.py SOURCE.gltf OUT.glb`` (a ``.glb`` source is copied as it
is). Nothing is decoded, resampled or re-encoded: the buffers' bytes and the image files' bytes
are laid end to end in the GLB's binary chunk (each started at a multiple of 4 bytes), every
image gets a buffer view and its MIME type in place of its file name, and the JSON is written
with sorted keys, so that the same sources give the same bytes. The standard library only.
"""

from __future__ import annotations

import json
import shutil
import struct
import sys
from pathlib import Path

_MIME = {".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg"}


def _pad(data: bytes, fill: bytes) -> bytes:
    return data + fill * (-len(data) % 4)


def pack(source: Path, out: Path) -> None:
    """Write ``source`` (``.gltf`` or ``.glb``) as the single file ``out`` (``.glb``)."""
    if source.suffix.lower() == ".glb":
        shutil.copyfile(source, out)
        return
    doc = json.loads(source.read_text(encoding="utf-8"))
    blob = b""
    starts = []  # where each old buffer begins in the new one
    for buf in doc.get("buffers", []):
        blob = _pad(blob, b"\0")
        starts.append(len(blob))
        blob += (source.parent / buf["uri"]).read_bytes()[: buf["byteLength"]]
    for view in doc.get("bufferViews", []):
        view["byteOffset"] = starts[view["buffer"]] + view.get("byteOffset", 0)
        view["buffer"] = 0
    views = doc.setdefault("bufferViews", [])
    for img in doc.get("images", []):
        if "uri" not in img:
            continue
        data = (source.parent / img["uri"]).read_bytes()
        blob = _pad(blob, b"\0")
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(data)})
        blob += data
        img.setdefault("name", img["uri"])
        img["mimeType"] = _MIME[Path(img["uri"]).suffix.lower()]
        img["bufferView"] = len(views) - 1
        del img["uri"]
    blob = _pad(blob, b"\0")
    doc["buffers"] = [{"byteLength": len(blob)}]
    text = _pad(json.dumps(doc, sort_keys=True, separators=(",", ":")).encode(), b" ")
    total = 12 + 8 + len(text) + 8 + len(blob)
    with open(out, "wb") as f:
        f.write(struct.pack("<4sII", b"glTF", 2, total))
        f.write(struct.pack("<II", len(text), 0x4E4F534A) + text)
        f.write(struct.pack("<II", len(blob), 0x004E4942) + blob)


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    pack(Path(sys.argv[1]), Path(sys.argv[2]))
