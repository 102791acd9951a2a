"""The long fuzz run of lobelight's loaders (not in CI): many random inputs per target.

Runs ``tests/test_fuzz.py`` (the mutators and checks CI runs with a few hundred fixed inputs
per test) with random inputs instead, ``--inputs`` per target split over the target's tests,
each pytest process under a memory limit, and writes a summary: per target the inputs, the
clean errors (one ``InputError`` naming the file, or a damaged checkpoint moved aside), the
inputs accepted (and checked sane), and the crashes, hangs and memory blow-ups (test failures:
hypothesis stops a test at its first and reports it).

    python tools/fuzz.py --inputs 100000 --jobs 2 -o fuzz-summary.json

Targets: model files, meshes, glTF assets (``.glb`` bytes, ``.gltf`` documents), scene files,
environment maps, cosine-lobe tables, bake checkpoints, command-line arguments (every command,
its checks run and its work stood in for).
"""

from __future__ import annotations

import argparse
import json
import math
import os
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
}


def run_test(test: str, inputs: int, memory_gb: float, workdir: Path) -> dict:
    """One test with ``inputs`` random inputs, in its own pytest process."""
    tally = workdir / f"{test}.json"
    env = {
        **os.environ,
        "LOBELIGHT_FUZZ_EXAMPLES": str(inputs),
        "LOBELIGHT_FUZZ_TALLY": str(tally),
        "LOBELIGHT_FUZZ_MEMORY_GB": str(memory_gb),
    }
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "no:logging"]
    cmd += ["-W", "ignore", f"tests/test_fuzz.py::{test}"]
    t0 = time.perf_counter()
    p = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
    counts = json.loads(tally.read_text()).get(test, {}) if tally.exists() else {}
    failed = p.returncode != 0
    return {
        "test": test,
        "inputs": sum(counts.values()) + int(failed),
        "clean_errors": counts.get("clean_errors", 0),
        "accepted": counts.get("accepted", 0),
        "crashes": int(failed),
        "seconds": time.perf_counter() - t0,
        "failure": p.stdout[-4000:] if failed else None,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--inputs", type=int, default=100_000, help="inputs per target")
    ap.add_argument("--targets", nargs="*", default=list(TARGETS), choices=list(TARGETS))
    ap.add_argument("--jobs", type=int, default=2, help="pytest processes at once")
    ap.add_argument("--memory-gb", type=float, default=4.0, help="address space per process")
    ap.add_argument("-o", "--output", default="fuzz-summary.json")
    args = ap.parse_args(argv)
    work = [
        (target, test, math.ceil(args.inputs / len(TARGETS[target])))
        for target in args.targets
        for test in TARGETS[target]
    ]
    with tempfile.TemporaryDirectory() as tmp, ThreadPoolExecutor(args.jobs) as pool:
        runs = list(
            pool.map(lambda w: (w[0], run_test(w[1], w[2], args.memory_gb, Path(tmp))), work)
        )
    table = {}
    for target, r in runs:
        row = table.setdefault(
            target, {"target": target, "inputs": 0, "clean_errors": 0, "accepted": 0,
                     "crashes": 0, "seconds": 0.0, "tests": []}
        )  # fmt: skip
        for k in ("inputs", "clean_errors", "accepted", "crashes", "seconds"):
            row[k] += r[k]
        row["tests"].append(r)
    summary = {"inputs_per_target": args.inputs, "targets": list(table.values())}
    Path(args.output).write_text(json.dumps(summary, indent=2))
    print("| target | inputs | clean errors | accepted | crashes |")
    print("|---|---|---|---|---|")
    for row in table.values():
        print(
            f"| {row['target']} | {row['inputs']:,} | {row['clean_errors']:,} | "
            f"{row['accepted']:,} | {row['crashes']} |"
        )
    return int(any(row["crashes"] for row in table.values()))


if __name__ == "__main__":
    sys.exit(main())
