#!/usr/bin/env bash
# The default test suite (7-19 minutes on 2 cores, by machine). Slow tests: scripts/test.sh -m slow
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/python -m pytest -q "$@"
