#!/usr/bin/env bash
# Run ForMIC-ROS: prepares the environment if needed, then `formic run ARGS...`.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$ROOT/scripts/setup.sh" --quiet
exec "$ROOT/.venv/bin/formic" run "$@"
