#!/usr/bin/env bash
# Build the package's ROS 2 interfaces (the top-level msg/*.msg files) as the ROS package
# twotank_validation_msgs (CMake project in the folder twotank_validation_msgs/) with the ROS 2
# PyPI wheels, and install them into a venv prefix: afterwards
# `from twotank_validation_msgs.msg import FlowCommand` works in the venv's Python with no extra
# environment variables.
#
#   scripts/build_msgs.sh [--force] [VENV]     (VENV default: $TWOTANK_VENV or .venv)
#
# The same machinery then builds the test double's interface controller_manager_msgs (only
# srv/SwitchController.srv, vendored from ros2_control in test/interfaces/) into the same venv:
# the supervisor's controller switch is tested against a fake controller manager
# (test/ros/fake_controller_manager.py), and the generated type support must sit in the
# interpreter's prefix (LD_LIBRARY_PATH cannot be set after a test process starts). It goes
# into the development/test venv that scripts/run makes, never into the package's install
# (setup.py, colcon: COLCON_IGNORE), so a ROS install keeps its real controller_manager_msgs.
#
# Idempotent: a stamp in the venv holds the hash of the .msg files, of the CMake project, of
# this script and of the requirement files; when it matches and the installed files are all
# present, nothing is rebuilt. The venv must already hold requirements.txt and
# requirements-ros.txt (scripts/run does that first). Needs cmake, a C and a C++ compiler, and
# ninja or make.
#
# Two snags of the PyPI wheels are worked around here and in
# twotank_validation_msgs/CMakeLists.txt without touching any installed file: the wheels'
# exported CMake targets name the wheel builder's Python/NumPy include dirs (the CMakeLists.txt
# re-points missing ones at this interpreter's), and the rosidl type-support lookup needs
# AMENT_PREFIX_PATH=<venv> at build time (exported below for cmake only).
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)

force=0
if [[ "${1:-}" == "--force" ]]; then
  force=1
  shift
fi
VENV=${1:-${TWOTANK_VENV:-$ROOT/.venv}}

say() { echo "[twotank] $*" >&2; }
die() {
  say "ERROR: $*"
  exit 1
}

[[ -x "$VENV/bin/python" ]] || die "no venv at $VENV: run 'bash scripts/run exec true' first"
VENV=$(cd "$VENV" && pwd)

shopt -s nullglob
msgs=("$ROOT"/msg/*.msg)
shopt -u nullglob
((${#msgs[@]})) || die "no .msg files in $ROOT/msg"
names=()
for f in "${msgs[@]}"; do
  n=${f##*/}
  names+=("${n%.msg}")
done

# build_package PKG SRC TAG SMOKE FILE...: build the CMake project SRC (ROS package PKG) into
# the venv unless the stamp $VENV/.TAG-stamp holds the hash of FILE... (paths relative to the
# repository root: everything that decides the output) and every installed file is present;
# SMOKE is Python run afterwards in a clean environment (it must import the generated module).
build_package() {
  local pkg=$1 src=$2 tag=$3 smoke=$4
  shift 4
  local stamp=$VENV/.$tag-stamp manifest=$VENV/.$tag-manifest log=$VENV/$tag-build.log want f
  want=$(
    cd "$ROOT"
    for f in "$@" scripts/build_msgs.sh twotank_validation_msgs/cmake/wheel_include_dirs.cmake \
      requirements.txt requirements-ros.txt; do
      printf '== %s\n' "$f"
      cat "$f"
    done | sha256sum | cut -d' ' -f1
  )
  if ((!force)) && [[ -f "$stamp" && "$(cat "$stamp")" == "$want" && -s "$manifest" ]]; then
    local ok=1
    while IFS= read -r f; do
      [[ -e "$f" ]] || { ok=0; break; }
    done <"$manifest"
    ((ok)) && return 0
  fi
  check_toolchain "$pkg"
  say "building ROS 2 interfaces $pkg into $VENV (log: $log)"
  local build start=$SECONDS
  build=$(mktemp -d "${TMPDIR:-/tmp}/twotank-msgs.XXXXXX")
  : >"$log"
  run_logged() {
    if ! "$@" >>"$log" 2>&1; then
      tail -n 40 "$log" >&2
      rm -rf "$build"
      die "building $pkg failed at: $* (full log: $log)"
    fi
  }
  # Only the venv: a sourced ROS install must not leak into this build.
  AMENT_PREFIX_PATH=$VENV CMAKE_PREFIX_PATH=$VENV run_logged cmake -S "$src" -B "$build" \
    -G "$generator" \
    -DCMAKE_BUILD_TYPE=Release \
    -DCMAKE_INSTALL_PREFIX="$VENV" \
    -DPython3_EXECUTABLE="$VENV/bin/python" \
    -DTWOTANK_INTERFACE_ROOT="$ROOT" \
    -DBUILD_TESTING=OFF
  AMENT_PREFIX_PATH=$VENV CMAKE_PREFIX_PATH=$VENV run_logged cmake --build "$build" \
    --parallel "$(nproc 2>/dev/null || echo 2)"
  # Remove what the previous build installed (a renamed or deleted file leaves no stale module).
  if [[ -f "$manifest" ]]; then
    while IFS= read -r f; do
      [[ "$f" == "$VENV"/* ]] && rm -f -- "$f"
    done <"$manifest"
    rm -f "$stamp" "$manifest"
  fi
  run_logged cmake --install "$build"
  cp "$build/install_manifest.txt" "$manifest"
  rm -rf "$build"
  # Smoke test in a clean environment: the generated module imports from the venv.
  if ! env -u AMENT_PREFIX_PATH -u CMAKE_PREFIX_PATH -u PYTHONPATH -u LD_LIBRARY_PATH \
    "$VENV/bin/python" -c "$smoke" >>"$log" 2>&1; then
    tail -n 20 "$log" >&2
    die "$pkg was built but does not import in $VENV/bin/python (log: $log)"
  fi
  echo "$want" >"$stamp"
  say "built $pkg in $((SECONDS - start)) s"
}

# --- toolchain (checked only when something is to be built) ---------------------------------
check_toolchain() {
  local missing=() list
  command -v cmake >/dev/null 2>&1 || missing+=(cmake)
  command -v cc >/dev/null 2>&1 || command -v gcc >/dev/null 2>&1 || missing+=("C compiler (gcc)")
  command -v c++ >/dev/null 2>&1 || command -v g++ >/dev/null 2>&1 || missing+=("C++ compiler (g++)")
  if command -v ninja >/dev/null 2>&1; then
    generator=Ninja
  elif command -v make >/dev/null 2>&1; then
    generator="Unix Makefiles"
  else
    missing+=("ninja or make")
  fi
  if ((${#missing[@]})); then
    list=$(printf ', %s' "${missing[@]}")
    die "building the ROS 2 interfaces ($1) needs: ${list#, }.
    On Debian/Ubuntu: apt-get install cmake g++ ninja-build   (then run the command again)"
  fi
}

# --- the two packages --------------------------------------------------------------------------
list=$(IFS=,; echo "${names[*]}")
mapfile -t own < <(cd "$ROOT" && printf '%s\n' msg/*.msg twotank_validation_msgs/CMakeLists.txt \
  twotank_validation_msgs/package.xml)
build_package twotank_validation_msgs "$ROOT/twotank_validation_msgs" twotank-msgs "
import importlib
mod = importlib.import_module('twotank_validation_msgs.msg')
for name in '$list'.split(','):
    getattr(mod, name)()
" "${own[@]}"

CM=test/interfaces/controller_manager_msgs
build_package controller_manager_msgs "$ROOT/$CM" twotank-test-cm-msgs "
from controller_manager_msgs.srv import SwitchController
SwitchController.Request(activate_controllers=['a'], strictness=SwitchController.Request.STRICT)
" $CM/srv/SwitchController.srv $CM/CMakeLists.txt $CM/package.xml
