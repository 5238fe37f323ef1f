"""The benchmark harness runs end to end in quick mode and writes well-formed records (no timing asserts)."""

import json

from wbmpc import bench

REQUIRED = {
    "formulation",
    "solver",
    "compiled",
    "nodes",
    "steps",
    "mean_ms",
    "std_ms",
    "median_ms",
    "p95_ms",
    "max_ms",
    "iterations_mean",
    "build_s",
    "build_peak_mb",
    "machine",
}


def test_quick_benchmark_writes_records(tmp_path):
    output = tmp_path / "solve_times.json"
    records = bench.main(["--quick", "--steps", "4", "--warmup", "1", "--output", str(output), "--quiet"])
    stored = json.loads(output.read_text())
    assert stored == json.loads(json.dumps(records))
    assert {(r["solver"], r["compiled"]) for r in stored} == {("fatrop", False), ("ipopt", False)}
    for record in stored:
        assert REQUIRED <= set(record)
        assert record["steps"] == 4
        assert 0 < record["median_ms"] <= record["p95_ms"] <= record["max_ms"]
        assert record["converged_fraction"] == 1.0
