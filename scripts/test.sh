#!/usr/bin/env bash
# Whole test suite in quick mode (what CI runs via .ci/run): unit tests + every notebook via nbmake.
# Extra args go to pytest, e.g.  bash scripts/test.sh -k quick   or   bash scripts/test.sh -x
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"   # cd's to the repo root and activates .venv

export WBMPC_QUICK=1
export MPLBACKEND=Agg

# Notebooks first: they are the longest files, and the workers share out the short tests after them.
# Only pass notebooks/ if it exists, otherwise pytest errors with "file or directory not found".
paths=()
if [ -d notebooks ]; then
    paths+=(notebooks)
fi
paths+=(tests)

# One pytest worker per core (pytest-xdist), each test file on one worker so that a file's module fixtures
# (an MPC, a compiled solver) are built once. WBMPC_TEST_WORKERS=0 runs in this process.
# Then the wall-clock tests (marker "wallclock": robot, controller and MPC worker as processes; JupyterLab
# and Chromium) in one process with the machine to themselves: a test beside them would take their CPU.
workers="${WBMPC_TEST_WORKERS:-auto}"
status=0
python -m pytest "${paths[@]}" --nbmake --nbmake-timeout=600 -p no:cacheprovider -q \
    -n "$workers" --dist loadfile -m "not wallclock" "$@" || status=$?
wallclock=0
python -m pytest tests -p no:cacheprovider -q -n 0 -m wallclock "$@" || wallclock=$?
if [ "$wallclock" -ne 0 ] && [ "$wallclock" -ne 5 ]; then  # 5: no test selected (e.g. by -k)
    status=$wallclock
fi
exit "$status"
