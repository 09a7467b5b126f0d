#!/usr/bin/env bash
# Prepare the development environment: .venv (Python 3.11) with the pinned packages, this
# project installed in editable mode, and the ROS 2 interfaces (formic_interfaces) built from
# ros2_ws/ and installed into the venv. Idempotent: does the work only when
# requirements.lock, pyproject.toml, ros2_ws/formic_interfaces/ or this script changed
# (stamp in .venv/.formic-setup-stamp); otherwise it returns at once.
#
# Usage: scripts/setup.sh [--quiet]   (--quiet: say nothing when everything is up to date)
set -euo pipefail

quiet=0
for arg in "$@"; do
  case "$arg" in
    -q|--quiet) quiet=1 ;;
    -h|--help) sed -n '2,9p' "$0"; exit 0 ;;
    *) echo "setup.sh: unknown argument: $arg" >&2; exit 2 ;;
  esac
done

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$ROOT/.venv"
PKG="$ROOT/ros2_ws/formic_interfaces"
BUILD="$ROOT/build/formic_interfaces"
LOGS="$ROOT/build/setup-logs"
STAMP_FILE="$VENV/.formic-setup-stamp"
SITE="$VENV/lib/python3.11/site-packages"

say() { [ "$quiet" = 1 ] || echo "setup: $*" >&2; }
die() { echo "setup: ERROR: $*" >&2; exit 1; }

# Run a step with its output in a log file; on failure show the end of the log.
step() {
  local name="$1"; shift
  local log="$LOGS/$name.log"
  local t0=$SECONDS
  if ! "$@" >"$log" 2>&1; then
    echo "setup: ERROR: step '$name' failed; last lines of $log:" >&2
    tail -n 40 "$log" >&2
    exit 1
  fi
  say "  $name done ($((SECONDS - t0)) s)"
}

compute_stamp() {
  (
    cd "$ROOT"
    {
      echo "python3.11 venv at $VENV"
      sha256sum requirements.lock pyproject.toml scripts/setup.sh
      find ros2_ws/formic_interfaces -type f -print0 | LC_ALL=C sort -z | xargs -0 sha256sum
    } | sha256sum | cut -d' ' -f1
  )
}

[ -f "$ROOT/requirements.lock" ] || die "missing $ROOT/requirements.lock"
[ -f "$ROOT/pyproject.toml" ] || die "missing $ROOT/pyproject.toml"
[ -f "$PKG/CMakeLists.txt" ] || die "missing $PKG/CMakeLists.txt"

stamp="$(compute_stamp)"

# Fast path: stamp matches and the installed pieces are still there.
if [ -x "$VENV/bin/python" ] && [ -f "$STAMP_FILE" ] \
   && [ "$(cat "$STAMP_FILE")" = "$stamp" ] \
   && [ -f "$SITE/formic_interfaces/msg/__init__.py" ] \
   && [ -f "$SITE/rclpy/__init__.py" ]; then
  say "up to date"
  exit 0
fi

quiet=0  # real work ahead: always show progress
t_start=$SECONDS
mkdir -p "$LOGS"

if [ ! -x "$VENV/bin/python" ]; then
  command -v python3.11 >/dev/null 2>&1 || die "python3.11 not found on PATH (needed to create .venv)"
  say "creating $VENV with $(command -v python3.11)"
  rm -rf "$VENV"
  python3.11 -m venv "$VENV"
fi
"$VENV/bin/python" -c 'import sys; assert sys.version_info[:2] == (3, 11), sys.version' \
  || die "$VENV is not a Python 3.11 venv; remove it and run again"
rm -f "$STAMP_FILE"

say "installing requirements.lock (log: build/setup-logs/pip-requirements.log)"
step pip-requirements "$VENV/bin/python" -m pip install -r "$ROOT/requirements.lock"

say "installing this project in editable mode"
step pip-editable "$VENV/bin/python" -m pip install --no-deps -e "$ROOT"

say "building formic_interfaces with cmake (build dir: build/formic_interfaces)"
# A build dir configured for another source tree or prefix (repo moved or copied) is unusable.
if [ -f "$BUILD/CMakeCache.txt" ] && ! {
     grep -qxF "CMAKE_HOME_DIRECTORY:INTERNAL=$PKG" "$BUILD/CMakeCache.txt" &&
     grep -qxF "CMAKE_INSTALL_PREFIX:PATH=$VENV" "$BUILD/CMakeCache.txt"; }; then
  say "  build dir was configured elsewhere; starting it afresh"
  rm -rf "$BUILD"
fi
export PATH="$VENV/bin:$PATH"
export AMENT_PREFIX_PATH="$VENV"
command -v cmake >/dev/null 2>&1 || die "cmake not found (install cmake >= 3.22, or pip install cmake into the venv)"
command -v c++ >/dev/null 2>&1 || command -v g++ >/dev/null 2>&1 || die "no C/C++ compiler found (install build-essential)"
step cmake-configure cmake -S "$PKG" -B "$BUILD" \
  -DCMAKE_PREFIX_PATH="$VENV" -DCMAKE_INSTALL_PREFIX="$VENV" \
  -DPython3_EXECUTABLE="$VENV/bin/python" -DBUILD_TESTING=OFF
step cmake-build cmake --build "$BUILD" -j "$(nproc 2>/dev/null || echo 2)"
step cmake-install cmake --install "$BUILD"

say "checking: import rclpy, formic_interfaces.msg"
if ! (cd / && "$VENV/bin/python" -c "import rclpy, formic_interfaces.msg") >"$LOGS/import-check.log" 2>&1; then
  echo "setup: ERROR: '$VENV/bin/python -c \"import rclpy, formic_interfaces.msg\"' failed:" >&2
  cat "$LOGS/import-check.log" >&2
  exit 1
fi

echo "$stamp" >"$STAMP_FILE"
say "done in $((SECONDS - t_start)) s"
