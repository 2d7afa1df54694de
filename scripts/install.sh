#!/usr/bin/env bash
# Install cylindersplat and what it needs into the Python scripts/_python.sh picks (a virtual environment
# .venv where the system Python refuses installs, PEP 668).
#
# torch goes first, pinned (torch==2.13.0), so that the package's loose torch requirement is then already
# satisfied. On a normal package index (PyPI) that pin resolves, on Linux, to the CUDA build with its nvidia-*
# packages (several GB); so on a Linux machine without an NVIDIA GPU the CPU wheels' index
# ($TORCH_CPU_INDEX, default https://download.pytorch.org/whl/cpu) is added, whose torch==2.13.0+cpu wins over
# the CUDA build (a local version sorts above the plain one). A machine with a GPU gets the normal (CUDA) build.
# A torch 2.13.0 that is already installed (any build) is kept; TORCH_CPU_INDEX= (empty) adds no index (a pip
# configured with its own mirror or wheel folder, as this project's CI is).
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/_python.sh
choose_python
EXTRAS=${1:-}
TORCH_VERSION=2.13.0
pip_install() { "$PYTHON" -m pip install --disable-pip-version-check -q "$@"; }

if ! "$PYTHON" -c "import sys, torch; sys.exit(torch.__version__.split('+')[0] != '$TORCH_VERSION')" 2>/dev/null; then
    index=()
    if [ "$(uname -s)" = Linux ] && ! command -v nvidia-smi >/dev/null 2>&1 && [ ! -e /dev/nvidia0 ] \
            && [ -n "${TORCH_CPU_INDEX-https://download.pytorch.org/whl/cpu}" ]; then
        index=(--extra-index-url "${TORCH_CPU_INDEX-https://download.pytorch.org/whl/cpu}")  # no GPU: the CPU build
    fi
    pip_install ${index[@]+"${index[@]}"} "torch==$TORCH_VERSION"
fi
pip_install -e ".${EXTRAS:+[$EXTRAS]}"
