"""A bake killed with SIGKILL (no handler runs, nothing is flushed) resumes to the same model.

The command line bakes in a child process that saves its state after every chunk
(``--checkpoint-every 0``); the test watches the checkpoint and kills the child with SIGKILL
once it records the kill point: part-way through the flood fill, and part-way through the
relaxation of two Gaussians per view. Run again, the bake resumes from the checkpoint; the
model it writes must be bit for bit the model of an uninterrupted bake, and no temporary file
may be left beside it.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

#: The scene: 162 vertices, three chunks of 64 per stage, glossy everywhere.
SCENE = "sphere:2"
RUN = "import sys; from lobelight.cli import main; sys.exit(main(sys.argv[1:]))"


def _bake(out: Path, gaussians: int) -> subprocess.Popen:
    cmd = [sys.executable, "-c", RUN, "bake", SCENE, "-o", str(out), "-q"]
    cmd += ["--gaussians", str(gaussians), "--checkpoint-every", "0"]
    return subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


def _stage(ckpt: Path) -> tuple[str, int] | None:
    """The checkpoint's (stage, next chunk), or None while there is none (it is written
    atomically: a reader sees a whole file or none)."""
    try:
        with np.load(ckpt, allow_pickle=False) as z:
            meta = json.loads(bytes(z["meta"]).decode())
    except FileNotFoundError:
        return None
    return meta["stage"], meta["next"]


def _arrays(path: Path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files if k != "meta"}
        meta = json.loads(bytes(z["meta"]).decode())
    # the provenance holds timings and measured peak memory; everything else must match
    meta["provenance"] = {
        k: v for k, v in meta["provenance"].items() if "second" not in k and k != "timings"
    }
    meta["provenance"].get("memory", {}).pop("peak_gb", None)
    return {**arrays, "meta": np.frombuffer(json.dumps(meta, sort_keys=True).encode(), np.uint8)}


@pytest.mark.parametrize(("gaussians", "stage"), [(1, "fit"), (2, "relax")])
def test_a_bake_killed_mid_stage_resumes_to_the_same_model(tmp_path, gaussians, stage):
    clean = tmp_path / "clean.npz"
    p = _bake(clean, gaussians)
    assert p.wait(timeout=600) == 0, p.stderr.read().decode()

    out = tmp_path / "killed.npz"
    ckpt = out.with_name(out.name + ".ckpt")
    p = _bake(out, gaussians)
    deadline = time.monotonic() + 600
    seen = None
    while p.poll() is None and time.monotonic() < deadline:
        seen = _stage(ckpt)
        if seen is not None and seen[0] == stage and seen[1] >= 1:
            os.kill(p.pid, signal.SIGKILL)
            break
        time.sleep(0.005)
    assert p.wait(timeout=60) == -signal.SIGKILL, f"not killed at {stage}: last saw {seen}"
    assert not out.exists() and ckpt.exists()

    p = _bake(out, gaussians)  # the same command again resumes
    assert p.wait(timeout=600) == 0, p.stderr.read().decode()
    assert not ckpt.exists()  # it has served
    a, b = _arrays(clean), _arrays(out)
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    leftovers = sorted(x.name for x in tmp_path.iterdir() if x.name not in ("clean.npz", out.name))
    assert leftovers == []
