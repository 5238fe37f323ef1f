"""``python -m wbmpc.studies.sweeps``: see :mod:`wbmpc.studies.sweeps.cli`."""

from wbmpc.studies.sweeps.cli import main

if __name__ == "__main__":
    main()
