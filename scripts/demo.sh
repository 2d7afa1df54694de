#!/usr/bin/env bash
# Install and run the main job on a default that needs no download (in .venv where the system Python refuses
# installs: see scripts/_python.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/_python.sh
choose_python
bash scripts/install.sh
exec "$PYTHON" -m cylindersplat demo --out outputs/demo "$@"
