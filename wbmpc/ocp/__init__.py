"""The optimal control problem: gait schedules, the time grid, dynamics formulations, the one builder.

The names of the former module ``wbmpc.ocp`` are re-exported here from ``wbmpc.ocp.builder``.
"""

from wbmpc.ocp.builder import (
    MAX_NODES,
    OCP,
    OCPSettings,
    ParameterLayout,
    StageInfo,
)

__all__ = [
    "MAX_NODES",
    "OCP",
    "OCPSettings",
    "ParameterLayout",
    "StageInfo",
]
