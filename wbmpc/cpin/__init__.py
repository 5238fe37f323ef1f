"""``wbmpc.cpin``: a small CasADi (SX) mirror of the Pinocchio algorithms the MPC needs.

The pip wheels of Pinocchio ship without ``pinocchio.casadi``, so wbmpc builds the symbolic expressions
itself from a numeric :class:`pinocchio.Model`, with the same names and conventions, and tests every
algorithm against numeric Pinocchio at random states.

Example:
    >>> import casadi as ca
    >>> from wbmpc import cpin
    >>> smodel = cpin.SymbolicModel(robot.model)
    >>> q, v, a = ca.SX.sym("q", smodel.nq), ca.SX.sym("v", smodel.nv), ca.SX.sym("a", smodel.nv)
    >>> tau = cpin.rnea(smodel, q, v, a, {"FL_foot": ca.SX.sym("f", 3)})
"""

from wbmpc.cpin.aba import aba, aba_function
from wbmpc.cpin.centroidal import (
    centroidal_base_acceleration,
    centroidal_base_velocity,
    centroidal_map,
    centroidal_map_time_variation,
    centroidal_momentum,
    centroidal_momentum_rate,
    generalized_gravity,
    static_torque_estimate,
)
from wbmpc.cpin.crba import crba
from wbmpc.cpin.kinematics import (
    LOCAL,
    LOCAL_WORLD_ALIGNED,
    WORLD,
    Motion,
    SymbolicData,
    center_of_mass,
    forward_kinematics,
    frame_placement,
    frame_velocity,
)
from wbmpc.cpin.liegroups import difference, integrate, integrate_base
from wbmpc.cpin.model import SymbolicModel
from wbmpc.cpin.rnea import rnea, rnea_function

__all__ = [
    "aba",
    "aba_function",
    "centroidal_base_acceleration",
    "centroidal_base_velocity",
    "centroidal_map",
    "centroidal_map_time_variation",
    "centroidal_momentum",
    "centroidal_momentum_rate",
    "crba",
    "generalized_gravity",
    "static_torque_estimate",
    "LOCAL",
    "LOCAL_WORLD_ALIGNED",
    "WORLD",
    "Motion",
    "SymbolicData",
    "SymbolicModel",
    "center_of_mass",
    "difference",
    "forward_kinematics",
    "frame_placement",
    "frame_velocity",
    "integrate",
    "integrate_base",
    "rnea",
    "rnea_function",
]
