"""The long fuzz run of lobelight's loaders (not in CI): many random inputs per target.

Runs ``tests/test_fuzz.py`` (the mutators and checks CI runs with a few hundred fixed inputs
per test) with random inputs instead, ``--inputs`` per target split over the target's tests,
each pytest process under a memory limit (``RLIMIT_AS``, ``--memory-gb``) and a wall-clock
limit, and writes a summary: per target the inputs, the clean errors (one ``InputError`` naming
the file, or a damaged checkpoint moved aside), the inputs accepted (and checked sane), and the
failures by kind: crashes (an exception other than a clean error, or a check of the result that
failed), hangs (an input past the test's time limit, or a process past ``--timeout``) and peaks
(a ``MemoryError`` under the address-space limit, or a structured target's peak over its stated
bound); hypothesis stops a test at its first failure and reports it. The peak column is the
largest resident memory of a target's processes (``ru_maxrss``).

    python tools/fuzz.py --inputs 100000 --jobs 2 -o fuzz-summary.json
    python tools/fuzz.py --targets mesh-structured model-claims cli-limits outputs --inputs 2000

Targets, mutated: model files, meshes, glTF assets (``.glb`` bytes, ``.gltf`` documents), scene
files, environment maps, cosine-lobe tables, bake checkpoints, command-line arguments (every
command, its checks run and its work stood in for). Structured (well-formed inputs a careful
user may have): meshes with far, tiny, flipped and stray parts (refused, or kept faithfully);
model files whose metadata claims large sizes (refused, or read within a peak bound); the
command line's numeric flags at the limits of their types; outputs aimed at inputs.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: Target -> its tests in tests/test_fuzz.py.
TARGETS = {
    "model": ["test_fuzz_model_bytes", "test_fuzz_model_arrays", "test_fuzz_model_meta"],
    "mesh": ["test_fuzz_mesh_text", "test_fuzz_mesh_bytes"],
    "gltf": ["test_fuzz_glb_bytes", "test_fuzz_gltf_structured"],
    "scene": ["test_fuzz_scene_structured", "test_fuzz_scene_bytes"],
    "envmap": [
        "test_fuzz_envmap_hdr_bytes",
        "test_fuzz_envmap_exr_bytes",
        "test_fuzz_envmap_pixels_and_aspect",
    ],
    "tables": ["test_fuzz_tables_bytes", "test_fuzz_tables_structured"],
    "checkpoint": ["test_fuzz_checkpoint_bytes", "test_fuzz_checkpoint_meta"],
    "cli": ["test_fuzz_cli_arguments"],
    "mesh-structured": ["test_fuzz_mesh_structured"],
    "model-claims": ["test_fuzz_model_claims"],
    "cli-limits": ["test_fuzz_cli_numeric_limits"],
    "outputs": ["test_fuzz_outputs_aimed_at_inputs"],
}

#: Failure kinds, told apart by what the failing test printed (first match wins).
_KINDS = (
    ("hangs", ("Hang", "load hung")),
    ("peaks", ("MemoryError", "peak memory grew", "Cannot allocate memory", "bad_alloc")),
)


def failure_kind(output: str) -> str:
    """``crashes``, ``hangs`` or ``peaks`` for a failed test's output."""
    for kind, marks in _KINDS:
        if any(m in output for m in marks):
            return kind
    return "crashes"


def _reap(p: subprocess.Popen, timeout: float) -> tuple[int, resource.struct_rusage, bool]:
    """Wait for ``p`` (killed past ``timeout`` seconds): its exit code, its resource usage
    (``wait4``: its own peak memory) and whether it timed out."""
    deadline = time.monotonic() + timeout
    timed_out = False
    while True:
        pid, status, usage = os.wait4(p.pid, os.WNOHANG)
        if pid:
            break
        if time.monotonic() > deadline:
            timed_out = True
            p.kill()
            _, status, usage = os.wait4(p.pid, 0)
            break
        time.sleep(0.2)
    p.returncode = os.waitstatus_to_exitcode(status)  # reaped here, not by Popen
    return p.returncode, usage, timed_out


def run_test(test: str, inputs: int, memory_gb: float, timeout: float, workdir: Path) -> dict:
    """One test with ``inputs`` random inputs, in its own pytest process."""
    tally = workdir / f"{test}.json"
    env = {
        **os.environ,
        "LOBELIGHT_FUZZ_EXAMPLES": str(inputs),
        "LOBELIGHT_FUZZ_TALLY": str(tally),
        "LOBELIGHT_FUZZ_MEMORY_GB": str(memory_gb),
        "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "1"),
    }
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "no:logging"]
    cmd += ["-W", "ignore", "--runxfail", f"tests/test_fuzz.py::{test}"]
    t0 = time.perf_counter()
    out_file = workdir / f"{test}.out"
    with open(out_file, "w+") as out:
        p = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=out, stderr=subprocess.STDOUT)
        code, usage, timed_out = _reap(p, timeout)
        out.seek(0)
        text = out.read()
    peak_mb = usage.ru_maxrss / 1024  # kB on Linux
    counts = json.loads(tally.read_text()).get(test, {}) if tally.exists() else {}
    failed = timed_out or code != 0
    kind = "hangs" if timed_out else failure_kind(text) if failed else None
    row = {
        "test": test,
        "inputs": counts.get("clean_errors", 0) + counts.get("accepted", 0) + int(bool(failed)),
        "clean_errors": counts.get("clean_errors", 0),
        "accepted": counts.get("accepted", 0),
        "crashes": int(kind == "crashes"),
        "hangs": int(kind == "hangs"),
        "peaks": int(kind == "peaks"),
        "peak_mb": round(peak_mb) if peak_mb else None,
        "load_peak_mb": counts.get("peak_mb"),
        "seconds": time.perf_counter() - t0,
        "failure": text[-4000:] if failed else None,
    }
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--inputs", type=int, default=100_000, help="inputs per target")
    ap.add_argument("--targets", nargs="*", default=list(TARGETS), choices=list(TARGETS))
    ap.add_argument("--jobs", type=int, default=2, help="pytest processes at once")
    ap.add_argument("--memory-gb", type=float, default=4.0, help="address space per process")
    ap.add_argument(
        "--timeout", type=float, default=6 * 3600, help="seconds one pytest process may run"
    )
    ap.add_argument("-o", "--output", default="fuzz-summary.json")
    args = ap.parse_args(argv)
    work = [
        (target, test, math.ceil(args.inputs / len(TARGETS[target])))
        for target in args.targets
        for test in TARGETS[target]
    ]
    with tempfile.TemporaryDirectory() as tmp, ThreadPoolExecutor(args.jobs) as pool:
        runs = list(
            pool.map(
                lambda w: (w[0], run_test(w[1], w[2], args.memory_gb, args.timeout, Path(tmp))),
                work,
            )
        )
    table = {}
    counted = ("inputs", "clean_errors", "accepted", "crashes", "hangs", "peaks", "seconds")
    for target, r in runs:
        row = table.setdefault(
            target, {"target": target, **dict.fromkeys(counted, 0), "peak_mb": 0, "tests": []}
        )
        for k in counted:
            row[k] += r[k]
        row["peak_mb"] = max(row["peak_mb"], r["peak_mb"] or 0)
        row["tests"].append(r)
    summary = {"inputs_per_target": args.inputs, "memory_gb": args.memory_gb,
               "targets": list(table.values())}  # fmt: skip
    Path(args.output).write_text(json.dumps(summary, indent=2))
    print("| target | inputs | clean errors | accepted | crashes | hangs | peaks | peak MB |")
    print("|---|---|---|---|---|---|---|---|")
    for row in table.values():
        print(
            f"| {row['target']} | {row['inputs']:,} | {row['clean_errors']:,} | "
            f"{row['accepted']:,} | {row['crashes']} | {row['hangs']} | {row['peaks']} | "
            f"{row['peak_mb']:,} |"
        )
    return int(any(row["crashes"] or row["hangs"] or row["peaks"] for row in table.values()))


if __name__ == "__main__":
    sys.exit(main())
