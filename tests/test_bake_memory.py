"""A bake's memory does not grow with the mesh beyond its per-vertex state.

Each measurement runs in a child process of its own (a fresh heap), which resets its peak
resident memory (``VmHWM``, through ``/proc/self/clear_refs``) once the inputs are built and
reads it after the stage: the peak *above* that baseline is what the stage itself held. The
same stage on a mesh four times as large may hold more only by its per-vertex state (the
interreflection's gather matrix, the Gaussians' zonal coefficients, the transfer vectors: at
most ``_STATE_PER_VERTEX`` bytes a vertex, ``lobelight.fit._memory.interreflection_bytes``).
The regression it pins: the zonal coefficients of every (vertex, view, Gaussian) computed at
once, through float64 tables of 45 quadrature nodes x 5 bands x 2 per Gaussian, 2 x 92 of
them per vertex: hundreds of KB a vertex, hundreds of MB more on the larger mesh.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from lobelight import fit
from lobelight.errors import InputError
from lobelight.fit import _memory

pytestmark = pytest.mark.skipif(
    not Path("/proc/self/clear_refs").exists(), reason="needs Linux's /proc peak reset"
)

# What a stage may keep per vertex: the interreflection's Gaussians and zonal coefficients
# (J = 92 views x 2 Gaussians x 12 floats, 8.8 KB), its gather matrix (at most 3 corners x 192
# rays x 20 bytes, 11.5 KB: on a sphere no ray hits, so 0) and six copies of the SH transfer
# (1.8 KB), with a margin of 1.5x for allocator rounding and the random inputs' copies.
_STATE_PER_VERTEX = 33_000
# Slack of the comparison for allocator and page-rounding noise between two processes (the
# heap's arenas come in 64 MB pieces).
_NOISE = 96 * 2**20

# the child processes' peak resident memory, from the kernel's high-water mark
_HWM = r"""
def hwm():
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
"""

_CHILD_INTERREFLECTION = (
    r"""
import json, sys, torch
from lobelight import scene, transport
from lobelight.geometry import sphere
"""
    + _HWM
    + r"""
sc = scene.load(sys.argv[1], material="ggx:alpha=0.04,specular=0.9")
tr = transport.Transport(sc)
v, views = sc.mesh.n_vertices, sphere.geodesic_views()
g = torch.Generator().manual_seed(0)
shadowed = torch.rand(v, 25, 3, generator=g)
w = torch.rand(v, views.shape[0], 2, 3, generator=g)
mu = torch.nn.functional.normalize(torch.randn(v, views.shape[0], 2, 3, generator=g), dim=-1)
lam = 10 ** (3 * torch.rand(v, views.shape[0], 2, generator=g))
open("/proc/self/clear_refs", "w").write("5")
base = hwm()
transport.diffuse_interreflection(
    tr, shadowed, bounces=1, glossy=(views, w, mu, lam), memory=int(sys.argv[2])
)
print(json.dumps({"vertices": v, "above": hwm() - base}))
"""
)


def _child(code: str, *args: str) -> dict:
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    out = subprocess.run(
        [sys.executable, "-c", code, *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
        check=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_interreflection_peak_does_not_grow_with_the_vertex_count():
    # the module docstring's regression grows by hundreds of MB from 642 to 2,562 vertices
    budget = 64 * 2**20
    small = _child(_CHILD_INTERREFLECTION, "sphere:3", str(budget))
    large = _child(_CHILD_INTERREFLECTION, "sphere:4", str(budget))
    assert large["vertices"] >= 4 * small["vertices"] - 100
    grown = large["above"] - small["above"]
    allowed = (large["vertices"] - small["vertices"]) * _STATE_PER_VERTEX + _NOISE
    assert grown <= allowed, (small, large, allowed)
    # and the batches themselves stay near their budget (twice it, for what the caller's
    # inputs are copied to: the Gaussians as float32, the transfer's sums)
    assert small["above"] <= 2 * budget + small["vertices"] * _STATE_PER_VERTEX + _NOISE, small


_CHILD_BAKE = (
    r"""
import json, sys, torch
from lobelight import fit, scene
"""
    + _HWM
    + r"""
sc = scene.load(sys.argv[1], material="ggx:alpha=0.04,specular=0.9")
open("/proc/self/clear_refs", "w").write("5")
base = hwm()
m = fit.fit_model(sc, 1, indirect_paths=2, bounces=1, progress=None)
print(json.dumps({"vertices": sc.mesh.n_vertices, "above": hwm() - base,
                  "memory": m.provenance["memory"]}))
"""
)


@pytest.mark.slow
def test_bake_peak_does_not_grow_with_the_vertex_count():
    small = _child(_CHILD_BAKE, "sphere:2")
    large = _child(_CHILD_BAKE, "sphere:3")
    assert small["memory"]["batch"] == large["memory"]["batch"] == 64
    # per vertex the bake keeps its state (lobelight.fit._memory.state_bytes: 8-10 KB) and the
    # interreflection's (bounded as above); everything else is batched
    grown = large["above"] - small["above"]
    allowed = (large["vertices"] - small["vertices"]) * _STATE_PER_VERTEX + _NOISE
    assert grown <= allowed, (small, large, allowed)
    assert set(large["memory"]["peak_gb"]) == {"setup", "fit", "relax", "interreflection"}


def test_the_default_budget_holds_a_50k_vertex_bake():
    # a 50K-vertex bake with two Gaussians per view: state and batches within 4 GB, with the
    # CPU's full chunk of 64 vertices
    plan = _memory.plan_memory(fit.MEMORY_GB, 50_000, 92, 2, device="cpu")
    assert plan.batch == 64
    assert plan.budget == 4 * 2**30
    state = 2**30 + _memory.state_bytes(50_000, 92, 2)
    assert state + 64 * _memory.chunk_bytes(92, 2) <= plan.budget  # the flood fill
    assert plan.interreflection == 512 * 2**20  # the interreflection's batches, at their most
    assert state + _memory.interreflection_bytes(50_000, 92, 2) + 512 * 2**20 <= plan.budget


def test_a_smaller_budget_gives_smaller_batches_and_an_impossible_one_an_error():
    full = _memory.plan_memory(4.0, 10_000, 92, 1, device="cpu")
    small = _memory.plan_memory(1.5, 10_000, 92, 1, device="cpu")
    assert full.batch == 64
    # what is left of 1.5 GB after the 1 GB allowance and the state, in chunks of ~14 MB
    left = 1.5 * 2**30 - 2**30 - _memory.state_bytes(10_000, 92, 1)
    assert small.batch == int(left // _memory.chunk_bytes(92, 1)) < 64
    assert small.interreflection == left - _memory.interreflection_bytes(10_000, 92, 1)
    with pytest.raises(InputError, match="memory_gb"):
        _memory.plan_memory(1.0, 10_000, 92, 1, device="cpu")
    with pytest.raises(InputError, match="memory_gb"):
        _memory.plan_memory(float("nan"), 10, 92, 1, device="cpu")


_CHILD_METER = r"""
import json, torch
from lobelight.fit import _memory
meter = _memory.PeakMeter(period=0.005)
meter.stage("small")
meter.stage("large")
x = torch.ones(64 * 2**20 // 4)  # 64 MB, touched
x += 1
print(json.dumps(meter.stop()))
"""


def test_the_peak_meter_sees_a_stage_allocation():
    # in a fresh process: a process that has freed memory may serve the 64 MB from pages it
    # still holds (the command line keeps its freed heap, lobelight.cli.tune)
    peaks = _child(_CHILD_METER)
    # 64 MB touched, less slack for pages the stage's start already counted
    assert peaks["large"] - peaks["small"] >= 48 * 2**20, peaks
