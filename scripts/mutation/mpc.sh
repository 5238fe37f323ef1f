# shellcheck shell=bash disable=SC2034
# wbmpc/control/mpc.py (parameters, warm and cold starts, the failed-solve rule) with the tests that solve
# small problems (4 to 8 nodes) in process (no compiled solver): the failure, cold-retry and iteration-cap
# tests of test_mpc, the static hold, the bad inputs, tests/test_mpc_mutation_gaps.py. Left out by -k, seconds
# to minutes per mutant: the closed-loop trots, the PyBullet run, the IPOPT comparison, the 15-node standing
# problem (its module fixture alone takes 5 s), the node-0 comparisons and tests/test_formulations.py.
# All 1368 mutants take hours on one core: run them by function name (docs/mutation/builder_mpc.md: solve,
# shifted_guess; builder_build_mpc_rest.md: hold_plan, pose_at_height, part of _run_solver; what was not run).
module="wbmpc/control/mpc.py"
tests=(tests/test_bad_inputs.py tests/test_static_hold.py tests/test_friction_cone.py tests/test_mpc.py
    tests/test_mpc_mutation_gaps.py)
select="not closed_loop_trot and not pybullet and not ipopt_agrees and not node0_state_as_parameter_gives and not decision_variables_match and not fatrop_detects_the_stage_structure and not cold_start_converges and not solution_satisfies_rnea"
names=()
