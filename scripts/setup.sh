#!/usr/bin/env bash
# Set up faceanim on a fresh Debian/Ubuntu machine. Safe to run again: it installs only what is
# missing, and prints a line per thing it installs.
#
#   system packages (apt-get, decided one need at a time, each need in its own apt-get call):
#     Mesa EGL/GL (offscreen rendering: EGL with Mesa's llvmpipe) and libGL/GLib for opencv
#       (mediapipe): libegl1 libgl1 libegl-mesa0 libgl1-mesa-dri libglx-mesa0 libgbm1, libglib2.0-0
#     espeak-ng (speech synthesis), optional
#     PortAudio, libportaudio2 (faceanim live --mic records through it), optional
#     chromium (Debian's; the browser viewer's end-to-end tests drive it headless with Playwright),
#       optional
#     Node.js with npm (the glTF validator and three-vrm used by tests; three.js for faceanim
#       view), optional: Debian's `nodejs npm` only when neither node nor npm exists (NodeSource's
#       nodejs carries its own npm, and Debian's npm conflicts with it)
#     python3 with venv, required, only when there is no usable .venv and no usable python3
#     with --tests only: PulseAudio (pulseaudio pulseaudio-utils) and ALSA's pulse plugin
#       (libasound2-plugins), optional: the virtual microphone of the --mic tests
#       (tests/pulse_loopback.py); without them those tests are skipped
#   .venv: a virtual environment with faceanim installed from this checkout (required)
#   tools/node_modules: the Khronos glTF validator and three-vrm, with npm (optional)
#   src/faceanim/viewer/static/node_modules: three.js and three-vrm served by faceanim view, with
#     npm (optional; pinned in that folder's package.json and package-lock.json)
#
# A required part that cannot be had stops the script with an error; an optional one prints one
# note saying what will be skipped, and the script goes on.
#
# FACEANIM_SETUP_SYSTEM_ONLY=1 (or --system-only) stops after the system packages (for tests).
# PYTHON=... picks the interpreter for a new .venv (default python3).
set -euo pipefail

system_only=${FACEANIM_SETUP_SYSTEM_ONLY:-0}
with_tests=0
for arg in "$@"; do
  case $arg in
    --system-only) system_only=1 ;;
    --tests) with_tests=1 ;;
    -h | --help) echo "usage: bash scripts/setup.sh [--system-only] [--tests]"; exit 0 ;;
    *) echo "setup: error: unknown argument: $arg (usage: bash scripts/setup.sh [--system-only] [--tests])" >&2; exit 2 ;;
  esac
done

cd "$(dirname "$0")/.."

say() { echo "setup: $*"; }
note() { echo "setup: note: $*" >&2; }
die() { echo "setup: error: $*" >&2; exit 1; }
have() { command -v "$1" >/dev/null 2>&1; }

PY=${PYTHON:-python3}

# ---------------------------------------------------------------------------------------------
# What is missing. Each need: a name, its Debian packages, whether it is required, and what is
# lost without it.
# ---------------------------------------------------------------------------------------------
need_names=() need_pkgs=() need_required=() need_loss=()
need() { need_names+=("$1"); need_pkgs+=("$2"); need_required+=("$3"); need_loss+=("$4"); }

# The dynamic linker's cache (ldconfig is in /sbin, which a user's PATH may lack).
ldconfig_bin=$(command -v ldconfig 2>/dev/null || true)
if [ -z "$ldconfig_bin" ]; then
  for p in /sbin/ldconfig /usr/sbin/ldconfig; do
    if [ -x "$p" ]; then ldconfig_bin=$p; break; fi
  done
fi
libcache=""
if [ -n "$ldconfig_bin" ]; then libcache=$("$ldconfig_bin" -p 2>/dev/null || true); fi
# The path the dynamic linker cache gives for a library (soname), or nothing.
lib_path() {
  local line
  while IFS= read -r line; do
    line=${line#"${line%%[![:space:]]*}"}
    if [ "${line%% *}" = "$1" ] && [[ $line == *" => "* ]]; then
      echo "${line##* => }"
      return 0
    fi
  done <<<"$libcache"
  return 1
}
has_lib() { lib_path "$1" >/dev/null; }
# Mesa's DRI drivers (swrast_dri.so, llvmpipe) are not in the linker cache: look beside Mesa's
# libraries, in their dri/ folder (newer Mesa also puts libgallium-*.so in the cache).
has_mesa_dri() {
  local lib dir
  [[ $libcache == *libgallium* ]] && return 0
  for lib in libEGL_mesa.so.0 libGLX_mesa.so.0 libgbm.so.1 libglapi.so.0; do
    dir=$(lib_path "$lib") || continue
    dir=${dir%/*}
    [ -e "$dir/dri/swrast_dri.so" ] && return 0
    [[ $dir == /lib/* ]] && [ -e "/usr$dir/dri/swrast_dri.so" ] && return 0
  done
  return 1
}

gl_pkgs=()
has_lib libEGL.so.1 || gl_pkgs+=(libegl1)
has_lib libGL.so.1 || gl_pkgs+=(libgl1)
has_lib libEGL_mesa.so.0 || gl_pkgs+=(libegl-mesa0)
has_lib libGLX_mesa.so.0 || gl_pkgs+=(libglx-mesa0)
has_lib libgbm.so.1 || gl_pkgs+=(libgbm1)
has_mesa_dri || gl_pkgs+=(libgl1-mesa-dri)
[ ${#gl_pkgs[@]} -eq 0 ] \
  || need "Mesa EGL/GL" "${gl_pkgs[*]}" 0 "offscreen rendering (faceanim demo, the render tests) will fail"
{ has_lib libglib-2.0.so.0 && has_lib libgthread-2.0.so.0; } \
  || need "GLib" libglib2.0-0 0 "opencv (mediapipe landmarks) may fail to import"

have espeak-ng \
  || need espeak-ng espeak-ng 0 "speech synthesis (faceanim say TEXT) and its tests will be skipped"
have chromium \
  || need chromium chromium 0 "the browser viewer's tests (faceanim view in headless Chromium) will be skipped"
has_lib libportaudio.so.2 \
  || need PortAudio libportaudio2 0 "faceanim live --mic (a microphone) will not work"
if [ "$with_tests" = 1 ]; then
  pulse_pkgs=()
  have pulseaudio || pulse_pkgs+=(pulseaudio)
  { have pactl && have pacat; } || pulse_pkgs+=(pulseaudio-utils)
  # ALSA's pulse plugin, beside libasound (PortAudio reaches PulseAudio through it)
  asound=$(lib_path libasound.so.2 || true)
  { [ -n "$asound" ] && [ -e "${asound%/*}/alsa-lib/libasound_module_pcm_pulse.so" ]; } \
    || pulse_pkgs+=(libasound2-plugins)
  [ ${#pulse_pkgs[@]} -eq 0 ] \
    || need "PulseAudio (tests)" "${pulse_pkgs[*]}" 0 "the live --mic tests (a virtual microphone) will be skipped"
fi

node_note=""
if have node && have npm; then
  :
elif have node; then
  node_note="node is here but npm is not (Debian's npm is not installed beside another Node.js: it conflicts with NodeSource's nodejs, which carries its own npm); the glTF validator and its test will be skipped, and faceanim view will lack three.js"
elif have npm; then
  node_note="npm is here but node is not (Debian's nodejs is not installed beside another npm); the glTF validator and its test will be skipped, and faceanim view will lack three.js"
else
  need "Node.js/npm" "nodejs npm" 0 "the glTF validator (tools/) and its test will be skipped, and faceanim view will lack three.js"
fi

if [ ! -x .venv/bin/python ] || ! .venv/bin/python -c '' >/dev/null 2>&1; then
  py_path=$(command -v "$PY" 2>/dev/null || true)
  if [ -z "$py_path" ]; then
    [ "$PY" = python3 ] && need "python3 with venv" "python3 python3-venv" 1 ""
  elif ! "$py_path" -c 'import venv, ensurepip' >/dev/null 2>&1; then
    # Debian splits venv's pip (ensurepip) into python3-venv; it only helps Debian's python3.
    case $(readlink -f "$py_path" 2>/dev/null || echo "$py_path") in
      /usr/bin/python3*) need "python3 with venv" python3-venv 1 "" ;;
    esac
  fi
fi

# ---------------------------------------------------------------------------------------------
# Install them: apt-get update once, then one apt-get install per need (and, if that fails, one
# per package), so that one conflict does not sink the rest.
# ---------------------------------------------------------------------------------------------
if [ ${#need_names[@]} -gt 0 ]; then
  all_pkgs=$(printf '%s ' "${need_pkgs[@]}")
  all_pkgs=${all_pkgs% }
  apt_prefix=()
  why_not=""
  if ! have apt-get; then
    why_not="there is no apt-get here"
  elif [ "$(id -u)" -ne 0 ]; then
    if have sudo; then
      apt_prefix=(sudo)
      [ -t 0 ] || apt_prefix+=(-n)  # no terminal to ask for a password on: fail, don't hang
    else
      why_not="not root and there is no sudo"
    fi
  fi

  required_failed=0
  failed=()  # indices of needs that could not be installed
  if [ -n "$why_not" ]; then
    note "$why_not; please install these Debian packages (or their equivalents): $all_pkgs"
    for i in "${!need_names[@]}"; do failed+=("$i"); done
  else
    apt() {
      if [ ${#apt_prefix[@]} -gt 0 ]; then
        "${apt_prefix[@]}" DEBIAN_FRONTEND=noninteractive apt-get "$@"
      else
        DEBIAN_FRONTEND=noninteractive apt-get "$@"
      fi
    }
    # apt-get's last error line (e.g. "E: ... you have held broken packages."), else its last line.
    apt_error() {
      local line last="" err=""
      while IFS= read -r line; do
        [ -z "$line" ] || last=$line
        case $line in E:* | Err:*) err=$line ;; esac
      done <<<"$1"
      echo "${err:-$last}"
    }
    if ! out=$(apt update -qq 2>&1); then
      echo "setup: apt-get update failed (trying to install anyway): $(apt_error "$out")" >&2
    fi
    for i in "${!need_names[@]}"; do
      read -r -a pkgs <<<"${need_pkgs[$i]}"
      say "installing ${need_names[$i]} (${pkgs[*]})"
      if out=$(apt install -y -qq "${pkgs[@]}" 2>&1); then
        continue
      fi
      if [ ${#pkgs[@]} -eq 1 ]; then
        echo "setup: apt-get install ${pkgs[0]} failed: $(apt_error "$out")" >&2
        failed+=("$i")
        continue
      fi
      # Try each package on its own: install what can be installed.
      bad=()
      for p in "${pkgs[@]}"; do
        if ! out=$(apt install -y -qq "$p" 2>&1); then
          echo "setup: apt-get install $p failed: $(apt_error "$out")" >&2
          bad+=("$p")
        fi
      done
      if [ ${#bad[@]} -gt 0 ]; then
        need_pkgs[$i]="${bad[*]}"
        failed+=("$i")
      fi
    done
    hash -r
  fi

  for i in "${failed[@]+"${failed[@]}"}"; do
    if [ "${need_required[$i]}" = 1 ]; then
      # the Python step below stops with what it cannot do
      echo "setup: could not install ${need_pkgs[$i]} (${need_names[$i]}), which faceanim needs" >&2
      required_failed=1
    elif [ "${need_names[$i]}" = "Node.js/npm" ]; then
      # part of it may have been installed
      if ! { have node && have npm; }; then
        note "could not install ${need_pkgs[$i]}; ${need_loss[$i]}"
      fi
    else
      note "could not install ${need_pkgs[$i]}; ${need_loss[$i]}"
    fi
  done
fi
[ -z "$node_note" ] || note "$node_note"

if [ "$system_only" = 1 ]; then
  [ "${required_failed:-0}" = 0 ] || die "a required system package could not be installed (see above)"
  exit 0
fi

# ---------------------------------------------------------------------------------------------
# Python: .venv with faceanim and its test dependencies (required).
# ---------------------------------------------------------------------------------------------
if [ ! -x .venv/bin/python ] || ! .venv/bin/python -c '' >/dev/null 2>&1; then
  have "$PY" || die "$PY was not found; faceanim needs Python 3.11 or newer with venv and pip (Debian: apt-get install python3 python3-venv), or set PYTHON=/path/to/python3.11"
  "$PY" -c 'import sys; sys.exit(sys.version_info < (3, 11))' \
    || die "$PY is Python $("$PY" -c 'import sys; print("%d.%d" % sys.version_info[:2])'); faceanim needs 3.11 or newer (set PYTHON=/path/to/python3.11)"
  "$PY" -c 'import venv, ensurepip' >/dev/null 2>&1 \
    || die "$PY has no venv/ensurepip (Debian: apt-get install python3-venv)"
  say "creating .venv with $PY"
  "$PY" -m venv .venv || die "could not create .venv with $PY -m venv (if .venv is left from another Python, remove it and run again)"
  .venv/bin/python -m pip install -q --upgrade pip || note "could not upgrade pip in .venv; going on with its own"
fi
.venv/bin/python -m pip install -q -e '.[all,test]' \
  || die "pip could not install faceanim and its test dependencies into .venv (.venv/bin/python -m pip install -e '.[all,test]'); see pip's messages above"

# ---------------------------------------------------------------------------------------------
# The Khronos glTF validator and three.js with three-vrm (optional), pinned in tools/package.json;
# installed when a pin is missing or at another version (npm ls fails).
# ---------------------------------------------------------------------------------------------
if have node && have npm && ! npm ls --prefix tools >/dev/null 2>&1; then
  say "installing the glTF validator and three-vrm into tools/ (npm)"
  npm install --prefix tools --no-audit --no-fund --silent >/dev/null 2>&1 \
    || note "could not install the glTF validator and three-vrm (npm install --prefix tools); their tests will be skipped"
fi

# ---------------------------------------------------------------------------------------------
# three.js and three-vrm served by faceanim view (optional), pinned in the viewer's package.json;
# installed when a pin is missing or at another version (npm ls fails).
# ---------------------------------------------------------------------------------------------
viewer_static=src/faceanim/viewer/static
if have node && have npm && ! npm ls --prefix "$viewer_static" >/dev/null 2>&1; then
  say "installing three.js for faceanim view into $viewer_static/ (npm)"
  npm install --prefix "$viewer_static" --no-audit --no-fund --silent >/dev/null 2>&1 \
    || note "could not install three.js (npm install --prefix $viewer_static); faceanim view and its tests will be skipped"
fi
# ---------------------------------------------------------------------------------------------
# --tests: Blender's Python module (bpy, optional) in its own .venv-blender, for the check that
# faceanim's glTF files import into Blender (tests/test_blender.py). bpy 5.0.1 wants Python 3.11
# exactly and numpy < 2; it is a 374 MB download, about 1 GB installed, so only the test setup
# makes it. Its X11 client libraries (libx11-6 libxrender1 libxfixes3 libxi6 libxkbcommon0 libsm6)
# are not installed here: without them bpy does not import and the test skips with the reason.
# ---------------------------------------------------------------------------------------------
BPY_VERSION=5.0.1
if [ "$with_tests" = 1 ] && ! { [ -x .venv-blender/bin/python ] && .venv-blender/bin/python -c 'import bpy' >/dev/null 2>&1; }; then
  bpy_py=""
  for c in python3.11 "$PY"; do
    p=$(command -v "$c" 2>/dev/null) || continue
    if "$p" -c 'import sys, venv, ensurepip; sys.exit(sys.version_info[:2] != (3, 11))' >/dev/null 2>&1; then
      bpy_py=$p
      break
    fi
  done
  if [ -z "$bpy_py" ]; then
    note "Blender's bpy $BPY_VERSION needs Python 3.11, which is not here; tests/test_blender.py will be skipped"
  else
    say "installing Blender's bpy $BPY_VERSION into .venv-blender (PyPI, about 1 GB)"
    if ! { rm -rf .venv-blender && "$bpy_py" -m venv .venv-blender \
           && .venv-blender/bin/python -m pip install -q "bpy==$BPY_VERSION" >/dev/null 2>&1 \
           && .venv-blender/bin/python -c 'import bpy' >/dev/null 2>&1; }; then
      note "could not set up Blender's bpy $BPY_VERSION in .venv-blender; tests/test_blender.py will be skipped"
    fi
  fi
fi
say "ready (.venv)"
