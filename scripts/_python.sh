# Sourced by install.sh, test.sh and demo.sh: picks the Python they install into and run, exported as PYTHON.
#
#   1. $PYTHON, when set;
#   2. the active virtual environment (or conda environment) of python3;
#   3. ./.venv, when an earlier run made one;
#   4. python3 itself, when it accepts installs (a pyenv/conda/official-installer Python, a CI image);
#   5. otherwise python3 refuses system-wide installs (PEP 668, "externally-managed-environment": stock
#      Debian/Ubuntu): a new ./.venv is made and used. Activate it later with `. .venv/bin/activate`.
#
# $CYLINDERSPLAT_BASE_PYTHON names another base interpreter than python3.
choose_python() {
    if [ -n "${PYTHON:-}" ]; then
        return 0
    fi
    local base=${CYLINDERSPLAT_BASE_PYTHON:-python3}
    if ! command -v "$base" >/dev/null 2>&1; then
        echo "set-up: $base not found; install Python >= 3.10 (Debian/Ubuntu: apt-get install python3 python3-venv)" >&2
        return 1
    fi
    local kind
    kind=$("$base" -c 'import os, sys, sysconfig
if sys.prefix != sys.base_prefix: print("venv")
elif os.path.isfile(os.path.join(sysconfig.get_path("stdlib"), "EXTERNALLY-MANAGED")): print("managed")
else: print("system")')
    if [ "$kind" != "venv" ] && [ -x "$PWD/.venv/bin/python" ]; then
        PYTHON="$PWD/.venv/bin/python"
    elif [ "$kind" = "managed" ]; then
        if ! "$base" -m venv "$PWD/.venv" >/dev/null 2>&1; then
            rm -rf "$PWD/.venv"
            echo "set-up: $base refuses system-wide installs (PEP 668) and cannot make a virtual environment here:" \
                 "apt-get install python3-venv, or make and activate one yourself (python3 -m venv .venv && . .venv/bin/activate), then run this again" >&2
            return 1
        fi
        echo "set-up: $base refuses system-wide installs (PEP 668), so everything goes into the virtual environment" \
             ".venv (use it later with: . .venv/bin/activate)" >&2
        PYTHON="$PWD/.venv/bin/python"
    else
        PYTHON=$(command -v "$base")
    fi
    export PYTHON
}
