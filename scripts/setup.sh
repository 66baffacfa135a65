#!/usr/bin/env bash
# Installs what the tests use beyond cargo: the Khronos glTF validator (npm),
# headless Blender (PyPI bpy) and kubernetes-validate (PyPI). Idempotent: a second
# run only checks.
set -euo pipefail
cd "$(dirname "$0")/.."

# `setup.sh ort` fetches only what running the service needs (ONNX Runtime).
only_ort=${1:-}

if [ "$only_ort" != "ort" ] && [ ! -d tools/node_modules/gltf-validator ]; then
  echo "setup: installing gltf-validator (npm)"
  npm ci --prefix tools --no-audit --no-fund --loglevel=error || npm install --prefix tools --no-audit --no-fund --loglevel=error
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

# ONNX Runtime for the `ort` crate (load-dynamic): the shared library from the PyPI
# wheel, unpacked into .onnxruntime/ (git-ignored). RIGSERVE_ORT_LIB points at it.
./scripts/fetch_ort.sh .onnxruntime
