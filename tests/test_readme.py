"""The README's Python snippet runs as written and makes a picture worth keeping: the object
whole in the frame and exposed for its own pixels (not blown out by a dark background)."""

from __future__ import annotations

import re

import numpy as np
from PIL import Image

from conftest import ROOT


def _snippet() -> str:
    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert len(blocks) == 1, "the README has one Python snippet"
    return blocks[0]


def test_the_readme_snippet_frames_and_exposes_its_object(tmp_path, monkeypatch):
    code = _snippet()
    assert 'scene.load("knot")' in code
    # the knot's bake takes about a minute here; a small sphere goes through the same calls
    code = code.replace('scene.load("knot")', 'scene.load("sphere:1")')
    monkeypatch.chdir(tmp_path)
    ns: dict = {}
    exec(compile(code, "README.md", "exec"), ns)  # the project's own README
    img = np.asarray(Image.open(tmp_path / "out.png")).astype(np.float64) / 255
    mask = ns["mask"].cpu().numpy() > 0.5  # fully covered object pixels
    h, w = mask.shape
    assert img.shape[:2] == (h, w)
    # framed: the object is whole (no object pixel on the border) and not a speck
    assert not (mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any())
    assert mask.mean() > 0.05
    # exposed for the object: a mid-grey average, and only highlights clipped (here the sun's
    # reflection on the glossy sphere, about 5 % of its pixels; exposed for the whole frame
    # with a dark background, most of an object is white)
    obj = img[mask]
    clipped = (obj >= 254 / 255).any(-1).mean()
    assert clipped < 0.1, clipped
    assert 0.15 < obj.mean() < 0.8, obj.mean()
