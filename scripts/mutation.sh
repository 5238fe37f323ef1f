#!/usr/bin/env bash
# Mutation testing of one module with the tests that cover it (docs/mutation_report.md).
#
#   bash scripts/mutation.sh gait                     # wbmpc/ocp/gait.py, ~4 min on one core
#   bash scripts/mutation.sh cache_key                # the cache-key functions of wbmpc/solver/codegen.py
#   bash scripts/mutation.sh gait 'wbmpc.ocp.gait.x_to_ticks*'   # only some mutants (fnmatch on names)
#
# mutmut is not part of environment.txt: install it and what it adds, pinned and checksummed, first:
#   pip install --no-deps --require-hashes -r scripts/mutation-requirements.txt
# It runs in a throwaway copy of the working tree (tracked and untracked, not ignored files), so the
# repository, its pyproject.toml and the venv's editable install stay as they are; one process, niced.
set -euo pipefail
target="${1:-}"
shift || true
repo="$(cd "$(dirname "$0")/.." && pwd)"
# Each target is a file scripts/mutation/<target>.sh that sets: module (the file to mutate), tests (test files),
# select (a pytest -k expression) and names (mutant name patterns, empty for all); optionally isolation
# (mutmut's process_isolation, e.g. forkserver: tests run in children of a process that never ran a test, so
# caches filled by the clean run, such as functools.cache in a test module, do not hide the mutants).
spec="$repo/scripts/mutation/$target.sh"
if [[ -z "$target" || ! -f "$spec" ]]; then
    echo "usage: bash scripts/mutation.sh TARGET [mutant name patterns...]; targets:" \
        "$(cd "$repo/scripts/mutation" && ls ./*.sh | sed 's|^./||; s|\.sh$||' | tr '\n' ' ')" >&2
    exit 2
fi
names=()
isolation=""
# shellcheck disable=SC1090
source "$spec"
if [[ $# -gt 0 ]]; then names=("$@"); fi
source "$repo/.venv/bin/activate"
if ! python -c "import mutmut" 2>/dev/null; then
  echo "mutmut is not installed: pip install --no-deps --require-hashes -r scripts/mutation-requirements.txt" >&2
  exit 2
fi
work="$(mktemp -d "${TMPDIR:-/tmp}/wbmpc-mutation-XXXXXX")"
(cd "$repo" && git ls-files -z -co --exclude-standard | tar --null -T - -cf -) | tar -x -C "$work"
{
  echo "[mutmut]"
  echo "source_paths=wbmpc"
  echo "only_mutate="
  echo "    $module"
  echo "pytest_add_cli_args_test_selection="
  for t in "${tests[@]}"; do echo "    $t"; done
  echo "    -k"
  echo "    $select"
  echo "pytest_add_cli_args="
  echo "    -x"
  echo "    -q"
  echo "    -p"
  echo "    no:cacheprovider"
  if [[ -n "$isolation" ]]; then echo "process_isolation=$isolation"; fi
} > "$work/setup.cfg"
cd "$work"
echo "[mutation] $module in $work"
nice -n 15 mutmut run --max-children 1 "${names[@]}" > mutmut_run.log 2>&1 || { tail -c 3000 mutmut_run.log; exit 1; }
echo "[mutation] survivors and timeouts (mutmut show NAME in $work for the diff):"
mutmut results | grep -Ev ": (killed|checked|not checked)$" || true
