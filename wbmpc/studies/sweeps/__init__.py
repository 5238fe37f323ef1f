"""Parameter sweeps on Dask ``distributed``: a grid of cases, one function per case, a tidy CSV table.

A sweep is a list of cases (dicts of parameters, each with a stable ``case_id``, see :func:`grid`) and a
*case function*: a module-level function that takes one case dict and returns a flat dict of results. The
function runs on the workers of a Dask cluster (a :class:`distributed.LocalCluster` with one single-threaded
worker process per core by default, or an existing cluster given by its scheduler address) and every
finished case becomes one row of a CSV table, appended as soon as it completes:

``case_id, <parameters>, <results>, status, error, wall_s, worker``

``status`` is ``"ok"``, ``"fell"`` (the results say ``fell=True``), ``"error"`` (the case raised; ``error``
holds the message) or ``"worker-died"`` (the worker process running the case exited or crashed, e.g.
``os._exit`` or a segfault; the nanny restarts it and the sweep goes on). A case is never retried: the local
scheduler runs with ``allowed-failures=0`` and the tasks with ``retries=0``, so a crashing case kills one
worker once instead of three. Re-running a sweep with the same table skips the cases already in it
(resume); rows cut short by an interrupted write are dropped and rerun.

Example::

    from wbmpc.studies.sweeps import closed_loop_case, grid, heatmap, read_table, run_sweep
    from wbmpc.studies.sweeps import warm_closed_loop_cache

    cases = grid(speed=[0.0, 0.2], yaw_rate=[0.0, 0.2], duration=[0.5])
    run_sweep(cases, closed_loop_case, "data/output/sweeps/trot.csv", warmup=warm_closed_loop_cache)
    heatmap(read_table("data/output/sweeps/trot.csv"), "max_tilt_rad", x="speed", y="yaw_rate")

On an existing cluster (``dask scheduler`` + ``dask worker --nthreads 1`` on each machine, with wbmpc
installed and the same code): pass ``scheduler="tcp://HOST:8786"`` (CLI ``--scheduler``). Start that
scheduler with ``DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES=0`` (as :func:`local_cluster` does), or a
crashing case is retried on up to three workers before it is recorded; the workers should run with
``OMP_NUM_THREADS=1`` etc. The client keeps no more cases in flight than the cluster has worker threads:
the scheduler fails every task assigned to a worker that dies, so no case waits on a worker behind another.

The compiled solver: :func:`wbmpc.solver.codegen.build` serialises builds of one key with a file lock in
the cache
folder, so workers sharing that folder never build the same library twice; ``warmup`` (e.g.
:func:`warm_closed_loop_cache`) runs once on one worker before the cases are submitted, so the library is
built once while no case waits on the lock with a worker tied up.

CLI: ``python -m wbmpc.studies.sweeps --help``.

Modules: :mod:`~wbmpc.studies.sweeps.engine` (grid, table, workers, cluster, :func:`run_sweep`),
:mod:`~wbmpc.studies.sweeps.cases` (case functions and the studies), :mod:`~wbmpc.studies.sweeps.reports`
(heatmaps, robustness and time-step summaries), :mod:`~wbmpc.studies.sweeps.benchmark` (speed-up and
overhead), :mod:`~wbmpc.studies.sweeps.cli`. Everything public is importable from this package.
"""

from wbmpc.studies.sweeps.benchmark import BENCHMARK_CASE, benchmark
from wbmpc.studies.sweeps.cases import (
    DIRECTIONS,
    NOISE,
    ROBUSTNESS_MAGNITUDES,
    ROBUSTNESS_PHASES,
    STUDIES,
    build_case,
    closed_loop_case,
    demo_case,
    nodes_case,
    noop_case,
    payload_case,
    robustness_case,
    time_steps_case,
    warm_build_cache,
    warm_closed_loop_cache,
    warm_experiment_cache,
)
from wbmpc.studies.sweeps.cli import FIGURES, RESULT_STUDIES, main
from wbmpc.studies.sweeps.engine import (
    ID,
    META,
    REPO_ROOT,
    STATUSES,
    THREAD_ENV,
    SweepRun,
    case_id,
    connect,
    execute,
    grid,
    local_cluster,
    read_table,
    run_sweep,
    write_table,
)
from wbmpc.studies.sweeps.reports import (
    committed_table,
    heatmap,
    nodes_figures,
    payload_figures,
    robustness_figures,
    robustness_report,
    time_steps_figures,
    time_steps_summary,
)

__all__ = [
    "committed_table",
    "BENCHMARK_CASE",
    "DIRECTIONS",
    "FIGURES",
    "ID",
    "META",
    "NOISE",
    "REPO_ROOT",
    "RESULT_STUDIES",
    "ROBUSTNESS_MAGNITUDES",
    "ROBUSTNESS_PHASES",
    "STATUSES",
    "STUDIES",
    "THREAD_ENV",
    "SweepRun",
    "benchmark",
    "build_case",
    "case_id",
    "closed_loop_case",
    "connect",
    "demo_case",
    "execute",
    "grid",
    "heatmap",
    "local_cluster",
    "main",
    "nodes_case",
    "nodes_figures",
    "noop_case",
    "payload_case",
    "payload_figures",
    "read_table",
    "robustness_case",
    "robustness_figures",
    "robustness_report",
    "run_sweep",
    "time_steps_case",
    "time_steps_figures",
    "time_steps_summary",
    "warm_build_cache",
    "warm_closed_loop_cache",
    "warm_experiment_cache",
    "write_table",
]
