#!/usr/bin/env bash
# Set up ./.venv and run the main job: the acrobot SEAGuL-vs-uniform experiment with its report.
# Extra arguments go to `seagul reproduce` (e.g. --preset paper --seeds 20 --workers 2).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/seagul reproduce acrobot --preset quick "$@"
