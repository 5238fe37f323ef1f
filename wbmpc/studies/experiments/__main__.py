"""``python -m wbmpc.studies.experiments``: see :mod:`wbmpc.studies.experiments.cli`."""

from wbmpc.studies.experiments.cli import main

main()
