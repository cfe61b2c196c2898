#!/usr/bin/env bash
# Create Blender's own virtual environment for the `blender` engine (plugins/engines/blender.py).
#
# bpy ships as a cp311 wheel (~940 MB installed) that needs numpy < 2, which conflicts with the
# main .venv (numpy 2, manim), so Blender lives in a separate venv and runs as a subprocess.
#
#   venv:    ${VISPHY_BLENDER_VENV:-$HOME/.cache/visphy/blender-venv}
#   pinned:  bpy==${VISPHY_BPY_VERSION:-5.0.1} (newest cp311 wheel on PyPI here), numpy<2
#
# Idempotent: does nothing when the venv's python already imports bpy. Prints what it did.
# Usage: scripts/setup_blender.sh [--force]      (--force recreates the venv)
set -euo pipefail

VENV="${VISPHY_BLENDER_VENV:-$HOME/.cache/visphy/blender-venv}"
BPY_VERSION="${VISPHY_BPY_VERSION:-5.0.1}"
PY="${PYTHON:-python3.11}"
FORCE=0
[ "${1:-}" = "--force" ] && FORCE=1

if [ "$FORCE" -eq 0 ] && [ -x "$VENV/bin/python" ] && \
   "$VENV/bin/python" -c "import bpy" >/dev/null 2>&1; then
  ver="$("$VENV/bin/python" -c "import bpy; print(bpy.app.version_string)" 2>/dev/null | tail -n 1)"
  echo "[setup_blender] already set up: $VENV (bpy $ver); nothing to do"
  exit 0
fi

command -v "$PY" >/dev/null 2>&1 || { echo "[setup_blender] error: $PY not found (bpy wheels are cp311 only)" >&2; exit 1; }
pyver="$("$PY" -c 'import sys; print("%d.%d" % sys.version_info[:2])')"
if [ "$pyver" != "3.11" ]; then
  echo "[setup_blender] error: $PY is Python $pyver; bpy $BPY_VERSION needs Python 3.11" >&2
  exit 1
fi

start=$(date +%s)
if [ "$FORCE" -eq 1 ] && [ -d "$VENV" ]; then
  echo "[setup_blender] removing $VENV (--force)"
  rm -rf "$VENV"
fi
if [ ! -x "$VENV/bin/python" ]; then
  echo "[setup_blender] creating venv $VENV with $PY"
  mkdir -p "$(dirname "$VENV")"
  "$PY" -m venv "$VENV"
fi
echo "[setup_blender] pip install bpy==$BPY_VERSION 'numpy<2' (~1 GB download)"
# (pip's warnings about absent local find-links folders are filtered out)
"$VENV/bin/python" -m pip install -q --disable-pip-version-check "bpy==$BPY_VERSION" "numpy<2" 2>&1 \
  | { grep -v "is ignored: it is neither a file nor a directory" || true; }

# Sanity check: bpy imports and the Workbench engine renders one tiny frame in background mode.
"$VENV/bin/python" - 2>&1 <<'EOF' | { grep -v -E "^EGL Error|Saved: '" || true; }
import os, tempfile
import bpy
bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
scene.collection.objects.link(cam)
scene.camera = cam
scene.render.engine = "BLENDER_WORKBENCH"
scene.render.resolution_x = scene.render.resolution_y = 8
out = os.path.join(tempfile.mkdtemp(), "probe.png")
scene.render.filepath = out
bpy.ops.render.render(write_still=True)
assert os.path.getsize(out) > 0
os.remove(out)
os.rmdir(os.path.dirname(out))
import numpy
print(f"[setup_blender] bpy {bpy.app.version_string} OK (numpy {numpy.__version__}), "
      "Workbench renders")
EOF
end=$(date +%s)
size="$(du -sh "$VENV" 2>/dev/null | cut -f1)"
echo "[setup_blender] done in $((end - start)) s: $VENV ($size)"
echo "[setup_blender] the blender engine finds it by default; or export VISPHY_BLENDER_PYTHON=$VENV/bin/python"
