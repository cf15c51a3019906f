#!/usr/bin/env bash
# One-time set-up on a fresh machine (idempotent): Debian GL libraries for headless
# rendering and a C compiler (the distance-field wall's contact test is compiled on first
# use), a virtual environment in .venv, the CPU build of PyTorch, this package.
set -euo pipefail
cd "$(dirname "$0")/.."

DEBIAN_PACKAGES="libegl1 libgl1-mesa-dri libopengl0 libosmesa6 gcc libc6-dev"
missing=""
for pkg in $DEBIAN_PACKAGES; do
  dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "ok installed" || missing="$missing $pkg"
done
if [ -n "$missing" ]; then
  if [ "$(id -u)" = 0 ]; then SUDO=""; else SUDO="sudo"; fi
  echo "installing Debian packages (headless GL, C compiler):$missing"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq $missing >/dev/null
fi

PYTHON="${PYTHON:-python3}"
if [ ! -x .venv/bin/python ]; then
  "$PYTHON" -m venv .venv
fi
# A stamp of the dependency files: reinstall only when they change.
stamp=".venv/.cathsim-installed"
want="$(cat pyproject.toml scripts/setup.sh | sha256sum | cut -d' ' -f1)"
# pip's own failures must stop the script; only its noise about local mirrors is hidden.
pip_install() { .venv/bin/python -m pip install -q "$@" 2> >(grep -v "is ignored" >&2); }
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  pip_install --upgrade pip
  # CPU PyTorch first: otherwise stable-baselines3 pulls a multi-GB CUDA build.
  pip_install torch==2.13.0
  pip_install -e ".[test]"
  .venv/bin/python -c "import cathsim_dmc, torch, mujoco; print('cathsim-dmc ready: mujoco', mujoco.__version__, 'torch', torch.__version__)"
  echo "$want" > "$stamp"
fi
