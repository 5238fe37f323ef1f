# shellcheck shell=bash
# Source me (bash):  source scripts/env.sh
#
# cd's to the repo root, creates .venv there if missing, installs environment.txt and the wbmpc
# package (editable, --no-deps) when environment.txt or pyproject.toml changed since the last
# install (sha256 stamp in .venv/.wbmpc-stamp), fetches the native BLASFEO for Fatrop once
# (.venv/lib/wbmpc-blasfeo/, see wbmpc/solver/blasfeo.py), then activates .venv.
# Works from any cwd. Set WBMPC_PYTHON to choose the interpreter that creates the venv.

_wbmpc_env_setup() {
    local root venv stamp_file stamp py
    root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)" || return 1
    cd "$root" || return 1
    venv="$root/.venv"
    stamp_file="$venv/.wbmpc-stamp"
    py="${WBMPC_PYTHON:-python3}"

    if [ ! -x "$venv/bin/python" ] || [ ! -f "$venv/bin/activate" ]; then
        echo "[env.sh] creating $venv with $("$py" --version 2>&1)" >&2
        rm -rf "$venv"
        "$py" -m venv "$venv" || { echo "[env.sh] ERROR: python3 -m venv failed" >&2; return 1; }
    fi

    stamp="$(cat environment.txt pyproject.toml | sha256sum | cut -d' ' -f1)" || return 1
    if [ ! -f "$stamp_file" ] || [ "$(cat "$stamp_file")" != "$stamp" ]; then
        echo "[env.sh] installing environment.txt and wbmpc (editable) into .venv ..." >&2
        rm -f "$stamp_file"
        "$venv/bin/python" -m pip install -q -r environment.txt \
            || { echo "[env.sh] ERROR: pip install -r environment.txt failed" >&2; return 1; }
        "$venv/bin/python" -m pip install -q -e . --no-deps \
            || { echo "[env.sh] ERROR: pip install -e . failed" >&2; return 1; }
        echo "$stamp" > "$stamp_file"
        echo "[env.sh] done" >&2
    fi

    # Native (AVX2/FMA) BLASFEO for Fatrop, see wbmpc/solver/blasfeo.py: fetched once, skipped while the file is
    # present with the checksum recorded there. A failure (e.g. offline) only leaves casadi's generic one.
    if [ "$(uname -s)-$(uname -m)" = "Linux-x86_64" ]; then
        local native want err
        native="${WBMPC_BLASFEO_PATH:-$venv/lib/wbmpc-blasfeo/libblasfeo.so.0}"
        want="$(sed -n 's/^NATIVE_SHA256 = "\([0-9a-f]*\)".*/\1/p' wbmpc/solver/blasfeo.py)"
        if [ ! -f "$native" ] || [ "$(sha256sum "$native" | cut -d' ' -f1)" != "$want" ]; then
            if err="$("$venv/bin/python" -m wbmpc.solver.blasfeo fetch --quiet 2>&1)"; then
                echo "[env.sh] fetched the native BLASFEO for Fatrop: $native" >&2
            else
                echo "[env.sh] native BLASFEO not fetched (${err##*$'\n'}); Fatrop uses casadi's generic one" >&2
            fi
        fi
    fi

    # shellcheck disable=SC1091
    source "$venv/bin/activate" || return 1
}

_wbmpc_env_setup
_wbmpc_env_rc=$?
unset -f _wbmpc_env_setup
if [ "$_wbmpc_env_rc" -ne 0 ]; then
    unset _wbmpc_env_rc
    return 1 2>/dev/null || exit 1
fi
unset _wbmpc_env_rc
