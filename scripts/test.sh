#!/usr/bin/env bash
# Whole test suite in quick mode (what CI runs via .ci/run): unit tests + every notebook via nbmake.
# Extra args go to pytest, e.g.  bash scripts/test.sh -k quick   or   bash scripts/test.sh -x
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"   # cd's to the repo root and activates .venv

export WBMPC_QUICK=1
export MPLBACKEND=Agg

paths=(tests)
# Only pass notebooks/ if it exists, otherwise pytest errors with "file or directory not found".
if [ -d notebooks ]; then
    paths+=(notebooks)
fi

exec python -m pytest "${paths[@]}" --nbmake --nbmake-timeout=600 -p no:cacheprovider -q "$@"
