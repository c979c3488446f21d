#!/usr/bin/env bash
# Set up ./.venv, lint (ruff), type-check (mypy), build the documentation site (mkdocs --strict) and run the default
# test suite (slow tests are opt-in: `-m slow`).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/python -m ruff check .
.venv/bin/python -m mypy seagul_envs seagul_control seagul_learn
NO_MKDOCS_2_WARNING=1 .venv/bin/python -m mkdocs build --strict --quiet --site-dir "$(mktemp -d)"
exec .venv/bin/python -m pytest -n 2 -q "$@"
