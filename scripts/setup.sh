#!/usr/bin/env bash
# Install everything visphy needs on a Debian machine with Python 3.11:
#   system packages (Chromium, fonts, Node.js/npm), a virtual environment in .venv with visphy
#   and its extras, and the vendored JavaScript libraries (npm ci into visphy's asset cache).
# Usage: scripts/setup.sh [extra[,extra...]]     e.g. scripts/setup.sh test
set -euo pipefail
cd "$(dirname "$0")/.."
EXTRAS="${1:-}"
PY="${PYTHON:-python3.11}"
command -v "$PY" >/dev/null 2>&1 || PY=python3

SUDO=""
[ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null 2>&1 && SUDO="sudo"
need_apt=()
command -v chromium >/dev/null 2>&1 || need_apt+=(chromium)
command -v npm >/dev/null 2>&1 || need_apt+=(nodejs npm)
[ -e /usr/share/fonts/truetype/dejavu/DejaVuSans.ttf ] || need_apt+=(fonts-dejavu-core)
command -v bwrap >/dev/null 2>&1 || need_apt+=(bubblewrap)  # process sandbox (Manim, Blender)
# the sandboxes' seccomp filter: libseccomp's Python binding (for the system python3)
/usr/bin/python3 -c "import seccomp" >/dev/null 2>&1 || need_apt+=(python3-seccomp)
if [ "${#need_apt[@]}" -gt 0 ]; then
  echo "[setup] apt-get install ${need_apt[*]}"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${need_apt[@]}" >/dev/null
fi

if [ ! -x .venv/bin/python ]; then
  echo "[setup] creating .venv with $PY"
  "$PY" -m venv .venv
fi
# torch first, pinned: on these machines this pair comes from the local wheel store and runs on
# the CPU (never mix the CPU-only torch 2.13.0 with a torchvision). Elsewhere override it, e.g.
# VISPHY_TORCH="torch torchvision" for the newest pair of your index.
TORCH_SPEC="${VISPHY_TORCH:-torch==2.14.1 torchvision==0.29.1}"
if ! .venv/bin/python -c "import torch, torchvision" >/dev/null 2>&1; then
  echo "[setup] pip install $TORCH_SPEC"
  # shellcheck disable=SC2086
  .venv/bin/python -m pip install -q --disable-pip-version-check $TORCH_SPEC
fi
spec="."
[ -n "$EXTRAS" ] && spec=".[$EXTRAS]"
echo "[setup] pip install -e '$spec'"
.venv/bin/python -m pip install -q --disable-pip-version-check -e "$spec"
bash scripts/setup_manim.sh
bash scripts/setup_blender.sh
.venv/bin/python -m visphy_core setup
