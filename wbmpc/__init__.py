"""wbmpc: whole-body inverse-dynamics MPC for a quadruped with an arm (Pinocchio + CasADi + Fatrop)."""

from wbmpc import blasfeo
from wbmpc.quick import pick, quick_mode

blasfeo.activate()  # choose the process's BLASFEO before casadi opens its Fatrop plugin

__version__ = "0.1.0"

__all__ = ["__version__", "pick", "quick_mode"]
