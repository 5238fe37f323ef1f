# shellcheck shell=bash disable=SC2034
# The CasADi mirror of Pinocchio, wbmpc/cpin/ (every module: a glob, which mutmut's only_mutate accepts),
# against numeric Pinocchio, finite differences and physical invariants (docs/mutation/cpin.md).
# One module at a time: bash scripts/mutation.sh cpin 'wbmpc.cpin.rnea.*'
module="wbmpc/cpin/*"
tests=(tests/test_cpin.py tests/test_cpin_dynamics.py tests/test_cpin_mutation_gaps.py)
select="not closed_loop"  # every test of these files: seconds in all (instruction budgets included)
names=()
# tests/test_cpin_dynamics.py builds its CasADi functions once per robot (functools.cache): with mutmut's
# default fork isolation they would be built by the clean run, unmutated, and inherited by every mutant.
isolation="forkserver"
