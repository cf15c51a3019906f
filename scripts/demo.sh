#!/usr/bin/env bash
# The main job on a built-in default: a short SAC run that ends with an evaluation
# report (too short to learn the task; see the README for full-length commands).
# Extra arguments are Hydra overrides.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/cathsim-train task=bca aorta=type1 obs=internal trainer.total_timesteps=3000 \
  trainer.eval_episodes=5 "$@"
