#!/usr/bin/env bash
# Prepare the development environment: .venv (Python 3.11) with the pinned packages, this
# project installed in editable mode, and the ROS 2 interface packages of ros2_ws/
# (formic_interfaces, and the standard simulation_interfaces and tf2_msgs, which are not on PyPI)
# built and installed into the venv. Idempotent: does the work only when
# requirements.lock, pyproject.toml, ros2_ws/ or this script changed
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
INTERFACE_PACKAGES=(formic_interfaces simulation_interfaces tf2_msgs)
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
      find ros2_ws -type f -print0 | LC_ALL=C sort -z | xargs -0 sha256sum
    } | sha256sum | cut -d' ' -f1
  )
}

[ -f "$ROOT/requirements.lock" ] || die "missing $ROOT/requirements.lock"
[ -f "$ROOT/pyproject.toml" ] || die "missing $ROOT/pyproject.toml"
for pkg in "${INTERFACE_PACKAGES[@]}"; do
  [ -f "$ROOT/ros2_ws/$pkg/CMakeLists.txt" ] || die "missing $ROOT/ros2_ws/$pkg/CMakeLists.txt"
done

stamp="$(compute_stamp)"

# Fast path: stamp matches and the installed pieces are still there.
if [ -x "$VENV/bin/python" ] && [ -f "$STAMP_FILE" ] \
   && [ "$(cat "$STAMP_FILE")" = "$stamp" ] \
   && [ -f "$SITE/formic_interfaces/msg/__init__.py" ] \
   && [ -f "$SITE/simulation_interfaces/srv/__init__.py" ] \
   && [ -f "$SITE/tf2_msgs/msg/__init__.py" ] \
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

export PATH="$VENV/bin:$PATH"
export AMENT_PREFIX_PATH="$VENV"
command -v cmake >/dev/null 2>&1 || die "cmake not found (install cmake >= 3.22, or pip install cmake into the venv)"
command -v c++ >/dev/null 2>&1 || command -v g++ >/dev/null 2>&1 || die "no C/C++ compiler found (install build-essential)"
for pkg in "${INTERFACE_PACKAGES[@]}"; do
  PKG="$ROOT/ros2_ws/$pkg"
  BUILD="$ROOT/build/$pkg"
  say "building $pkg with cmake (build dir: build/$pkg)"
  # A build dir configured for another source tree or prefix (repo moved or copied) is unusable.
  if [ -f "$BUILD/CMakeCache.txt" ] && ! {
       grep -qxF "CMAKE_HOME_DIRECTORY:INTERNAL=$PKG" "$BUILD/CMakeCache.txt" &&
       grep -qxF "CMAKE_INSTALL_PREFIX:PATH=$VENV" "$BUILD/CMakeCache.txt"; }; then
    say "  build dir was configured elsewhere; starting it afresh"
    rm -rf "$BUILD"
  fi
  step "$pkg-configure" cmake -S "$PKG" -B "$BUILD" \
    -DCMAKE_PREFIX_PATH="$VENV" -DCMAKE_INSTALL_PREFIX="$VENV" \
    -DPython3_EXECUTABLE="$VENV/bin/python" -DBUILD_TESTING=OFF
  step "$pkg-build" cmake --build "$BUILD" -j "$(nproc 2>/dev/null || echo 2)"
  step "$pkg-install" cmake --install "$BUILD"
done

IMPORTS="import rclpy, formic_interfaces.msg, simulation_interfaces.srv, simulation_interfaces.action, tf2_msgs.msg"
say "checking: $IMPORTS"
if ! (cd / && "$VENV/bin/python" -c "$IMPORTS") >"$LOGS/import-check.log" 2>&1; then
  echo "setup: ERROR: '$VENV/bin/python -c \"$IMPORTS\"' failed:" >&2
  cat "$LOGS/import-check.log" >&2
  exit 1
fi

echo "$stamp" >"$STAMP_FILE"
say "done in $((SECONDS - t_start)) s"
