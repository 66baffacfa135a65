#!/usr/bin/env bash
# Copies the three.js modules the viewer page imports from tools/node_modules/three (the
# version pinned in tools/package.json) into web/vendor/three, keeping the package's
# layout so the modules' own relative imports resolve unchanged. The binary embeds
# web/vendor (src/api/viewer.rs), so the page needs no CDN at run time.
# Run after changing the pinned version; tests/viewer.rs checks the copies match.
set -euo pipefail
cd "$(dirname "$0")/.."
src=tools/node_modules/three
dst=web/vendor/three
[ -d "$src" ] || { echo "run: npm install --prefix tools" >&2; exit 1; }
for f in LICENSE build/three.module.js build/three.core.js \
         examples/jsm/loaders/GLTFLoader.js examples/jsm/controls/OrbitControls.js \
         examples/jsm/utils/BufferGeometryUtils.js examples/jsm/utils/SkeletonUtils.js; do
  mkdir -p "$dst/$(dirname "$f")"
  cp "$src/$f" "$dst/$f"
done
node -e 'console.log(require("./tools/node_modules/three/package.json").version)' > "$dst/VERSION"
