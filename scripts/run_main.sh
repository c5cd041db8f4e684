#!/usr/bin/env bash
# Set up (if needed) and run the main job on built-in data: both hands in both simulators.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/ges sim check --hand shadow --hand allegro --sim sapien --sim pybullet "$@"
