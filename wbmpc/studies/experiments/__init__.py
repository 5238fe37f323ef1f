"""The simulation experiments of the paper (and the simulated counterparts of its hardware tasks) in PyBullet.

Each experiment is a function ``name(quick=None, progress=True, log_dir=None) -> ExperimentResult`` that
builds the MPC, runs the closed loop(s) in PyBullet, and returns the key numbers (``result.summary``, JSON
ready), the runs (logs) and a paper-style figure (``result.figure``). The command

    python -m wbmpc.studies.experiments                      # all, full runs -> data/results/sim/<name>.json
    python -m wbmpc.studies.experiments wiping --quick       # one, quick mode -> data/output/sim/<name>.json

writes the summaries, the figures (``data/output/sim/<name>.png``) and the columnar logs
(``data/output/sim/logs/<name>_<run>.npz``, see :mod:`wbmpc.io.logs`).

Full runs use the compiled Fatrop solver and 15 nodes; quick mode (``WBMPC_QUICK=1``) uses the in-process
solver, 10 nodes and about a second of simulated time, enough to check each experiment's key outcome.

==========================  ===================  ========================================================
experiment                  module               what it does
==========================  ===================  ========================================================
``arm_tracking``            ``tracking``         trot at 0.2 m/s while the end effector reaches low and high
``disturbance_rejection``   ``kicks``            0.8 m/s lateral base kick while trotting in place, at two
                                                 gait phases
``pulling_load``            ``pulling``          drag a tethered load with a commanded force: stance,
                                                 walking, max load
``box_pushing``             ``pushing``          push a box against a wall with a force target while
                                                 trotting in place
``wiping``                  ``wipe``             wipe a vertical board with a normal-force target while
                                                 standing
``compliance``              ``compliant_arm``    zero arm targets, low arm gains: a push moves the arm,
                                                 which yields
``time_steps_drift``        ``drift``            adaptive vs uniform time steps with computation delay:
                                                 base drift
``robustness_sweep``        ``sweep``            success over kick magnitudes and gait phases (a benchmark)
==========================  ===================  ========================================================

Shared helpers are in ``common`` (the MPC set-up and cache, the loop's defaults), writing the results in
``output`` (:func:`save`, :func:`replay_html`), the command line and :data:`EXPERIMENTS` in ``cli``.
"""

from wbmpc.studies.experiments.cli import EXPERIMENTS, main
from wbmpc.studies.experiments.common import GAIT_PERIOD, REPO_ROOT, ExperimentResult
from wbmpc.studies.experiments.compliant_arm import compliance
from wbmpc.studies.experiments.drift import time_steps_drift
from wbmpc.studies.experiments.kicks import disturbance_rejection
from wbmpc.studies.experiments.output import replay_html, save
from wbmpc.studies.experiments.pulling import pulling_load
from wbmpc.studies.experiments.pushing import box_pushing
from wbmpc.studies.experiments.sweep import robustness_sweep
from wbmpc.studies.experiments.tracking import arm_tracking
from wbmpc.studies.experiments.wipe import wiping

__all__ = [
    "EXPERIMENTS",
    "GAIT_PERIOD",
    "REPO_ROOT",
    "ExperimentResult",
    "arm_tracking",
    "box_pushing",
    "compliance",
    "disturbance_rejection",
    "main",
    "pulling_load",
    "replay_html",
    "robustness_sweep",
    "save",
    "time_steps_drift",
    "wiping",
]
