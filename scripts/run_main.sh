#!/usr/bin/env bash
# Set up (if needed) and run the main job on built-in data:
#   1. both hands close on a box in both simulators (contact forces printed);
#   2. Stage 1 demo: grasps synthesized and validated for 20 built-in objects with both hands,
#      written to runs/demo/ (dataset, a picture per grasp, contact sheet, Table-1 style summary).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/ges sim check --hand shadow --hand allegro --sim sapien --sim pybullet
.venv/bin/ges demo "$@"
