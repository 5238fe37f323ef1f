"""A direct primal-dual warm-started Fatrop driver (issue 22): Fatrop's C++ OCP interface over the OCP's own
compiled stage functions, built at set-up against the casadi wheel's Fatrop 1.1.8 headers and libraries.

* :mod:`wbmpc.solver.direct.problem`: the stage functions in Fatrop's ``(u_k, x_k)`` layout and the maps
  between Fatrop's and the NLP's variables, rows and multipliers;
* :mod:`wbmpc.solver.direct.build`: generation, compilation and the cache;
* :mod:`wbmpc.solver.direct.driver`: :class:`DirectFatrop`, the ctypes front of ``fatrop_direct.cpp``.
"""

from wbmpc.solver.direct.driver import DirectFatrop, DirectResult

__all__ = ["DirectFatrop", "DirectResult"]
