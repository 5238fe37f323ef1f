# shellcheck shell=bash disable=SC2034
# wbmpc/control/mpc.py (parameters, warm and cold starts, the failed-solve rule) with the tests that solve
# small problems in process (no compiled solver): test_mpc's injected failures, cold retries and the
# iteration cap, the static hold, the bad inputs. Closed loops over seconds of simulated time, the PyBullet
# run, the IPOPT comparison and the formulations other than inverse_dynamics are left out by -k.
module="wbmpc/control/mpc.py"
tests=(tests/test_bad_inputs.py tests/test_static_hold.py tests/test_friction_cone.py tests/test_mpc.py
    tests/test_formulations.py tests/test_mpc_mutation_gaps.py)
select="not closed_loop_trot and not pybullet and not ipopt_agrees and not short_trot and not node0_state_as_parameter_gives and not centroidal and not forward_dynamics and not generated_functions and not node0_state_as_parameter_is_the_same_problem"
names=()
