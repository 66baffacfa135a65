#!/usr/bin/env bash
# Unpacks libonnxruntime.so.1.31.1 from the PyPI wheel onnxruntime==1.31.1 into DIR.
# One script for the checkout (setup.sh), the image (Dockerfile) and its mirror
# (image_build.sh), so all three load the same library. pip picks the wheel of the
# machine it runs on, which is what lets the Dockerfile build for arm64 too.
set -euo pipefail
dest=${1:?usage: fetch_ort.sh DIR}
lib="$dest/libonnxruntime.so.1.31.1"
[ -f "$lib" ] && exit 0
echo "fetch_ort: onnxruntime==1.31.1 (PyPI wheel) -> $lib"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
python3 -m pip download --quiet --disable-pip-version-check --no-deps --only-binary=:all: \
  -d "$tmp" onnxruntime==1.31.1
mkdir -p "$dest"
python3 - "$tmp" "$lib" <<'PY'
import glob, os, sys, zipfile
wheel = glob.glob(sys.argv[1] + "/onnxruntime-1.31.1-*.whl")[0]
# Written under a temporary name and renamed: a half-written library is never loaded.
part = sys.argv[2] + ".part"
with zipfile.ZipFile(wheel) as z, open(part, "wb") as out:
    out.write(z.read("onnxruntime/capi/libonnxruntime.so.1.31.1"))
os.chmod(part, 0o644)
os.replace(part, sys.argv[2])
PY
