#!/usr/bin/env bash
# The main job: set up if needed, then a distributed ForMIC run (`formic run`: world, agent
# host(s) and recorder as separate ROS 2 processes) with the shipped model, recorded to MCAP
# under out/recordings/. Extra arguments go to `formic run` (they win over these defaults).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$ROOT/scripts/setup.sh" --quiet
cd "$ROOT"
exec .venv/bin/formic run --record "out/recordings/run-$(date +%Y%m%d-%H%M%S)" "$@"
