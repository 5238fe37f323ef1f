"""The benchmark harness runs end to end in quick mode and writes well-formed records (no timing asserts)."""

import json

from wbmpc.studies import bench

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


def test_committed_table1_has_the_issue_columns_and_matches_its_markdown(tmp_path):
    from wbmpc.ocp.formulations import FORMULATIONS
    from wbmpc.studies import table1

    rows = table1.load_table()
    required = {
        "formulation",
        "base_in_input",
        "path_constraint",
        "instructions",
        "decision_variables",
        "pre_mean_ms",
        "pre_std_ms",
        "post_mean_ms",
        "post_std_ms",
        "iterations_mean",
        "build_s",
    }
    assert [r["formulation"] for r in rows] == list(FORMULATIONS)
    for r in rows:
        assert required <= set(r) and all(r[key] is not None for key in required)
        assert r["post_mean_ms"] > 0 and r["pre_mean_ms"] > 0
    assert (table1.REPO_ROOT / "data/bench/table1.md").read_text() == table1.markdown(rows)
    table1.plot(rows, tmp_path / "figures" / "table1.png")
    assert (tmp_path / "figures" / "table1.png").stat().st_size > 1000
