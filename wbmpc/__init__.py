"""wbmpc: whole-body inverse-dynamics MPC for a quadruped with an arm (Pinocchio + CasADi + Fatrop)."""

from wbmpc.quick import pick, quick_mode

__version__ = "0.1.0"

__all__ = ["__version__", "pick", "quick_mode"]
