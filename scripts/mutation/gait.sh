# shellcheck shell=bash disable=SC2034
# wbmpc/ocp/gait.py, ~4 min on one core. The closed loops and end-to-end runs cover the gait too but take
# minutes per mutant (and tests/test_commands.py is mostly closed loops): left out by the -k selection.
module="wbmpc/ocp/gait.py"
tests=(tests/test_gait.py tests/test_contact_schedule.py tests/test_bad_inputs.py tests/test_demo_cli.py)
select="not closed_loop and not swing_feet_out and not transitions_on_mpc_ticks and not holds_until and not failing_loop and not failed_first_solve and not hold_still and not stand_segment_stands_still and not heading_frame_carries and not world_fixed_hand and not hand_moving and not end_to_end and not no_work_guard"
names=()
