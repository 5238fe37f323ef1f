"""Generated NLP functions: exact derivatives, node-independent code size, compiled solve, cache."""

import casadi as ca
import numpy as np
import pytest

from wbmpc import codegen
from wbmpc.gait import make_gait
from wbmpc.mpc import MPCConfig, WholeBodyMPC
from wbmpc.ocp import OCP, OCPSettings
from wbmpc.robot import load_b1, load_b1_z1

FLAGS = ("-O0",)  # quick to compile in CI; the benchmark uses the default -O1


@pytest.fixture(scope="module")
def small_ocp():
    return OCP(load_b1(), OCPSettings(n_nodes=3, n_tau_nodes=1))


def test_generated_functions_equal_casadi_derivatives():
    """Each assembled function equals what CasADi derives from the monolithic symbolic NLP."""
    ocp = OCP(load_b1_z1(), OCPSettings(n_nodes=5, n_tau_nodes=2))
    functions = {f.name(): f for f in codegen.nlp_functions(ocp)}
    x, p = ocp.nlp["x"], ocp.nlp["p"]
    lam_f, lam_g = ca.SX.sym("lam_f"), ca.SX.sym("lam_g", ocp.n_constraints)
    lagrangian = lam_f * ocp.nlp["f"] + ca.dot(lam_g, ocp.nlp["g"])
    reference = ca.Function(
        "reference",
        [x, p, lam_f, lam_g],
        [
            ocp.nlp["f"],
            ocp.nlp["g"],
            ca.gradient(ocp.nlp["f"], x),
            ca.jacobian(ocp.nlp["g"], x),
            ca.gradient(lagrangian, x),
            ca.hessian(lagrangian, x)[0],
            ca.gradient(lagrangian, p),
        ],
    )
    rng = np.random.default_rng(0)
    xv = 0.05 * rng.normal(size=ocp.n_variables)
    pv = ocp.params.pack(
        {
            name: rng.uniform(0.01, 0.1, size=shape)
            if name in ("dt_min", "dt_max")
            else rng.normal(size=shape)
            for name, (_, shape) in ocp.params.blocks.items()
        }
    )
    pv[ocp.params.blocks["q_hat"][0] + 3 : ocp.params.blocks["q_hat"][0] + 7] = [0, 0, 0, 1]
    lf, lg = 0.7, rng.normal(size=ocp.n_constraints)
    f, g, grad_f, jac_g, grad_l, hess_l, grad_p = (np.array(v) for v in reference(xv, pv, lf, lg))

    def close(a, b):
        np.testing.assert_allclose(np.array(a), b, atol=1e-9 * max(1.0, np.abs(b).max()))

    close(functions["nlp_f"](xv, pv), f)
    close(functions["nlp_g"](xv, pv), g)
    close(functions["nlp_grad_f"](xv, pv), grad_f)
    close(ca.densify(functions["nlp_jac_g"](xv, pv)[1]), jac_g)
    gx, hx = functions["nlp_hess_l"](xv, pv, lf, lg)
    close(gx, grad_l)
    close(ca.densify(hx), hess_l)
    close(functions["nlp_grad"](xv, pv, lf, lg)[3], grad_p)


def test_stage_code_is_not_repeated_per_node(tmp_path):
    robot = load_b1()
    sizes = []
    for n_nodes in (4, 12):
        generator = ca.CodeGenerator(f"nlp_{n_nodes}.c")
        for function in codegen.nlp_functions(OCP(robot, OCPSettings(n_nodes=n_nodes, n_tau_nodes=2))):
            generator.add(function)
        generator.generate(str(tmp_path) + "/")
        sizes.append((tmp_path / f"nlp_{n_nodes}.c").stat().st_size)
    # Only per-node calls and sparsity patterns grow (~40 kB/node); a stage's code (~1.5 MB) is not copied.
    per_node = (sizes[1] - sizes[0]) / 8
    assert per_node < 0.02 * sizes[0], sizes


def test_compiled_solver_matches_in_process(shared_cache, monkeypatch):
    monkeypatch.setenv("WBMPC_CACHE_DIR", str(shared_cache))
    robot = load_b1()
    settings = OCPSettings(n_nodes=3, n_tau_nodes=1)
    plans = []
    for compiled in (False, True):
        config = MPCConfig(gait=make_gait("stand"), compiled=compiled, compile_flags=FLAGS, dt_max=0.02)
        mpc = WholeBodyMPC(robot, settings, config)
        mpc.verbose = False
        plans.append(mpc.solve(robot.q_nominal, np.zeros(robot.nv)))
    in_process, compiled = plans
    assert in_process.success and compiled.success
    assert compiled.iterations == in_process.iterations
    np.testing.assert_allclose(compiled.w, in_process.w, atol=1e-8)
    stats = mpc._solver(cold=True).stats()
    assert list(stats["nu"]) == mpc.ocp.stage_sizes()["nu"]  # Fatrop found the stages in the library too


def test_cache_reuses_rebuilds_on_change_and_survives_truncation(small_ocp, tmp_path):
    first = codegen.build(small_ocp, FLAGS, directory=tmp_path, progress=False)
    assert first.rebuilt and first.library.is_file()
    again = codegen.build(small_ocp, FLAGS, directory=tmp_path, progress=False)
    assert not again.rebuilt and again.library == first.library
    # A truncated library (e.g. a killed copy) is detected by its checksum and rebuilt.
    data = first.library.read_bytes()
    first.library.write_bytes(data[: len(data) // 2])
    repaired = codegen.build(small_ocp, FLAGS, directory=tmp_path, progress=False)
    assert repaired.rebuilt and repaired.library.read_bytes() != data[: len(data) // 2]
    ca.external("nlp_hess_l", str(repaired.library))
    # Anything that changes the generated code changes the key.
    key_flags, _ = codegen.cache_key(small_ocp, ("-O2",))
    key_nodes, _ = codegen.cache_key(OCP(load_b1(), OCPSettings(n_nodes=4, n_tau_nodes=1)), FLAGS)
    assert len({first.key, key_flags, key_nodes}) == 3


def test_compiled_needs_fatrop():
    with pytest.raises(ValueError, match="compiled needs solver='fatrop'"):
        MPCConfig(solver="ipopt", compiled=True)
