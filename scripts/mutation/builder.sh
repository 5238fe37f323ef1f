# shellcheck shell=bash disable=SC2034
# wbmpc/ocp/builder.py (the OCP builder) with the tests that evaluate its rows, cost and plan function
# directly (tests/test_builder_mutation_gaps.py, tests/test_friction_cone.py, 3 to 4 nodes) and the small
# in-process solves of test_mpc (8-node trot, arm force as parameter, limit rows, injected failures).
# Left out, seconds to minutes per mutant: tests/test_bad_inputs.py (it builds OCPs by the dozen and checks
# no row value), tests/test_formulations.py (module fixtures that solve every formulation, paid again in
# every mutant's process), the closed loops, the IPOPT comparison, the 15-node standing problem.
# All 1275 mutants take hours on one core: run them by function name (docs/mutation/builder_mpc.md: stage_terms,
# applied_forces; builder.md: the helpers; builder_build_mpc_rest.md: _build, OCPSettings.__post_init__).
module="wbmpc/ocp/builder.py"
tests=(tests/test_builder_mutation_gaps.py tests/test_friction_cone.py tests/test_mpc.py)
select="mutation_gaps or cone or trot_plan_has_zero or limit_rows or arm_force_as_parameter or injected or cold_retry_rescues or unconverged_iterate"
names=()
