#!/usr/bin/env bash
# The default test suite, one pytest worker per core (at most 4: each worker holds its own
# MuJoCo, dm_control and torch). 2 cores: about 15 min of pytest on a fresh clone (docs/install.md).
# Slow tests: scripts/test.sh -m slow. One process: scripts/test.sh -n 0
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# --durations: the slowest tests, printed last, to keep the default suite near ten minutes.
exec .venv/bin/python -m pytest -q -n auto --maxprocesses 4 --durations=20 "$@"
