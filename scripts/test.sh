#!/usr/bin/env bash
# Set up ./.venv and run the default test suite (slow tests are opt-in: `-m slow`).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/python -m ruff check .
exec .venv/bin/python -m pytest -n 2 -q "$@"
