#!/usr/bin/env bash
# Optional parts; none is needed by the core install or the core tests (their tests skip, saying why).
#
#   bash scripts/install_optional.sh video     # MP4 fly-throughs: imageio-ffmpeg (pip install -e ".[video]")
#   bash scripts/install_optional.sh view      # the browser viewer: viser (pip install -e ".[view]")
#   bash scripts/install_optional.sh formats   # .spz / .compressed.ply / .sog: PlayCanvas splat-transform from
#                                              #   npm into the project's .tools/ (npm's cache too; PREFIX=... to
#                                              #   change, e.g. PREFIX=~/.local; needs Node.js >= 20)
#   bash scripts/install_optional.sh browser   # for scripts/viewer_screenshot.py: Debian's chromium (apt-get
#                                              #   update + install, SYSTEM-WIDE, as root; skipped when chromium
#                                              #   is there) and the playwright Python package (no browser download)
#   bash scripts/install_optional.sh sfm       # `data poses` (SfM on unposed panoramas): pycolmap, a CPU wheel
#                                              #   from PyPI (pip install -e ".[sfm]")
#   bash scripts/install_optional.sh all
#
# video, view, sfm and playwright go into the Python scripts/_python.sh picks (.venv under PEP 668); only browser's
# apt-get touches the system (scripts/test.sh runs it only with --with-system-tools).
# Measured on the 2-core dev machine: view ~5 s, formats ~10 s (215 MB of node_modules),
# browser ~65 s (apt-get update + chromium) + ~6 s (playwright).
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/_python.sh
choose_python  # the Python install.sh uses (.venv where the system Python refuses installs)
PY=$PYTHON
SPLAT_TRANSFORM_VERSION=${SPLAT_TRANSFORM_VERSION:-3.7.0}

install_video() {
    "$PY" -m pip install --disable-pip-version-check -q -e ".[video]"
}

install_view() {
    "$PY" -m pip install --disable-pip-version-check -q -e ".[view]"
}

install_formats() {
    if ! command -v node >/dev/null || ! command -v npm >/dev/null; then
        echo "formats: Node.js and npm are needed (Debian: apt-get install nodejs npm; or https://nodejs.org)" >&2
        return 1
    fi
    local major
    major=$(node -p 'process.versions.node.split(".")[0]')
    if [ "$major" -lt 20 ]; then
        echo "formats: Node.js >= 20 is needed, found $(node --version)" >&2
        return 1
    fi
    local prefix=${PREFIX:-$PWD/.tools}
    # npm's cache (and its logs) in the prefix too: nothing is written to ~/.npm
    npm install --global --prefix "$prefix" --cache "$prefix/npm-cache" --no-audit --no-fund --loglevel=error \
        "@playcanvas/splat-transform@$SPLAT_TRANSFORM_VERSION"
    "$prefix/bin/splat-transform" --version
    case ":$PATH:" in
        *":$prefix/bin:"*) ;;
        *) echo "note: $prefix/bin is not on PATH; cylindersplat still finds $prefix/bin/splat-transform when PREFIX is" \
                "the default (this clone's .tools/, or ~/.local), otherwise set" \
                "CYLINDERSPLAT_SPLAT_TRANSFORM=$prefix/bin/splat-transform" ;;
    esac
}

install_sfm() {
    "$PY" -m pip install --disable-pip-version-check -q -e ".[sfm]"
}

install_browser() {
    if ! command -v chromium >/dev/null; then
        if [ "$(id -u)" -ne 0 ]; then
            echo "browser: run as root, or install chromium yourself (apt-get install chromium)" >&2
            return 1
        fi
        apt-get update -qq
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
    fi
    chromium --version
    "$PY" -m pip install --disable-pip-version-check -q -e ".[browser]"
}

case "${1:-}" in
    video) install_video ;;
    view) install_view ;;
    formats) install_formats ;;
    browser) install_browser ;;
    sfm) install_sfm ;;
    all) install_video; install_view; install_formats; install_browser; install_sfm ;;
    *) echo "usage: bash scripts/install_optional.sh video|view|formats|browser|sfm|all" >&2; exit 2 ;;
esac
