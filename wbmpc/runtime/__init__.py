"""Driving a robot on the wall clock: the robot protocol, the 500 Hz controller, the MPC worker, DDS.

Everything else in wbmpc advances in simulated time. This subpackage runs the same controller against a
robot that answers on its own clock: :mod:`wbmpc.runtime.robot` (the protocol every robot implements),
:mod:`wbmpc.runtime.messages` and :mod:`wbmpc.runtime.dds` (the Unitree low-level wire format over DDS),
:mod:`wbmpc.runtime.shared` (latest-only plan and observation slots in shared memory),
:mod:`wbmpc.runtime.clock` (absolute deadlines on the monotonic clock), :mod:`wbmpc.runtime.watchdog`
and :mod:`wbmpc.runtime.metrics`.
"""
