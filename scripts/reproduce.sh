#!/usr/bin/env bash
# Set up ./.venv and run the main job: the acrobot's shipped controller in closed loop beside LQR and the
# full-horizon MPC, then the quick equal-budget comparison of the samplers, and the report.
# Extra arguments go to `seagul reproduce` (e.g. --preset paper --seeds 20 --workers 2, --shipped-jit).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/seagul reproduce acrobot --preset quick "$@"
