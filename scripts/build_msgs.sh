#!/usr/bin/env bash
# Build the package's ROS 2 interfaces (the top-level msg/*.msg files) as the ROS package
# twotank_validation_msgs (CMake project in the folder twotank_validation_msgs/) with the ROS 2
# PyPI wheels, and install them into a venv prefix: afterwards
# `from twotank_validation_msgs.msg import FlowCommand` works in the venv's Python with no extra
# environment variables.
#
#   scripts/build_msgs.sh [--force] [VENV]     (VENV default: $TWOTANK_VENV or .venv)
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
PKG=twotank_validation_msgs
SRC=$ROOT/$PKG

say() { echo "[twotank] $*" >&2; }
die() {
  say "ERROR: $*"
  exit 1
}

[[ -x "$VENV/bin/python" ]] || die "no venv at $VENV: run 'bash scripts/run exec true' first"
VENV=$(cd "$VENV" && pwd)
STAMP=$VENV/.twotank-msgs-stamp
MANIFEST=$VENV/.twotank-msgs-manifest
LOG=$VENV/msgs-build.log

shopt -s nullglob
msgs=("$ROOT"/msg/*.msg)
shopt -u nullglob
((${#msgs[@]})) || die "no .msg files in $ROOT/msg"

# Everything that decides the build output (names and contents).
want=$(
  cd "$ROOT"
  for f in msg/*.msg $PKG/CMakeLists.txt $PKG/package.xml scripts/build_msgs.sh \
    requirements.txt requirements-ros.txt; do
    printf '== %s\n' "$f"
    cat "$f"
  done | sha256sum | cut -d' ' -f1
)

installed_ok() {
  [[ -f "$STAMP" && "$(cat "$STAMP")" == "$want" && -s "$MANIFEST" ]] || return 1
  local f
  while IFS= read -r f; do
    [[ -e "$f" ]] || return 1
  done <"$MANIFEST"
}

if ((!force)) && installed_ok; then
  exit 0
fi

# --- toolchain -----------------------------------------------------------------------------
missing=()
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
  die "building the ROS 2 messages ($PKG) needs: ${list#, }.
  On Debian/Ubuntu: apt-get install cmake g++ ninja-build   (then run the command again)"
fi

# --- build -----------------------------------------------------------------------------------
say "building ROS 2 messages $PKG from msg/*.msg into $VENV (log: $LOG)"
build=$(mktemp -d "${TMPDIR:-/tmp}/twotank-msgs.XXXXXX")
trap 'rm -rf "$build"' EXIT
start=$SECONDS

run_logged() {
  if ! "$@" >>"$LOG" 2>&1; then
    tail -n 40 "$LOG" >&2
    die "building $PKG failed at: $* (full log: $LOG)"
  fi
}

: >"$LOG"
# Only the venv: a sourced ROS install must not leak into this build.
export AMENT_PREFIX_PATH=$VENV
export CMAKE_PREFIX_PATH=$VENV
run_logged cmake -S "$SRC" -B "$build" -G "$generator" \
  -DCMAKE_BUILD_TYPE=Release \
  -DCMAKE_INSTALL_PREFIX="$VENV" \
  -DPython3_EXECUTABLE="$VENV/bin/python" \
  -DTWOTANK_INTERFACE_ROOT="$ROOT" \
  -DBUILD_TESTING=OFF
run_logged cmake --build "$build" --parallel "$(nproc 2>/dev/null || echo 2)"

# Remove what the previous build installed (a renamed or deleted .msg leaves no stale module).
if [[ -f "$MANIFEST" ]]; then
  while IFS= read -r f; do
    [[ "$f" == "$VENV"/* ]] && rm -f -- "$f"
  done <"$MANIFEST"
  rm -f "$STAMP" "$MANIFEST"
fi
run_logged cmake --install "$build"
cp "$build/install_manifest.txt" "$MANIFEST"

# Smoke test in a clean environment: every message imports and instantiates from the venv.
names=()
for f in "${msgs[@]}"; do
  n=${f##*/}
  names+=("${n%.msg}")
done
list=$(IFS=,; echo "${names[*]}")
if ! env -u AMENT_PREFIX_PATH -u CMAKE_PREFIX_PATH -u PYTHONPATH -u LD_LIBRARY_PATH \
  "$VENV/bin/python" -c "
import importlib
mod = importlib.import_module('$PKG.msg')
for name in '$list'.split(','):
    getattr(mod, name)()
" >>"$LOG" 2>&1; then
  tail -n 20 "$LOG" >&2
  die "$PKG was built but does not import in $VENV/bin/python (log: $LOG)"
fi

echo "$want" >"$STAMP"
say "built $PKG (${names[*]}) in $((SECONDS - start)) s"
