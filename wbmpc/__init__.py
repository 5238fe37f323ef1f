"""wbmpc: whole-body inverse-dynamics MPC for a quadruped with an arm (Pinocchio + CasADi + Fatrop).

Subpackages follow the data flow: ``model`` (robots) -> ``cpin`` (symbolic dynamics) -> ``ocp`` (gait,
time grid, formulations, the builder) -> ``solver`` (code generation, deployment, BLASFEO) -> ``control``
(the MPC, prechecks, low level) -> ``estimation`` / ``sim`` (estimator; plants and the closed loop) ->
``io`` (logs, ROS 2 bags) -> ``viz`` (viewer, figures); ``analysis`` reads a robot's log (solve times, gait
phase, touchdowns, the base CoM); ``studies`` holds the command lines (demo, benchmarks, Table I, experiments,
sweeps).

``import wbmpc`` loads nothing heavy: the BLASFEO under Fatrop is chosen when :mod:`wbmpc.solver` is first
imported (the MPC imports it), before casadi opens its Fatrop plugin.
"""

from wbmpc.quick import pick, quick_mode

__version__ = "0.1.0"

__all__ = ["__version__", "pick", "quick_mode"]
