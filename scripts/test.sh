#!/usr/bin/env bash
# Install with the test extras and run the whole test suite, slow tests included (CPU, about 5 minutes on 2 cores;
# `python -m pytest -m "not slow"` is the quick local run).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install.sh test
exec "${PYTHON:-python3}" -m pytest -q "$@"
