#!/usr/bin/env bash
# Install and run the main job on a default that needs no download.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install.sh
exec cylindersplat demo --out outputs/demo "$@"
