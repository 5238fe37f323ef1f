# shellcheck shell=bash disable=SC2034
# wbmpc/ocp/builder.py (the OCP builder) with the tests that build small OCPs and solve them in process
# (no compiled solver). The closed loops, the IPOPT comparison, the 8-node node-0 comparison of test_mpc and
# the formulations other than inverse_dynamics and centroidal_velocity take seconds to minutes per mutant:
# left out by the -k selection (centroidal_velocity stays: it covers the velocity-level branches).
module="wbmpc/ocp/builder.py"
tests=(tests/test_bad_inputs.py tests/test_friction_cone.py tests/test_static_hold.py tests/test_mpc.py
    tests/test_formulations.py tests/test_builder_mutation_gaps.py)
select="not closed_loop and not pybullet and not ipopt_agrees and not short_trot and not real_iteration_cap and not node0_state_as_parameter_gives and not centroidal_acceleration and not forward_dynamics and not nobase and not generated_functions and not (node0_state_as_parameter_is_the_same_problem and centroidal_velocity)"
names=()
