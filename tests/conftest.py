"""Shared test fixtures: seeded randomness, devices, the bundled data, and a private cache.

Tolerances used across tests live in :data:`TOL` so that their justification is in one place;
tests that need a tighter or looser bound say why next to the assertion.

The suite writes only under temporary folders: before anything imports lobelight (or numba, or
Mitsuba's Dr.Jit), every on-disk cache is pointed into one folder made for this session, which
is removed when the session ends. Every file the tests read is in the repository (the package's
bundled maps, ``examples/``) or made by the test itself.
"""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile
from pathlib import Path

# A private cache for the whole session, set at import: numba reads NUMBA_CACHE_DIR when it is
# first imported, and lobelight reads LOBELIGHT_CACHE whenever it looks for its cache (the
# cosine-lobe tables, the prefiltered chains); hypothesis looks for its folder on first use.
# Never the user's ~/.cache, ~/.drjit, the package's __pycache__ (numba's default) or the
# working folder (hypothesis's), whatever the environment says.
SESSION_TMP = Path(tempfile.mkdtemp(prefix="lobelight-tests-"))
atexit.register(shutil.rmtree, SESSION_TMP, ignore_errors=True)
for _var, _sub in [
    ("LOBELIGHT_CACHE", "lobelight"),  # lobelight._cache.cache_dir()
    ("NUMBA_CACHE_DIR", "numba"),  # the compiled visibility walk (cosine._walk, cache=True)
    ("DRJIT_CACHE_DIR", "drjit"),  # Mitsuba's kernel cache (else ~/.drjit)
    ("WARP_CACHE_PATH", "warp"),  # NVIDIA Warp's compiled kernels (the Warp ray engine)
    ("MPLCONFIGDIR", "matplotlib"),  # matplotlib's font cache (else ~/.cache/matplotlib)
    ("HYPOTHESIS_STORAGE_DIRECTORY", "hypothesis"),  # its example database (else ./.hypothesis)
]:
    os.environ[_var] = str(SESSION_TMP / _sub)

import random  # noqa: E402 - after the cache variables above

import numpy as np  # noqa: E402
import pytest  # noqa: E402
import torch  # noqa: E402
from hypothesis import assume  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

import lobelight  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def _bundled_envmaps() -> list[Path]:
    from lobelight.data import envmap_names, envmap_path

    return [envmap_path(n) for n in envmap_names()]


#: The real HDR maps that ship with the package (CC0): the park with its small unclipped sun
#: and the studio's softboxes, 512 x 256 each.
REAL_ENVMAPS = _bundled_envmaps()
assert len(REAL_ENVMAPS) >= 2, REAL_ENVMAPS

#: Spot (public domain, 2,930 vertices), as the examples use it.
SPOT = ROOT / "examples" / "spot.obj"


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
def builtin_sky():
    """The built-in sky at its default 512 x 1024 (seconds to make): one for the session."""
    from lobelight import envmap

    return envmap.builtin()


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


def pytest_configure(config):
    # CI tests the package as installed, not the source tree (.ci/run sets the variable): a
    # module or data file the wheel leaves out must fail the run
    if os.environ.get("LOBELIGHT_TEST_INSTALLED") == "1":
        src = Path(__file__).resolve().parents[1] / "src"
        if Path(lobelight.__file__).resolve().is_relative_to(src):
            raise pytest.UsageError(f"lobelight is imported from {src}, not from its install")
