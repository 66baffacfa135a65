#!/usr/bin/env bash
# Rebuilds the committed skeleton library, models/library.bin, from the `train` split of
# ../shared/rigs (and, when given, more data sets with a `train` split, such as the corpus
# training/corpus rebuilds). Share-alike rigs train models but are not shipped in the
# library, and mobs_lava_flan is left out because its source's licence file names its
# model CC BY-SA 3.0 (Zeg9), whatever the manifest says. Every entry must be credited in
# models/NOTICE; tests/shipped_models.rs checks that it is.
#
#   scripts/build_library.sh [DATASET...]
set -euo pipefail
cd "$(dirname "$0")/.."
args=(--dataset ../shared/rigs)
for d in "$@"; do args+=(--dataset "$d"); done
cargo run --release --quiet --bin rigserve -- library "${args[@]}" --split train \
  --exclude-license BY-SA --exclude mobs_lava_flan.glb --out models/library.bin
sha256sum models/library.bin
