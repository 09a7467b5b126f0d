#!/usr/bin/env bash
# Run the test suite: prepares the environment if needed, then pytest from the repo root on two
# workers (pytest-xdist: most tests wait on processes and ROS, so two side by side halve the wall
# time on two cores); `scripts/test.sh -n 0` runs them in one process.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$ROOT/scripts/setup.sh"
cd "$ROOT"
exec .venv/bin/python -m pytest -q -n 2 "$@"
