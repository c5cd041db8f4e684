#!/usr/bin/env bash
# Set up .venv at the repository root: CPU torch first (so pip does not pull a CUDA build), then the project.
# Running it again is harmless and fast: it reinstalls only when pyproject.toml changed.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
TORCH_VERSION=2.13.0
if [ ! -x .venv/bin/python ]; then
  echo "setup: creating .venv"
  "$PY" -m venv .venv
fi
stamp=.venv/.ges-setup-stamp
want="$(cat pyproject.toml setup.py scripts/setup.sh | sha256sum | cut -c1-16)"
if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then
  echo "setup: .venv is up to date"
  exit 0
fi
# pip's own exit status decides (a failed install stops setup); only its "WARNING: Location" noise is dropped.
pip() {
  local status=0
  .venv/bin/python -m pip --disable-pip-version-check -q "$@" > .venv/.pip-log 2>&1 || status=$?
  grep -v "^WARNING: Location" .venv/.pip-log || true
  return "$status"
}
echo "setup: installing torch==$TORCH_VERSION (CPU) and the project; this takes about a minute"
pip install --upgrade pip setuptools wheel
pip install "torch==$TORCH_VERSION"
pip install -e ".[all,test]"  # every simulator and hand asset (the extras: pyproject.toml)
# the engines' import chatter (Vulkan fallback, PyBullet build time) is shown only if the check fails
check=$(.venv/bin/python -c "import torch, sapien, pybullet, mujoco, gymnasium_robotics, pytorch_kinematics, rsl_rl, ges_core" 2>&1) \
  || { echo "$check" >&2; echo "setup: import check failed; see the pip output above" >&2; exit 1; }
echo "$want" > "$stamp"
echo "setup: done"
