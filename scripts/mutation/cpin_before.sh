# shellcheck shell=bash disable=SC2034
# wbmpc/cpin/ with the tests as they were before tests/test_cpin_mutation_gaps.py (the "before" row of
# docs/mutation/cpin.md): bash scripts/mutation.sh cpin_before
# shellcheck disable=SC1091
source "$(dirname "${BASH_SOURCE[0]}")/cpin.sh"
tests=(tests/test_cpin.py tests/test_cpin_dynamics.py)
