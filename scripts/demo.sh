#!/usr/bin/env bash
# The main job on a built-in default: train a specialist for the BCA in the type I arch
# from scratch (SAC with 100 scripted-expert demonstrations mixed into every batch; the
# defaults of conf/train.yaml: 8k steps, about 15 minutes on 2 CPU cores with set-up),
# then report its evaluation over 20 deterministic episodes. Extra arguments are Hydra
# overrides.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/cathsim-train task=bca aorta=type1 "$@"
