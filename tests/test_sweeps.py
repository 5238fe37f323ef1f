"""The sweep engine on Dask: grid, table, resume, failures (raise, worker death), shared solver cache."""

import math

# distributed and pybullet are pinned in environment.txt: a broken install must fail here, not skip.
import distributed  # noqa: F401
import pybullet  # noqa: F401
import pytest

from wbmpc.studies import sweeps

# The case functions live in wbmpc.studies.sweeps: workers import them by name (this module is not
# importable from a worker process).


@pytest.fixture(scope="module")
def client():
    """One 2-worker local cluster for the module (starting one costs ~2-3 s)."""
    with sweeps.local_cluster(workers=2) as client:
        yield client


def test_grid_ids_are_stable_and_distinct():
    cases = sweeps.grid(magnitude=[0.4, 0.8], phase=[0.0, 0.25], seed=0)
    assert len(cases) == 4 and len({c["case_id"] for c in cases}) == 4
    assert cases[1] == {"case_id": cases[1]["case_id"], "magnitude": 0.4, "phase": 0.25, "seed": 0}
    # The id depends on the parameters only, not on their order or on the rest of the grid.
    assert sweeps.case_id({"seed": 0, "phase": 0.25, "magnitude": 0.4}) == cases[1]["case_id"]
    assert sweeps.grid(magnitude=[0.4], phase=[0.25], seed=[0])[0] == cases[1]
    with pytest.raises(ValueError, match="repeated"):
        sweeps.grid(x=[1, 1])


def test_tiny_grid_on_two_workers(client, tmp_path):
    cases = sweeps.grid(x=[1, 2, 3, 4], action=[None, "fall"])
    run = sweeps.run_sweep(cases, sweeps.demo_case, tmp_path / "t.csv", client=client, progress=False)
    assert run.counts == {"ok": 4, "fell": 4} and run.skipped == 0
    rows = {r["case_id"]: r for r in sweeps.read_table(tmp_path / "t.csv")}
    assert set(rows) == {c["case_id"] for c in cases}
    for case in cases:
        row = rows[case["case_id"]]
        assert row["y"] == 2 * case["x"] and row["fell"] == (case["action"] == "fall")
        assert row["worker"].startswith("tcp://") and row["wall_s"] >= 0 and row["error"] is None
        # BLAS/OpenMP pinned to one thread in the workers
        assert row["omp_num_threads"] == row["openblas_num_threads"] == row["mkl_num_threads"] == 1
    assert len({r["pid"] for r in rows.values()}) == 2  # both workers ran cases


def test_resume_skips_done_cases_and_repairs_a_cut_row(client, tmp_path):
    path = tmp_path / "t.csv"
    first = sweeps.grid(x=[1, 2, 3])
    sweeps.run_sweep(first, sweeps.demo_case, path, client=client, progress=False)
    # An interrupted write leaves a cut last line: that case is run again, the others are kept.
    with open(path, "a") as f:
        f.write("deadbeef0000,9,")
    run = sweeps.run_sweep(
        sweeps.grid(x=[1, 2, 3, 4, 5]), sweeps.demo_case, path, client=client, progress=False
    )
    assert run.skipped == 3 and sorted(r["x"] for r in run.rows) == [4, 5]
    assert sorted(r["x"] for r in sweeps.read_table(path)) == [1, 2, 3, 4, 5]
    again = sweeps.run_sweep(sweeps.grid(x=[1, 2, 3, 4, 5]), sweeps.demo_case, path, client=client)
    assert again.rows == [] and again.skipped == 5


def test_a_case_that_raises_is_recorded_and_the_others_complete(client, tmp_path):
    cases = sweeps.grid(x=[1, 2, 3], action=[None, "raise"])
    run = sweeps.run_sweep(cases, sweeps.demo_case, tmp_path / "t.csv", client=client, progress=False)
    assert run.counts == {"ok": 3, "error": 3}
    for row in sweeps.read_table(tmp_path / "t.csv"):
        if row["action"] == "raise":
            assert row["error"] == f"ValueError: case {row['case_id']} raised on purpose" and row["y"] is None
    # retry_failed runs the failed cases again (and only those)
    rerun = sweeps.run_sweep(cases, sweeps.demo_case, tmp_path / "t.csv", client=client, retry_failed=True)
    assert rerun.skipped == 3 and rerun.counts == {"error": 3}
    assert len(sweeps.read_table(tmp_path / "t.csv")) == 6


@pytest.mark.parametrize("crash", ["exit", "segfault"])
def test_a_worker_killed_mid_case_is_recorded_and_the_sweep_goes_on(client, tmp_path, crash):
    cases = sweeps.grid(x=[1, 2, 3, 4, 5], action=[None]) + sweeps.grid(x=[0], action=[crash], sleep=[0.2])
    run = sweeps.run_sweep(cases, sweeps.demo_case, tmp_path / "t.csv", client=client, progress=False)
    # Only the crashing case is lost: it is not retried, and no other case was waiting on that worker.
    assert run.counts == {"ok": 5, "worker-died": 1}
    (dead,) = [r for r in sweeps.read_table(tmp_path / "t.csv") if r["status"] == "worker-died"]
    assert dead["action"] == crash and "died" in dead["error"] and dead["worker"].startswith("tcp://")
    # The nanny restarted the worker: the cluster keeps its two workers for the next sweep.
    client.wait_for_workers(2, timeout=30)


def test_table_round_trips(tmp_path):
    rows = [
        {"case_id": "a", "m": 0.1, "n": 3, "name": "trot", "flag": True, "y": -1e-300, "z": math.inf,
         "status": "ok", "error": None, "wall_s": 1.25, "worker": "tcp://h:1"},
        {"case_id": "b", "m": 2.0, "n": -4, "name": "1_0", "flag": False, "extra": "a, \"quoted\"\nline",
         "status": "error", "error": "ValueError: x", "wall_s": None, "worker": None},
    ]  # fmt: skip
    path = sweeps.write_table(tmp_path / "t.csv", rows)
    back = sweeps.read_table(path)
    assert back == [{**r, **{k: None for k in ("y", "z", "extra") if k not in r}} for r in rows]
    header = path.read_text().splitlines()[0].split(",")
    assert header[0] == "case_id" and header[-4:] == ["status", "error", "wall_s", "worker"]
    sweeps.write_table(path, back)
    assert sweeps.read_table(path) == back


def test_heatmap_of_a_result_over_two_parameters():
    rows = [
        {**c, "status": "ok" if c["m"] < 0.8 or c["seed"] else "fell", "tilt": c["m"] + c["p"]}
        for c in sweeps.grid(m=[0.4, 0.8], p=[0.0, 0.25], seed=[0, 1])
    ]
    fig = sweeps.heatmap(rows, lambda r: r["status"] == "ok", x="p", y="m", title="success")
    data = fig.axes[0].images[0].get_array()
    assert data.tolist() == [[1.0, 1.0], [0.5, 0.5]]  # rows: m = 0.4, 0.8; mean over the seeds
    assert sweeps.heatmap(rows, "tilt", x="p", y="m").axes[0].images[0].get_array()[1, 1] == pytest.approx(
        1.05
    )


def test_two_workers_build_the_compiled_solver_once(client, tmp_path):
    """codegen's file lock serialises builds of one key: of two workers starting together, one compiles
    and the other loads its library; with a warm-up, the cases only load."""
    cache = str(tmp_path / "cache")
    cases = sweeps.grid(cache_dir=[cache], copy=[0, 1])
    run = sweeps.run_sweep(cases, sweeps.build_case, tmp_path / "t.csv", client=client, progress=False)
    assert run.counts == {"ok": 2} and len({r["worker"] for r in run.rows}) == 2
    assert sorted(r["rebuilt"] for r in run.rows) == [False, True] and len({r["key"] for r in run.rows}) == 1
    assert len(list((tmp_path / "cache").glob("*/build.json"))) == 1
    # Warm-up: built once before the cases (here already cached: nobody builds again).
    more = sweeps.grid(cache_dir=[cache], copy=[2, 3])
    run = sweeps.run_sweep(
        more, sweeps.build_case, tmp_path / "t.csv", client=client, warmup=sweeps.warm_build_cache
    )
    assert [r["rebuilt"] for r in run.rows] == [False, False]


def test_cli_help(capsys):
    with pytest.raises(SystemExit) as exit_:
        sweeps.main(["--help"])
    assert exit_.value.code == 0
    text = capsys.readouterr().out
    assert all(option in text for option in ("--scheduler", "--workers", "--output", "--quick"))


@pytest.mark.parametrize("study", ["payload", "nodes", "time_steps"])
def test_quick_study_grids_run_on_the_engine(client, tmp_path, study):
    """The payload, node-count and time-step studies (quick grids: in-process solver, short PyBullet runs)
    run as sweeps and give one complete row per case, and their figures."""
    make_cases, fn, _ = sweeps.STUDIES[study]
    cases = make_cases(True)
    run = sweeps.run_sweep(cases, fn, tmp_path / f"{study}.csv", client=client, progress=False)
    assert "error" not in run.counts and "worker-died" not in run.counts, run.rows
    rows = sweeps.read_table(tmp_path / f"{study}.csv")
    assert len(rows) == len(cases)
    for row in rows:
        assert 0.0 < row["converged_fraction"] <= 1.0 and row["sim_duration_s"] > 0.3
    if study == "payload":
        assert {(r["walking"], r["fell"]) for r in rows} == {(False, False), (True, False)}
        assert all(r["load_displacement_m"] is not None for r in rows)
    elif study == "nodes":
        assert sorted(r["nodes"] for r in rows) == [5, 8] and all(r["solve_ms_median"] > 0 for r in rows)
        assert all(r["ee_rms_cm"] is not None for r in rows)
    else:
        assert {r["grid"] for r in rows} == {"adaptive", "uniform"}
        assert all(r["drift_cm_per_s"] >= 0 for r in rows)
        assert rows[0]["horizon_s"] == pytest.approx(rows[1]["horizon_s"])  # same horizon, other steps
    paths = sweeps.FIGURES[study](rows, tmp_path / "figures")
    assert paths and all(p.stat().st_size > 5_000 for p in paths)


def test_robustness_study_grids():
    full = sweeps.STUDIES["robustness"][0](False)
    # 11 magnitudes (0 to 1.0 m/s) x 2 directions x 8 phases x delay off/on x 3 seeds
    assert len(full) == 11 * 2 * 8 * 2 * 3
    assert sorted({c["magnitude"] for c in full}) == [round(0.1 * i, 1) for i in range(11)]
    assert sorted({c["phase"] for c in full}) == [i / 8 for i in range(8)]
    quick = sweeps.STUDIES["robustness"][0](True)
    assert 0 < len(quick) <= 8 and all(c["quick"] for c in quick)
