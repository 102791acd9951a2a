"""``lobelight bench all``: every benchmark in one run, its file kept whole, and its table.

The benchmarks themselves are stood in for (their figures are measured by hand and recorded in
docs/benchmarks.md); what is tested is the run's bookkeeping and the table made from it, and
that the prefilter's record keeps its figures when its CUDA graph cannot be captured.
"""

from __future__ import annotations

import json

import pytest

from lobelight.bench import prefilter as bench
from lobelight.bench import suite as ba
from lobelight.cli import _commands, main


def _fake(value: dict):
    return lambda: dict(value)


def test_runs_in_order_writes_after_each_and_keeps_going_after_a_failure(tmp_path):
    out = tmp_path / "gpu.json"
    seen = []

    def failing():
        seen.append(json.loads(out.read_text()))  # the file holds the first result already
        raise RuntimeError("CUDA error: out of memory\nsecond line")

    runs = {
        "prefilter": _fake({"seconds_best": 0.004}),
        "rays": failing,
        "bake_10k": _fake({"seconds_per_10k_vertices": 12.0}),
    }
    s = ba.bench_all(device="cuda", output=out, only=tuple(runs), runs=runs)
    assert list(s["results"]) == ["prefilter", "rays", "bake_10k"]
    assert seen[0]["results"] == {"prefilter": {"seconds_best": 0.004}}
    err = s["results"]["rays"]["error"]
    assert err.startswith("RuntimeError: CUDA error") and "\n" not in err
    assert s["results"]["bake_10k"] == {"seconds_per_10k_vertices": 12.0}
    assert json.loads(out.read_text()) == json.loads(json.dumps(s))


def test_budget_skips_what_has_not_started():
    calls = []
    runs = {n: (lambda n=n: calls.append(n) or {"seconds_best": 1.0}) for n in ("a", "b")}
    s = ba.bench_all(device="cpu", only=("a", "b"), runs=runs, budget_seconds=1e-9)
    # the first always runs (no time has passed before it), the second finds the budget spent
    assert calls == ["a"]
    assert "skipped" in s["results"]["b"]


def test_unknown_benchmark_is_refused():
    with pytest.raises(ValueError, match="unknown benchmarks"):
        ba.bench_all(only=("nope",), runs={"a": _fake({})})


def test_table_gives_each_goal_its_gap():
    summary = {
        "device": "cuda",
        "machine": {"gpu": "NVIDIA H200", "torch": "2.11"},
        "results": {
            "prefilter": {"seconds_best": 0.5, "seconds_dynamic_best": 0.010},
            "bake_10k": {"seconds_per_10k_vertices": 5.0},
            "bake_50k": {"error": "RuntimeError: boom"},
            "render": {
                "rows": [{"n_gaussians": 1, "fps": 500.0}, {"n_gaussians": 3, "fps": 1000.0}]
            },
            "rays": {
                "engines": [
                    {
                        "engine": "warp",
                        "occluded_rays_per_second": 1e9,
                        "first_hit_rays_per_second": 5e8,
                    }
                ]
            },
        },
    }
    text = ba.table(summary)
    rows = {line.split("|")[1].strip(): line for line in text.splitlines() if line.startswith("|")}
    assert "NVIDIA H200" in text
    # the GPU goal is a dynamic environment's: 10 ms against at most 5 ms, twice the goal
    assert "seconds_dynamic_best" in rows["prefilter"] and "2.00x" in rows["prefilter"]
    assert "0.50x" in rows["bake_10k"]  # 5 s against at most 10 s: half
    assert "boom" in rows["bake_50k"]
    assert "2.00x" in rows["render_n1"]  # 500 fps against at least 1000: twice too slow
    assert "0.50x" in rows["render_n3"]
    assert "1e+09 occlusion rays/s" in rows["rays (warp)"]


def test_table_from_the_command_line(tmp_path, capsys):
    path = tmp_path / "r.json"
    path.write_text(json.dumps({"device": "cpu", "results": {"prefilter": {"seconds_best": 1}}}))
    ba.main(["table", str(path)])
    assert "| prefilter | seconds_best = 1 | at most 0.5 | 2.00x |" in capsys.readouterr().out


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["bench", "all", "--budget", "-3"], "--budget"),
        (["bench", "all", "--budget", "nan"], "--budget"),
        (["bench", "all", "-o", "/nonexistent-dir/gpu.json"], "does not exist"),
    ],
)
def test_bad_arguments_fail_before_any_work(argv, needle, capsys, monkeypatch):
    def never(**_):
        raise AssertionError("a benchmark ran")

    monkeypatch.setattr(_commands, "bench_all", never)
    assert main([*argv, "-q"]) == 2
    err = capsys.readouterr().err
    assert needle in err and err.count("\n") == 1


def test_bench_all_command_passes_its_settings(tmp_path, capsys, monkeypatch):
    got = {}

    def fake(**kw):
        got.update(kw)
        return {"benchmark": "all", "results": {}}

    monkeypatch.setattr(_commands, "bench_all", fake)
    out = tmp_path / "gpu.json"
    assert main(["bench", "all", "--budget", "60", "-o", str(out), "--json", "-q"]) == 0
    assert got["device"] == "cpu" and got["budget_seconds"] == 60 and got["output"] == str(out)
    assert json.loads(capsys.readouterr().out)["benchmark"] == "all"


def test_bench_prefilter_times_the_dynamic_path_and_survives_a_failed_capture(monkeypatch):
    record = bench.bench_prefilter(base_res=16, repeats=2)
    assert record["cuda_graph"] is False and record["cuda_graph_error"] is None
    assert 0 < record["seconds_dynamic_best"] <= record["seconds_dynamic_median"]
    assert record["dynamic_repeats"] == 2 and record["ops_per_build"] > 0

    real = bench.ChainBuilder

    def no_capture(**kwargs):  # as a CUDA device whose capture fails would
        if kwargs["graph"] is None:
            raise RuntimeError("operation not permitted when stream is capturing")
        return real(**kwargs)

    monkeypatch.setattr(bench, "ChainBuilder", no_capture)
    record = bench.bench_prefilter(base_res=16, repeats=2)
    assert "not permitted" in record["cuda_graph_error"]
    assert record["cuda_graph"] is False and record["seconds_dynamic_best"] > 0
