#!/usr/bin/env bash
# Install cylindersplat and what it needs. torch goes first, pinned to the CPU wheel this
# machine kind provides (elsewhere the same pin fetches the normal build); the package's loose
# torch requirement is then already satisfied, so pip pulls no CUDA packages.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
EXTRAS=${1:-}
"$PY" -m pip install --disable-pip-version-check -q "torch==2.13.0"
"$PY" -m pip install --disable-pip-version-check -q -e ".${EXTRAS:+[$EXTRAS]}"
