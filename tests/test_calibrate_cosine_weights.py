"""The cosine lobes' weight calibrator (tools/calibrate_cosine_weights.py) and its data file.

The tool is a script beside the library, imported here by path. The library reads what it
writes, ``lobelight/cosine/weights.json``, through :mod:`lobelight.cosine._calibration`.
"""

from __future__ import annotations

import importlib.util
import json
import struct
from pathlib import Path

import numpy as np
import pytest
import torch

from lobelight.cosine import DIST_NODES, MASK_MODES
from lobelight.cosine._calibration import WEIGHTS_FILE, calibrated_weights, default_weights

TOOL = Path(__file__).resolve().parents[1] / "tools" / "calibrate_cosine_weights.py"


@pytest.fixture(scope="module")
def tool():
    spec = importlib.util.spec_from_file_location("calibrate_cosine_weights", TOOL)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _bits(rows) -> list[bytes]:
    return [struct.pack("<d", float(v)) for row in rows for v in row]


def test_help_runs(tool, capsys):
    with pytest.raises(SystemExit) as stop:
        tool.main(["--help"])
    assert stop.value.code == 0
    assert "--output" in capsys.readouterr().out


def test_the_tool_writes_the_file_the_library_reads(tool):
    assert tool.WEIGHTS_PATH.name == WEIGHTS_FILE
    assert tool.WEIGHTS_PATH.parent.parts[-2:] == ("lobelight", "cosine")


def test_stored_file_is_the_tools_own_text(tool):
    """The packaged table is exactly what :func:`weights_text` writes for its numbers."""
    from importlib import resources

    text = resources.files("lobelight.cosine").joinpath(WEIGHTS_FILE).read_text("utf-8")
    doc = json.loads(text)
    assert tuple(doc["dist_nodes"]) == DIST_NODES
    assert tool.weights_text({"weights": doc["weights"], "report": doc["report"]}) == text
    assert set(doc["weights"]) == {f"{m}:{d}" for m in MASK_MODES for d in (3, 4, 5)}


def test_write_weights_round_trips_every_bit(tool, tmp_path):
    rng = np.random.default_rng(0)
    weights = {
        "aggressive:1": (rng.random((2, 12)) * 3).tolist(),
        "conservative:2": np.round(rng.random((3, 12)), 5).tolist(),
    }
    report = {k: {"rms_before": float(rng.random()), "points": 7} for k in weights}
    path = tool.write_weights({"weights": weights, "report": report}, tmp_path / "w.json")
    assert [p.name for p in tmp_path.iterdir()] == ["w.json"]  # nothing half-written is left
    doc = json.loads(path.read_text())
    assert doc["report"] == report
    for key, rows in weights.items():
        assert _bits(doc["weights"][key]) == _bits(rows)


def test_calibrated_weights_are_read_once_and_read_only():
    table = calibrated_weights()
    assert calibrated_weights() is table
    with pytest.raises(TypeError):
        table["aggressive:5"] = ()  # type: ignore[index]
    for key, rows in table.items():
        mode, depth = key.split(":")
        w = default_weights(mode, int(depth))
        assert w.dtype == torch.float32 and w.shape == (int(depth) + 1, len(DIST_NODES))
        assert torch.equal(w, torch.tensor(rows, dtype=torch.float32))


@pytest.mark.slow
def test_small_calibration_fits_non_negative_weights_and_reduces_the_error(tool, tmp_path):
    result = tool.calibrate_weights(
        depths=(3,), modes=("aggressive",), points_per_light=16, mc_samples=4
    )
    w = np.array(result["weights"]["aggressive:3"])
    assert w.shape == (4, len(DIST_NODES)) and (w >= 0).all()
    rep = result["report"]["aggressive:3"]
    assert rep["rms_after"] < rep["rms_before"]
    path = tool.write_weights(result, tmp_path / "weights.json")
    assert json.loads(path.read_text())["weights"] == result["weights"]
