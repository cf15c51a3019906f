#!/usr/bin/env bash
# The main job on a built-in default. Extra arguments are Hydra overrides.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/cathsim-eval task=bca aorta=type1 policy=forward episodes=1 "$@"
