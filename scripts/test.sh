#!/usr/bin/env bash
# The default test suite (under ~10 minutes on 2 cores). Slow tests: scripts/test.sh -m slow
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/python -m pytest -q "$@"
