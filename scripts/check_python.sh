#!/usr/bin/env bash
# Install faceanim on another Python (3.11, 3.12, 3.13 ...) in a fresh virtual environment and run
# the tests that stand on MediaPipe, numpy and OpenCV (landmarks on meshes, video tracking, the ARKit
# solve, perform, live, photos): what `pip install faceanim` gives a user of that Python.
#
#   bash scripts/check_python.sh PYTHON [PYTEST ARGS ...]
#   e.g. bash scripts/check_python.sh python3.13
#        bash scripts/check_python.sh ~/.pyenv/versions/3.12.1/bin/python -k solve
#
# The environment is made in a temporary folder and removed at the end; the checkout is installed
# editable (nothing in it is written but Python's caches). System packages come from
# scripts/setup.sh --system-only (run it first on a new machine). Exits with pytest's code.
set -euo pipefail

if [ $# -lt 1 ] || [ "$1" = -h ] || [ "$1" = --help ]; then
  echo "usage: bash scripts/check_python.sh PYTHON [PYTEST ARGS ...]"
  [ $# -ge 1 ] && exit 0 || exit 2
fi
py=$1
shift
command -v "$py" >/dev/null 2>&1 || { echo "check_python: error: $py was not found" >&2; exit 2; }
"$py" -c 'import sys; sys.exit(sys.version_info < (3, 11))' \
  || { echo "check_python: error: $py is older than Python 3.11, which faceanim needs" >&2; exit 2; }
cd "$(dirname "$0")/.."
venv=$(mktemp -d "${TMPDIR:-/tmp}/faceanim-check-XXXXXX")
trap 'rm -rf "$venv"' EXIT
version=$("$py" -c 'import sys; print("%d.%d.%d" % sys.version_info[:3])')
echo "check_python: Python $version: installing faceanim[all,test] into $venv"
"$py" -m venv "$venv"
"$venv/bin/python" -m pip install -q --upgrade pip >/dev/null 2>&1 || true
"$venv/bin/python" -m pip install -q -e '.[all,test]' 2>&1 | grep -v "^WARNING: Location" || true
"$venv/bin/python" -c 'import faceanim, mediapipe, numpy, cv2
print(f"check_python: numpy {numpy.__version__}, mediapipe {mediapipe.__version__}, opencv {cv2.__version__}")'
tests=(tests/test_landmarks.py tests/test_video_tracking.py tests/test_solve.py tests/test_perform.py
       tests/test_live.py tests/test_photo.py tests/test_registration.py)
"$venv/bin/python" -m pytest -q -p no:cacheprovider "${tests[@]}" "$@"
