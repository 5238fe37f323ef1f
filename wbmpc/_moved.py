"""Old flat module paths (``wbmpc.mpc``, ``wbmpc.robot``, ...) as aliases of their new homes.

The package is grouped into subpackages along the data flow; code written against the flat layout keeps
working: ``import wbmpc.mpc`` returns the very module object ``wbmpc.control.mpc`` (no second copy, so
classes stay identical), and ``python -m wbmpc.demo`` runs ``wbmpc.studies.demo``.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys

MOVED = {
    "wbmpc.robot": "wbmpc.model.robot",
    "wbmpc.statics": "wbmpc.model.statics",
    "wbmpc.gait": "wbmpc.ocp.gait",
    "wbmpc.time_grid": "wbmpc.ocp.time_grid",
    "wbmpc.formulations": "wbmpc.ocp.formulations",
    "wbmpc.codegen": "wbmpc.solver.codegen",
    "wbmpc.deploy": "wbmpc.solver.deploy",
    "wbmpc.blasfeo": "wbmpc.solver.blasfeo",
    "wbmpc.mpc": "wbmpc.control.mpc",
    "wbmpc.low_level": "wbmpc.control.low_level",
    "wbmpc.arm_task": "wbmpc.control.arm_task",
    "wbmpc.diagnostics": "wbmpc.control.diagnostics",
    "wbmpc.plant": "wbmpc.sim.plant",
    "wbmpc.pybullet_sim": "wbmpc.sim.pybullet_plant",
    "wbmpc.closed_loop": "wbmpc.sim.closed_loop",
    "wbmpc.disturbances": "wbmpc.sim.disturbances",
    "wbmpc.sensing": "wbmpc.sim.sensing",
    "wbmpc.logs": "wbmpc.io.logs",
    "wbmpc.plots": "wbmpc.viz.plots",
    "wbmpc.demo": "wbmpc.studies.demo",
    "wbmpc.bench": "wbmpc.studies.bench",
    "wbmpc.table1": "wbmpc.studies.table1",
    "wbmpc.experiments": "wbmpc.studies.experiments",
}


class _AliasLoader(importlib.abc.Loader):
    def __init__(self, target: str):
        self.target = target

    def create_module(self, spec):
        return importlib.import_module(self.target)

    def exec_module(self, module) -> None:
        pass  # the target module is already executed

    def get_code(self, fullname):  # ``python -m wbmpc.demo`` runs the target's code as __main__
        return importlib.util.find_spec(self.target).loader.get_code(self.target)


class _AliasFinder(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname, path=None, target=None):
        if fullname not in MOVED:
            return None
        target = importlib.util.find_spec(MOVED[fullname])  # its file: ``__file__`` under ``python -m``
        return importlib.util.spec_from_loader(fullname, _AliasLoader(MOVED[fullname]), origin=target.origin)


def install() -> None:
    """Put the alias finder on ``sys.meta_path`` (once)."""
    if not any(isinstance(f, _AliasFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, _AliasFinder())
