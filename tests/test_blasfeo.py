"""The BLASFEO under Fatrop: native and generic give the same solves, the mapped library is the reported one,
bad settings fail clearly, a missing native file falls back to the generic library with one line.

Each case runs in a fresh subprocess: a process holds one BLASFEO, chosen at the first import of
``wbmpc.solver``.
"""

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from wbmpc.solver import blasfeo

NATIVE_OK = blasfeo.native_supported()[0] and not blasfeo.check_native_file()
NATIVE_SKIP = "native BLASFEO unusable here: " + (
    blasfeo.native_supported()[1] or blasfeo.check_native_file() or ""
)
needs_native = pytest.mark.skipif(not NATIVE_OK, reason=NATIVE_SKIP)

# A warm-started closed-loop-like sequence: 10 ticks of 12.5 ms, trot, each measurement the plan's next node.
SOLVES = textwrap.dedent(
    """
    import json, sys
    import numpy as np
    from wbmpc.solver import blasfeo
    from wbmpc.ocp.gait import make_gait
    from wbmpc.control.mpc import MPCConfig, WholeBodyMPC
    from wbmpc.ocp import OCPSettings
    from wbmpc.model.robot import load_b1_z1

    robot = load_b1_z1()
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=6), MPCConfig(gait=make_gait("trot")))
    mpc.verbose = False
    q, v = robot.q_nominal, np.zeros(robot.nv)
    iterations, solutions = [], []
    for k in range(10):
        plan = mpc.solve(q, v, t=0.0125 * k)
        assert plan.success, plan.status
        iterations.append(plan.iterations)
        solutions.append(plan.w)
        q, v = plan.q[1], plan.v[1]
    np.save(sys.argv[1], np.array(solutions))
    mapped = blasfeo.mapped_libraries()
    print(json.dumps({"iterations": iterations, "info": blasfeo.info(), "mapped": mapped}))
    """
)

# Load the Fatrop plugin with a tiny problem, then report.
TINY = textwrap.dedent(
    """
    import json
    import casadi as ca
    from wbmpc.solver import blasfeo
    x = ca.MX.sym("x", 2)
    options = {"print_time": False, "fatrop": {"print_level": 0}}
    ca.nlpsol("s", "fatrop", {"x": x, "f": ca.sumsqr(x - 1)}, options)
    print(json.dumps({"info": blasfeo.info(), "mapped": blasfeo.mapped_libraries()}))
    """
)


def run(code: str, *args: str, **env: str) -> subprocess.CompletedProcess:
    environ = {k: v for k, v in os.environ.items() if k != blasfeo.ENV}
    return subprocess.run(
        [sys.executable, "-c", code, *args], env=environ | env, capture_output=True, text=True, timeout=600
    )


def report(proc: subprocess.CompletedProcess) -> dict:
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


@needs_native
def test_native_and_generic_give_identical_iterations_and_solutions(tmp_path):
    results = {}
    for choice in blasfeo.CHOICES:
        path = tmp_path / f"{choice}.npy"
        out = report(run(SOLVES, str(path), WBMPC_BLASFEO=choice))
        assert out["info"]["choice"] == choice
        assert out["info"]["fatrop_loaded"] and out["mapped"] == [out["info"]["library"]]
        results[choice] = (out["iterations"], np.load(path))
    (it_native, w_native), (it_generic, w_generic) = results["native"], results["generic"]
    assert it_native == it_generic
    np.testing.assert_allclose(w_native, w_generic, rtol=0, atol=1e-9)


@pytest.mark.parametrize("choice", [pytest.param("native", marks=needs_native), pytest.param("generic")])
def test_the_mapped_library_is_the_reported_one(choice):
    out = report(run(TINY, WBMPC_BLASFEO=choice))
    info = out["info"]
    assert info["choice"] == choice and info["fatrop_loaded"]
    assert out["mapped"] == [info["library"]], "exactly one BLASFEO, the reported one"
    if choice == "native":
        assert os.path.samefile(info["library"], blasfeo.native_path())
        assert info["target"] == blasfeo.NATIVE_TARGET and "AVX2" in info["library_features"]
    else:
        assert os.path.samefile(info["library"], blasfeo.generic_path())
        assert info["target"] == "GENERIC"


def test_an_invalid_choice_raises_a_clear_error():
    proc = run("import wbmpc.solver", WBMPC_BLASFEO="fast")
    assert proc.returncode != 0
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("ValueError") and "WBMPC_BLASFEO" in last
    assert "native" in last and "generic" in last


def test_a_missing_native_file_falls_back_to_generic_with_one_line(tmp_path):
    missing = tmp_path / "absent" / "libblasfeo.so.0"
    proc = run(TINY, WBMPC_BLASFEO="native", WBMPC_BLASFEO_PATH=str(missing))
    info = report(proc)["info"]
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, lines
    assert (
        "generic" in lines[0]
        and str(missing) in lines[0]
        and "python -m wbmpc.solver.blasfeo fetch" in lines[0]
    )
    assert info["choice"] == "generic" and info["mapped_count"] == 1
    assert os.path.samefile(info["library"], blasfeo.generic_path())


def test_a_corrupt_native_file_is_refused(tmp_path):
    corrupt = tmp_path / "libblasfeo.so.0"
    corrupt.write_bytes(b"not a library")
    assert "sha256" in blasfeo.check_native_file(corrupt)
    # Under the default (no WBMPC_BLASFEO) a corrupt file is worth the line too; a missing one is not.
    proc = run(TINY, WBMPC_BLASFEO_PATH=str(corrupt))
    assert report(proc)["info"]["choice"] == "generic"
    assert "sha256" in proc.stderr and "fetch" in proc.stderr
    proc = run(TINY, WBMPC_BLASFEO_PATH=str(tmp_path / "absent.so"))
    assert report(proc)["info"]["choice"] == "generic" and proc.stderr.strip() == ""


@needs_native
def test_bench_compares_both_libraries_in_one_interleaved_run(tmp_path):
    from wbmpc.studies import bench

    output = tmp_path / "blasfeo.json"
    argv = ["--quick", "--steps", "4", "--warmup", "1", "--batch", "2", "--blasfeo", "both"]
    records = bench.main([*argv, "--output", str(output), "--quiet"])
    assert json.loads(output.read_text()) == json.loads(json.dumps(records))
    assert [(r["solver"], r["blasfeo_variant"]) for r in records] == [
        ("fatrop", "native"),
        ("fatrop", "generic"),
    ]
    for record in records:
        assert record["blasfeo"]["choice"] == record["blasfeo_variant"]
        assert record["blasfeo"]["mapped_count"] == 1
        assert record["cpu_model"] and record["cpu_flags"]["avx2"]
        comparison = record["blasfeo_comparison"]
        assert comparison["iterations_identical"] and comparison["max_abs_solution_diff"] < 1e-9
