# shellcheck shell=bash disable=SC2034
# wbmpc/ocp/builder.py (the OCP builder) with the tests that build small OCPs (3 to 8 nodes) and solve them
# in process (no compiled solver); not tests/test_bad_inputs.py (it builds OCPs by the dozen and checks no
# row value). Left out by the -k selection, seconds to minutes per mutant: the closed loops, the IPOPT
# comparison, the 15-node standing problem of test_mpc (its structure, convergence and physics are checked on 7 nodes by test_formulations), the 8-node node-0 comparison, and the formulations
# other than inverse_dynamics and centroidal_velocity (which covers the velocity-level branches).
# All 1274 mutants take hours on one core: docs/mutation/builder_mpc.md runs the functions with the rows,
# the cost and the applied forces (names: stage_terms, _unit_rows, applied_forces).
module="wbmpc/ocp/builder.py"
tests=(tests/test_friction_cone.py tests/test_mpc.py
    tests/test_formulations.py tests/test_builder_mutation_gaps.py)
select="not closed_loop and not pybullet and not ipopt_agrees and not short_trot and not real_iteration_cap and not node0_state_as_parameter_gives and not decision_variables_match and not fatrop_detects_the_stage_structure and not cold_start_converges and not solution_satisfies_rnea and not centroidal_acceleration and not forward_dynamics and not nobase and not generated_functions and not (node0_state_as_parameter_is_the_same_problem and centroidal_velocity)"
names=()
