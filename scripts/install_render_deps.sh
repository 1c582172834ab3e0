#!/usr/bin/env bash
# Install the system libraries dashtraj.render needs for a headless OpenGL context:
# EGL + Mesa's software rasterizer (llvmpipe). Idempotent: installs only what is missing.
# Usage: scripts/install_render_deps.sh [--pip PYTHON]   (with --pip also pip-installs moderngl)
set -euo pipefail
PKGS=(libegl1 libgl1 libgl1-mesa-dri)
missing=()
for p in "${PKGS[@]}"; do
    if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
        missing+=("$p")
    fi
done
if [ ${#missing[@]} -gt 0 ]; then
    SUDO=""
    if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
    echo "install_render_deps: installing ${missing[*]}"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
else
    echo "install_render_deps: system packages present (${PKGS[*]})"
fi
if [ "${1:-}" = "--pip" ]; then
    PY="${2:-python3}"
    "$PY" -c "import moderngl" 2>/dev/null || "$PY" -m pip install -q "moderngl>=5.10"
fi
