#!/usr/bin/env bash
# Main job: closed-loop demo on the default robot (B1 + Z1). Extra args go to python -m wbmpc.studies.demo.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"   # cd's to the repo root and activates .venv

exec python -m wbmpc.studies.demo "$@"
