"""Analysis of a run log that came from a robot: what the hardware did differently.

Every function takes a columnar :class:`~wbmpc.io.logs.RunLog`, typically read from a ROS 2 bag with
:func:`wbmpc.io.rosbag.read_bag`, and uses only what a robot records: joint states (``q``, ``v``, applied
torques ``tau``), the base state of the odometry, the scheduled contacts and the MPC's solve diagnostics.
None of the analyses needs the simulator's contact forces or the emulated robot's profile (the notebook
``05_hardware_log_analysis`` uses them only to check the results).

* :mod:`~wbmpc.analysis.solve_times`: :func:`solve_time_jitter`: solve times against the real-time budget
  (12.5 ms at 80 Hz), histogram data.
* :mod:`~wbmpc.analysis.gait_phase`: :func:`gait_phase`, :func:`phase_profile`, :func:`align_by_phase`: a
  joint signal averaged over gait cycles and compared with a nominal simulation at the same commands.
* :mod:`~wbmpc.analysis.touchdowns`: :func:`detect_touchdowns`: touchdown instants from the jump of a calf's
  joint velocity, against the schedule (a late contact shows as a late spike); :func:`first_contacts`: the
  simulator's contact flag near the same instants (a check).
* :mod:`~wbmpc.analysis.com_identification`: :func:`foot_forces_from_torques`, :func:`identify_com_offset`:
  foot forces from the leg torques through the leg Jacobians, their centre of pressure against the model's
  centre of mass: the base's CoM offset. :func:`wbmpc.model.base_com.shift_base_com` gives the model with that
  offset, for an MPC re-run; :func:`lean` measures the lean (pitch, rear-leg share) before and after.
* :mod:`~wbmpc.analysis.emulated_runs`: :func:`record_emulated_run`, :func:`write_robot_bag`: a
  stand-then-trot run on the emulated robot and its bag with a robot's topics only (how
  ``data/hardware/emulated_b1_stand_trot`` was made).
"""

from wbmpc.analysis.com_identification import (
    ComIdentification,
    foot_forces_from_torques,
    identify_com_offset,
    lean,
    standing_mask,
)
from wbmpc.analysis.emulated_runs import (
    EMULATED_TORQUE_FRACTION,
    ROBOT_TOPICS,
    downsample,
    emulated_mpc,
    record_emulated_run,
    write_robot_bag,
)
from wbmpc.analysis.gait_phase import (
    PhaseAlignment,
    PhaseProfile,
    align_by_phase,
    gait_phase,
    joint_signal,
    phase_profile,
)
from wbmpc.analysis.solve_times import BUDGET_S, SolveJitter, solve_time_jitter
from wbmpc.analysis.touchdowns import Touchdowns, detect_touchdowns, first_contacts

__all__ = [
    "BUDGET_S",
    "EMULATED_TORQUE_FRACTION",
    "ROBOT_TOPICS",
    "ComIdentification",
    "PhaseAlignment",
    "PhaseProfile",
    "SolveJitter",
    "Touchdowns",
    "align_by_phase",
    "detect_touchdowns",
    "downsample",
    "emulated_mpc",
    "first_contacts",
    "foot_forces_from_torques",
    "gait_phase",
    "identify_com_offset",
    "joint_signal",
    "lean",
    "phase_profile",
    "record_emulated_run",
    "solve_time_jitter",
    "standing_mask",
    "write_robot_bag",
]
