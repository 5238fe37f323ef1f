"""wbmpc: whole-body inverse-dynamics MPC for a quadruped with an arm (Pinocchio + CasADi + Fatrop).

Subpackages follow the data flow: ``model`` (robots) -> ``cpin`` (symbolic dynamics) -> ``ocp`` (gait,
time grid, formulations, the builder) -> ``solver`` (code generation, deployment, BLASFEO) -> ``control``
(the MPC, diagnostics, low level) -> ``estimation`` / ``sim`` (estimator; plants and the closed loop) ->
``io`` (logs, ROS 2 bags) -> ``viz`` (viewer, figures); ``studies`` holds the command lines (demo,
benchmarks, Table I, experiments, sweeps). The flat module paths of earlier versions (``wbmpc.mpc``,
``wbmpc.robot``, ``python -m wbmpc.demo``, ...) still work (:mod:`wbmpc._moved`).
"""

from wbmpc import _moved
from wbmpc.quick import pick, quick_mode
from wbmpc.solver import blasfeo

_moved.install()
blasfeo.activate()  # choose the process's BLASFEO before casadi opens its Fatrop plugin

__version__ = "0.1.0"

__all__ = ["__version__", "pick", "quick_mode"]
