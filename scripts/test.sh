#!/usr/bin/env bash
# Install the package with its test extras, lint (ruff), and run the whole test suite, slow tests included
# (CI: .ci/run).
#
#   bash scripts/test.sh                        # installs only into the project's Python (scripts/_python.sh)
#                                               # and the project folder; then runs pytest
#   bash scripts/test.sh --with-system-tools    # also installs system packages (apt-get chromium, as root) so
#                                               # that the headless-browser test runs; CI passes this
#   bash scripts/test.sh -m "not slow" -x       # other arguments go to pytest
#
# CYLINDERSPLAT_SYSTEM_INSTALLS=1 is the same as --with-system-tools; CYLINDERSPLAT_SKIP_OPTIONAL=1 installs no
# optional part. What each optional part installs, and where: scripts/install_optional.sh. A part that is not
# installed only makes its tests skip; the lines below say which and why.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/_python.sh

system_installs=${CYLINDERSPLAT_SYSTEM_INSTALLS:-}
pytest_args=()
for argument in "$@"; do
    case "$argument" in
        --with-system-tools) system_installs=1 ;;
        *) pytest_args+=("$argument") ;;
    esac
done

choose_python  # exported PYTHON: the scripts below install into the same one (.venv under PEP 668)
bash scripts/install.sh test

# Lint before anything slow: line length, pyflakes and import order as [tool.ruff] in pyproject.toml sets them
# (ruff comes with the test extra). A finding stops the script.
"$PYTHON" -m ruff check src tests studies benchmarks scripts

skipped() { echo "test.sh: optional part '$1' skipped: $2; its tests will skip" >&2; }

# Optional parts, so that their tests run instead of skipping: video, view, sfm (pip, into the same Python),
# formats (npm, into the project's own .tools/) and browser (the playwright package; chromium itself comes from
# apt-get, system-wide, only with --with-system-tools unless it is already on this machine).
if [ -n "${CYLINDERSPLAT_SKIP_OPTIONAL:-}" ]; then
    echo "test.sh: no optional part installed (CYLINDERSPLAT_SKIP_OPTIONAL is set); their tests will skip" >&2
else
    for part in video view formats sfm browser; do
        if [ "$part" = browser ] && [ "$system_installs" != 1 ] && ! command -v chromium >/dev/null 2>&1; then
            skipped browser "chromium would be installed system-wide (apt-get); run \`bash scripts/test.sh\
 --with-system-tools\` (or CYLINDERSPLAT_SYSTEM_INSTALLS=1) to install it"
            continue
        fi
        log=$(mktemp)
        if ! CYLINDERSPLAT_SYSTEM_INSTALLS=$system_installs timeout 300 bash scripts/install_optional.sh "$part" \
                >"$log" 2>&1; then
            reason=$(grep -v '^\s*$' "$log" | tail -n 1)
            skipped "$part" "${reason:-its installer failed (bash scripts/install_optional.sh $part says why)}"
        fi
        rm -f "$log"
    done
fi
exec "$PYTHON" -m pytest -q ${pytest_args[@]+"${pytest_args[@]}"}
