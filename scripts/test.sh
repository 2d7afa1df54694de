#!/usr/bin/env bash
# Install with the test extras and run the whole test suite, slow tests included (CPU, about 5 minutes on 2 cores;
# `python -m pytest -m "not slow"` is the quick local run).
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/_python.sh
choose_python  # exported PYTHON: the scripts below install into the same one (.venv under PEP 668)
bash scripts/install.sh test
# The optional tools (viewer, browser, splat formats, SfM), so that their tests run instead of skipping; a tool
# that cannot be installed here only makes its tests skip (CYLINDERSPLAT_SKIP_OPTIONAL=1 skips the installs).
if [ -z "${CYLINDERSPLAT_SKIP_OPTIONAL:-}" ]; then
    for part in video view formats browser sfm; do
        timeout 300 bash scripts/install_optional.sh "$part" >/dev/null 2>&1 \
            || echo "optional part '$part' not installed: its tests will skip" >&2
    done
fi
exec "$PYTHON" -m pytest -q "$@"
