"""Shared test fixtures: seeded randomness, devices, and the project's shared data folder.

Tolerances used across tests live in :data:`TOL` so that their justification is in one place;
tests that need a tighter or looser bound say why next to the assertion.
"""

from __future__ import annotations

import os
import random
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import assume
from hypothesis import strategies as st

ROOT = Path(__file__).resolve().parents[1]


def shared_dir() -> Path | None:
    """The project's read-only ``shared/`` folder (papers, data), or None when absent.

    Looked up from ``LOBELIGHT_SHARED`` and then next to the repository (``../shared``), so the
    package also tests standalone: tests that need it skip with a reason.
    """
    env = os.environ.get("LOBELIGHT_SHARED")
    for cand in ([Path(env)] if env else []) + [ROOT / "shared", ROOT.parent / "shared"]:
        if (cand / "data").is_dir():
            return cand
    return None


SHARED = shared_dir()
ENVMAP_DIR = SHARED / "data" / "envmaps" if SHARED else None
REAL_ENVMAPS = sorted(ENVMAP_DIR.rglob("*.hdr")) if ENVMAP_DIR else []

needs_shared = pytest.mark.skipif(SHARED is None, reason="../shared (real data) is not present")


# Two threads at most: CI machines have 2 cores, and oversubscription makes torch 10-50x slower
# when other processes share the machine.
torch.set_num_threads(min(2, torch.get_num_threads()))


@pytest.fixture(autouse=True)
def _seed() -> None:
    random.seed(0)
    np.random.seed(0)  # noqa: NPY002 - seeds libraries that use the legacy global generator
    torch.manual_seed(0)


DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


def tiny_table_params():
    """Cosine-lobe table parameters small enough to build in about a second (loader tests)."""
    from lobelight import cosine

    return cosine.TableParams(
        per_decade=1, e_max=10.0, angle_uniform=4, angle_grading=0.0, angle_pi_grading=0.0,
        cap_nodes=4, quad_nodes=4,
    )  # fmt: skip


@pytest.fixture(scope="session")
def tiny_table_path(tmp_path_factory) -> Path:
    """A saved table file of :func:`tiny_table_params`, built once for the whole session."""
    from lobelight import cosine

    p = tmp_path_factory.mktemp("tables") / "t.npz"
    cosine.save_tables(cosine.build_tables(tiny_table_params()), p)
    return p


@pytest.fixture(scope="module")
def one_torch_thread():
    """One torch thread for a test module: EM and the SG-BRDF harness run many small tensor
    operations, where a second thread buys little and, on a shared 2-core machine, a contended
    one slows torch down many times over. Use with ``pytestmark``."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(params=["cpu", "cuda"])
def device(request) -> str:
    """Run a test on the CPU and, where there is one, on a CUDA GPU."""
    if request.param == "cuda" and not torch.cuda.is_available():
        pytest.skip("no CUDA GPU on this machine")
    return request.param


# Directions for tests. ``triple`` is a hypothesis strategy for a normal-ish 3-vector; ``unit``
# normalises one (rejecting ~0); ``random_dirs`` draws seeded uniform directions.
F64 = torch.float64
coord = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False)
triple = st.tuples(coord, coord, coord)


def unit(t) -> torch.Tensor:
    v = torch.tensor(t, dtype=F64)
    n = torch.linalg.vector_norm(v)
    assume(n > 1e-3)
    return v / n


def random_dirs(n: int, dtype=F64, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    v = torch.randn(n, 3, generator=g, dtype=F64)
    return torch.nn.functional.normalize(v, dim=-1).to(dtype)


def smooth_env():
    """A smooth, strictly positive lat-long environment (64 x 128): low-frequency colour
    gradients, so that lookups and sampled estimates converge fast."""
    import math

    from lobelight.envmap import EnvMap

    h = 64
    th = (torch.arange(h) + 0.5) / h * math.pi
    ph = (torch.arange(2 * h) + 0.5) / (2 * h) * 2 * math.pi
    t, p = torch.meshgrid(th, ph, indexing="ij")
    img = torch.stack(
        [
            1 + 0.8 * torch.cos(t) + 0.3 * torch.sin(3 * p) * torch.sin(t),
            1 + 0.5 * torch.sin(t) * torch.cos(p),
            1.5 + torch.cos(2 * t),
        ],
        -1,
    ).clamp_min(0.05)
    return EnvMap(img, layout="latlong", name="smooth")
