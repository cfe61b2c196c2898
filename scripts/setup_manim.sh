#!/usr/bin/env bash
# Install Manim Community Edition for visphy's `manim` engine (idempotent):
#   apt: libcairo2-dev libpango1.0-dev pkg-config   (pycairo / manimpango build against them)
#   pip: manim>=0.18,<0.23 into .venv               (no LaTeX: Text works, MathTex does not)
# Usage: scripts/setup_manim.sh        (called by the project's setup; safe to re-run)
set -euo pipefail
cd "$(dirname "$0")/.."

PIP=".venv/bin/pip"
if [ ! -x "$PIP" ]; then
  echo "[setup_manim] .venv is missing: run scripts/setup.sh first" >&2
  exit 1
fi

SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null 2>&1; then
    SUDO="sudo"
  else
    echo "[setup_manim] not root and no sudo: apt-get may fail" >&2
  fi
fi

need_apt=()
for pkg in libcairo2-dev libpango1.0-dev pkg-config; do
  dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || need_apt+=("$pkg")
done
if [ "${#need_apt[@]}" -gt 0 ]; then
  echo "[setup_manim] apt-get install -y ${need_apt[*]}"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${need_apt[@]}" >/dev/null
fi

echo "[setup_manim] $PIP install 'manim>=0.18,<0.23'"
"$PIP" install -q --disable-pip-version-check "manim>=0.18,<0.23"   # no-op when satisfied
.venv/bin/python -c "import manim; print('[setup_manim] manim', manim.__version__, 'ready')"
