"""A bake on a Dask cluster (``fit_mesh(..., client=)``): the local bake's model, faults.

Every test runs on one ``distributed.LocalCluster`` of two worker processes of one thread each
(:func:`lobelight.fit.cluster`; a nanny restarts a worker that dies), with tiny meshes: two
icospheres of 42 vertices side by side, so that indirect glossy paths bounce off the other
sphere (the chunks' seeded paths are compared too), and a 12-vertex icosphere for two
Gaussians per view.
"""

from __future__ import annotations

import io
import json
import math
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

distributed = pytest.importorskip(
    "distributed", reason="the cluster bake needs Dask: pip install 'lobelight[cluster]'"
)
cloudpickle = pytest.importorskip("cloudpickle")

from lobelight import fit, scene  # noqa: E402
from lobelight.bench import bench_cluster  # noqa: E402
from lobelight.cli import main  # noqa: E402
from lobelight.errors import InputError  # noqa: E402
from lobelight.model._format import read  # noqa: E402
from lobelight.progress import Reporter  # noqa: E402

# the fault-injecting functions below run on the workers, which cannot import this file
cloudpickle.register_pickle_by_value(sys.modules[__name__])

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def client():
    # a distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True)
    with fit.cluster(workers=2) as c:
        assert len(c.scheduler_info()["workers"]) == 2
        yield c


def _two_spheres() -> scene.Scene:
    """84 vertices: two glossy icospheres that see each other (indirect glossy paths hit)."""
    one = scene.builtin("sphere", subdivisions=1)
    v, f = one.mesh.vertices, one.mesh.faces
    shift = torch.tensor([1.05, 0.0, 0.0])
    mesh = scene.mesh_from_arrays(
        torch.cat([v - shift, v + shift]), torch.cat([f, f + v.shape[0]]), name="two"
    )
    spec = {"diffuse": [0.3, 0.3, 0.3], "model": "phong", "exponent": 20.0, "specular": [0.5] * 3}
    return scene.Scene(mesh, scene.uniform(spec, mesh.n_vertices), "builtin", one.camera, "two")


#: One Gaussian, chunks of 6 vertices (14 chunks), paths that hit the other sphere, bounces.
KW = dict(n=1, batch=6, indirect_paths=2, bounces=1, checkpoint_every=0)


@pytest.fixture(scope="module")
def spheres():
    sc = _two_spheres()
    return sc, fit.fit_mesh(sc, **KW)


def _same(a, b) -> None:
    """Bit for bit: the same chunks computed in another process of the same build."""
    for x, y in (
        (a.gaussians.w, b.gaussians.w),
        (a.gaussians.mu, b.gaussians.mu),
        (a.gaussians.lam, b.gaussians.lam),
        (a.diffuse, b.diffuse),
        (a.bounce, b.bounce),
        (a.data_error, b.data_error),
    ):
        torch.testing.assert_close(x, y, rtol=0, atol=0)
    assert a.indirect_gaussians == b.indirect_gaussians
    assert (a.flips_before, a.flips_after) == (b.flips_before, b.flips_after)


class _Kill(Exception):
    """Stands for a client killed in the middle of a bake."""


def test_the_cluster_bake_is_the_local_bake_bit_for_bit(client, spheres):
    sc, local = spheres
    assert local.indirect_gaussians == 1  # the paths bounced: their seeding is compared too
    seen = []
    mf = fit.fit_mesh(sc, **KW, client=client, progress=lambda *a: seen.append(a))
    _same(mf, local)
    fills = [d for s, d, t in seen if s == "fit"]
    assert fills == list(range(1, 15))  # every chunk reported once, as it came back
    # the bake's plugin is gone from the workers: nothing of it stays behind
    plugins = client.run(lambda dask_worker: list(dask_worker.plugins))
    assert not any(p.startswith("lobelight") for ps in plugins.values() for p in ps)


def test_fit_model_on_a_cluster_gives_the_local_model_and_reports_progress(client):
    sc = scene.builtin("sphere", subdivisions=1, model="phong", exponent=200.0)
    kw = dict(n_gaussians=1, batch=8, indirect_paths=0, bounces=1)
    a = fit.fit_model(sc, **kw, progress=None)
    log = io.StringIO()  # off a terminal: plain lines, here one per chunk
    b = fit.fit_model(
        sc,
        **kw,
        client=client.scheduler.address,  # an address: it connects
        progress=Reporter(log, interval=0.0, bars=False),
    )
    for x, y in ((a.gaussians.w, b.gaussians.w), (a.gaussians.mu, b.gaussians.mu),
                 (a.diffuse, b.diffuse)):  # fmt: skip
        torch.testing.assert_close(x, y, rtol=0, atol=0)
    assert "cluster" in b.provenance and "cluster" not in a.provenance
    lines = log.getvalue().splitlines()
    assert f"on the Dask cluster at {client.scheduler.address} (2 workers now)" in lines[0]
    fills = [ln for ln in lines if ln.startswith("lobelight: fit: ")]
    assert fills[0].startswith("lobelight: fit: 1/6 chunks") and "s left" in fills[1]
    assert fills[-1].startswith("lobelight: fit: 6/6 chunks (100 %), done in")


def test_two_gaussians_with_one_chunk_per_wavefront_give_the_local_bake(client):
    # a wavefront in one chunk reads what it does in one process: the cluster's order (a
    # wavefront's chunks at once, reading earlier wavefronts only) changes nothing there, in
    # the flood fill and in the relaxation, so the models agree bit for bit
    sc = scene.builtin("sphere", subdivisions=0, model="ggx", roughness=0.25)
    kw = dict(n=2, batch=6, indirect_paths=0, bounces=0)
    assert max(w.numel() for w in fit.wavefronts(sc.mesh)) <= 6
    _same(fit.fit_mesh(sc, **kw, client=client), fit.fit_mesh(sc, **kw))


@pytest.mark.parametrize("stage", ["fit", "relax"])
def test_two_gaussians_killed_mid_wavefront_resume_on_the_cluster_to_the_same_model(
    tmp_path, client, stage
):
    # 12 vertices in wavefronts of 1, 5, 5 and 1, chunks of 2: groups of several chunks that
    # run at once. In the flood fill a chunk reads the wavefronts before its own only, whatever
    # the checkpoint holds of its own; a wavefront's refit reads the state as the wavefront
    # found it, so the relaxation's checkpoint is saved between wavefronts only, and a resumed
    # bake runs the interrupted wavefront whole again, from the state it started from
    sc = scene.builtin("sphere", subdivisions=0, model="ggx", roughness=0.25)
    kw = dict(n=2, batch=2, indirect_paths=0, bounces=0, checkpoint_every=0, client=client)
    clean = fit.fit_mesh(sc, **kw)
    ck = tmp_path / "bake.ckpt.npz"

    def killer(at, done, total):
        if at == stage and done == 5:  # inside the third wavefront (chunks 4-6)
            raise _Kill

    with pytest.raises(_Kill):
        fit.fit_mesh(sc, **kw, checkpoint=ck, progress=killer)
    with np.load(ck, allow_pickle=False) as z:
        meta = json.loads(bytes(z["meta"]).decode())
        reached = int(z["done"].sum())
    seen = []
    _same(fit.fit_mesh(sc, **kw, checkpoint=ck, progress=lambda *a: seen.append(a)), clean)
    if stage == "fit":
        assert meta["stage"] == "fit" and reached > 6  # a chunk of the third wavefront is in
        assert [d for s, d, t in seen if s == "fit"] == [6, 7, 8]
    else:
        assert (meta["stage"], meta["next"]) == ("relax", 4)  # the end of the second wavefront
        assert [d for s, d, t in seen if s == "relax"] == [5, 6, 7, 8]


@pytest.mark.parametrize("killed_on", ["cluster", "local"])
def test_a_killed_client_resumes_from_its_checkpoint_with_or_without_the_cluster(
    tmp_path, client, spheres, killed_on
):
    sc, local = spheres
    ck = tmp_path / "bake.ckpt.npz"

    def killer(stage, done, total):
        if stage == "fit" and done == 5:
            raise _Kill

    with pytest.raises(_Kill):
        fit.fit_mesh(
            sc,
            **KW,
            checkpoint=ck,
            progress=killer,
            client=client if killed_on == "cluster" else None,
        )
    assert ck.exists() and not list(tmp_path.glob("*.partial*"))
    seen = []
    resume_on = None if killed_on == "cluster" else client
    mf = fit.fit_mesh(sc, **KW, checkpoint=ck, progress=lambda *a: seen.append(a), client=resume_on)
    _same(mf, local)
    # it went on from the checkpoint: the five chunks done (in any order on the cluster) were
    # not run again, the nine others were
    assert len([d for s, d, t in seen if s == "fit"]) == 14 - 5


def test_a_worker_killed_mid_chunk_has_its_chunks_run_elsewhere(client, spheres):
    sc, local = spheres
    pids = client.run(os.getpid)
    killed = []

    def kill_a_busy_worker(stage, done, total):
        if stage == "fit" and not killed:
            busy = [w for w, keys in client.processing().items() if keys]
            assert busy, "no chunk in flight"
            os.kill(pids[busy[0]], signal.SIGKILL)
            killed.append(busy[0])

    mf = fit.fit_mesh(sc, **KW, client=client, progress=kill_a_busy_worker)
    _same(mf, local)
    assert killed
    client.wait_for_workers(2, timeout=60)  # the nanny restarted it
    assert set(client.run(os.getpid).values()) != set(pids.values())


def _fail_chunk_3(kind: str):
    """Patch the workers' chunk computation so that chunk 3 raises (``"raise"``) or returns
    NaN weights (``"nan"``)."""
    from lobelight.fit import _worker

    real = _worker.compute_chunk

    def broken(stage, bake, chunk, inputs):
        result = real(stage, bake, chunk, inputs)
        if chunk.index == 3:
            if kind == "raise":
                raise ValueError("degenerate data")
            result.arrays["w"][0] = float("nan")
        return result

    _worker.compute_chunk, _worker._real = broken, real


def _restore():
    from lobelight.fit import _worker

    _worker.compute_chunk = getattr(_worker, "_real", _worker.compute_chunk)


@pytest.mark.parametrize("kind", ["raise", "nan"])
def test_a_chunk_failing_on_its_data_stops_the_bake_with_one_error_naming_it(
    tmp_path, client, spheres, kind
):
    sc, _ = spheres
    chunks = fit._chunk.plan_chunks(fit.wavefronts(sc.mesh), n=1, batch=6, device="cpu")
    ids = chunks[3].vertices.tolist()
    ck = tmp_path / "bake.ckpt.npz"
    client.run(_fail_chunk_3, kind)
    try:
        with pytest.raises(InputError) as e:
            fit.fit_mesh(sc, **KW, client=client, checkpoint=ck)
    finally:
        client.run(_restore)
    text = str(e.value)
    if kind == "raise":
        assert text.startswith(f"vertices {', '.join(map(str, ids))}:"), text
        assert "degenerate data" in text
    else:
        assert text.startswith(f"vertex {ids[0]}:") and "not finite" in text, text
    # nothing half-written: no temporary file, and the checkpoint (saved after each chunk
    # that came back before) is whole, its chunk 3 not done and nothing in it NaN
    assert not list(tmp_path.glob("*.partial*"))
    if ck.exists():
        with np.load(ck, allow_pickle=False) as z:
            assert not z["done"][ids].any()
            assert all(np.isfinite(z[k]).all() for k in z.files if z[k].dtype.kind == "f")


def test_an_unreachable_scheduler_is_one_clear_error():
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    address = f"tcp://127.0.0.1:{port}"
    with pytest.raises(InputError, match="no Dask scheduler answered within 1 s") as e:
        with fit.cluster(address, timeout=1):
            pass
    assert str(e.value).startswith(address)
    with pytest.raises(InputError, match="scheduler's address or a number of local workers"):
        with fit.cluster():
            pass


#: A client process: the bake of the two spheres on the scheduler at argv[1], saving its state
#: after every chunk to argv[2].
CLIENT = """
import sys
sys.path.insert(0, {tests!r})
import distributed
from lobelight import fit
from test_cluster import KW, _two_spheres
with distributed.Client(sys.argv[1]) as c:
    fit.fit_mesh(_two_spheres(), **KW, client=c, checkpoint=sys.argv[2], progress=None)
"""


@pytest.mark.slow  # a second Python process importing torch, lobelight and Dask
def test_a_client_process_killed_mid_bake_resumes_on_the_cluster(tmp_path, client, spheres):
    sc, local = spheres
    ck = tmp_path / "bake.ckpt.npz"
    code = CLIENT.format(tests=str(Path(__file__).parent))
    p = subprocess.Popen(
        [sys.executable, "-c", code, client.scheduler.address, str(ck)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    deadline = time.monotonic() + 600
    reached = 0
    while p.poll() is None and time.monotonic() < deadline:
        try:  # written atomically: a whole file or none
            with np.load(ck, allow_pickle=False) as z:
                reached = int(z["done"].sum())
        except FileNotFoundError:
            pass
        if reached >= 12:  # two chunks of six or more came back
            os.kill(p.pid, signal.SIGKILL)
            break
        time.sleep(0.01)
    assert p.wait(timeout=60) == -signal.SIGKILL, p.stderr.read().decode()
    assert not list(tmp_path.glob("*.partial*"))
    seen = []
    mf = fit.fit_mesh(sc, **KW, checkpoint=ck, client=client, progress=lambda *a: seen.append(a))
    _same(mf, local)
    assert len([d for s, d, t in seen if s == "fit"]) <= 14 - 2  # it went on from the checkpoint


def test_bake_on_a_cluster_from_the_command_line_writes_the_local_model(client, tmp_path):
    """``lobelight bake ... --cluster ADDRESS`` gives the model file the plain bake gives,
    array for array (one Gaussian per view: the chunks are independent)."""
    args = ["bake", "sphere:1", "--gaussians", "1", "--indirect-paths", "2", "--bounces", "1"]
    args.append("-q")
    here, there = tmp_path / "here.npz", tmp_path / "there.npz"
    assert main([*args, "-o", str(here)]) == 0
    assert main([*args, "-o", str(there), "--cluster", client.scheduler.address]) == 0
    a, b = read(here), read(there)
    for k in ("diffuse", "bounce"):
        torch.testing.assert_close(a[k], b[k], rtol=0, atol=0)
    ga, gb = a["gaussians"], b["gaussians"]
    for x, y in ((ga.w, gb.w), (ga.mu, gb.mu), (ga.lam, gb.lam)):
        torch.testing.assert_close(x, y, rtol=0, atol=0)


def test_bench_cluster_times_the_local_and_the_cluster_bakes():
    """``lobelight bench cluster``'s record: per worker count a local run on as many threads
    and the cluster run, each with its chunks' stage timed, and the overhead (cluster against
    the local run on the same threads) and projection computed from them."""
    r = bench_cluster(scene="sphere:1", workers=(1,), indirect_paths=0, bounces=0)
    assert [(row["workers"], row["threads"]) for row in r["runs"]] == [(0, 1), (1, 1)]
    local, one = r["runs"]
    assert r["overhead"] == pytest.approx(
        one["chunk_stage_seconds"] / local["chunk_stage_seconds"] - 1
    )
    assert all(row["chunk_stage_seconds"] > 0 for row in r["runs"])
    assert r["chunks"] == math.ceil(r["vertices"] / r["batch"])
    assert r["projection"]["workers"] == 20 * (os.cpu_count() or 1)
    assert math.isfinite(r["overhead"]) and math.isfinite(r["overhead_seconds_per_chunk"])
