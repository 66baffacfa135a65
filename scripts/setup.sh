#!/usr/bin/env bash
# Installs what the tests use beyond cargo: the Khronos glTF validator, playwright-core
# and three.js (npm), headless Chromium (Debian `chromium`, for the viewer page tests)
# and headless Blender (PyPI bpy). Idempotent: a second run only checks.
set -euo pipefail
cd "$(dirname "$0")/.."

# `setup.sh ort` fetches only what running the service needs (ONNX Runtime).
only_ort=${1:-}

npm_missing() {
  for p in gltf-validator ajv playwright-core three; do
    [ -d "tools/node_modules/$p" ] || return 0
  done
  return 1
}

if [ "$only_ort" != "ort" ] && npm_missing; then
  echo "setup: installing gltf-validator, playwright-core and three (npm)"
  npm ci --prefix tools --no-audit --no-fund --loglevel=error || npm install --prefix tools --no-audit --no-fund --loglevel=error
fi

if [ "$only_ort" != "ort" ] && [ ! -x /usr/bin/chromium ]; then
  echo "setup: installing chromium (apt; the viewer page tests drive it headless)"
  sudo_cmd=""
  [ "$(id -u)" -eq 0 ] || sudo_cmd=sudo
  $sudo_cmd apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo_cmd apt-get install -y -qq chromium
fi

if [ "$only_ort" != "ort" ] && ! python3 -c "import bpy" >/dev/null 2>&1; then
  echo "setup: installing bpy==5.0.1 (headless Blender, about 400 MB)"
  python3 -m pip install --quiet --disable-pip-version-check bpy==5.0.1
fi

# ONNX Runtime for the `ort` crate (load-dynamic): the shared library from the PyPI
# wheel, unpacked into .onnxruntime/ (git-ignored). RIGSERVE_ORT_LIB points at it.
ORT_LIB=.onnxruntime/libonnxruntime.so.1.31.1
if [ ! -f "$ORT_LIB" ]; then
  echo "setup: fetching onnxruntime==1.31.1 (PyPI wheel) for libonnxruntime.so"
  tmp=$(mktemp -d)
  python3 -m pip download --quiet --disable-pip-version-check --no-deps --only-binary=:all: -d "$tmp" onnxruntime==1.31.1
  mkdir -p .onnxruntime
  python3 - "$tmp" <<'PY'
import glob, sys, zipfile
wheel = glob.glob(sys.argv[1] + "/onnxruntime-1.31.1-*.whl")[0]
with zipfile.ZipFile(wheel) as z:
    name = "onnxruntime/capi/libonnxruntime.so.1.31.1"
    open(".onnxruntime/libonnxruntime.so.1.31.1", "wb").write(z.read(name))
PY
  rm -rf "$tmp"
fi
