#!/usr/bin/env bash
# Installs what the tests use beyond cargo: the Khronos glTF validator (npm) and
# headless Blender (PyPI bpy). Idempotent: a second run only checks.
set -euo pipefail
cd "$(dirname "$0")/.."

if [ ! -d tools/node_modules/gltf-validator ]; then
  echo "setup: installing gltf-validator (npm)"
  npm ci --prefix tools --no-audit --no-fund --loglevel=error || npm install --prefix tools --no-audit --no-fund --loglevel=error
fi

if ! python3 -c "import bpy" >/dev/null 2>&1; then
  echo "setup: installing bpy==5.0.1 (headless Blender, about 400 MB)"
  python3 -m pip install --quiet --disable-pip-version-check bpy==5.0.1
fi
