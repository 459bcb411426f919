#!/usr/bin/env bash
# Set up faceanim on a fresh Debian/Ubuntu machine: system libraries for offscreen OpenGL
# (Mesa's EGL, used by VTK to render without a display), espeak-ng (speech synthesis for lip
# sync), Node.js for the glTF validator used by the tests, a virtual environment in .venv with
# faceanim installed from this checkout.
# Safe to run again: it only installs what is missing.
set -euo pipefail
cd "$(dirname "$0")/.."

need_apt=()
for lib in libEGL.so.1 libGL.so.1 libEGL_mesa.so.0; do
  ldconfig -p 2>/dev/null | grep -q "$lib" || need_apt+=("$lib")
done
command -v node >/dev/null 2>&1 || need_apt+=(node)
command -v espeak-ng >/dev/null 2>&1 || need_apt+=(espeak-ng)
if [ ${#need_apt[@]} -gt 0 ]; then
  if command -v apt-get >/dev/null 2>&1; then
    sudo=""; [ "$(id -u)" -ne 0 ] && sudo="sudo"
    echo "setup: installing Debian packages (missing: ${need_apt[*]})"
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq \
      libegl1 libgl1 libegl-mesa0 libgl1-mesa-dri libglx-mesa0 nodejs npm espeak-ng >/dev/null
  else
    echo "setup: please install Mesa's EGL/GL libraries, Node.js and espeak-ng (missing: ${need_apt[*]})" >&2
  fi
fi

PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e '.[test]'

if command -v npm >/dev/null 2>&1 && [ ! -d tools/node_modules/gltf-validator ]; then
  npm install --prefix tools --no-audit --no-fund --silent >/dev/null 2>&1 \
    || echo "setup: could not install the glTF validator; its test will be skipped" >&2
fi
echo "setup: ready (.venv)"
