# The two entry points of the README: `make run` and `make test`.
.PHONY: run test setup runtime

# What running needs: ONNX Runtime (from the PyPI wheel).
runtime:
	./scripts/setup.sh ort

# What testing needs besides: gltf-validator (npm) and headless Blender (PyPI bpy).
setup:
	./scripts/setup.sh

# The HTTP service on the embedded default (SQLite + files under ./data).
# Extra flags: make run ARGS="--bind 0.0.0.0:8080 --workers 8"
run: runtime
	cargo run --release -- serve $(ARGS)

# Format and lints first (cheap, and a red one is the first thing to fix), then every test.
test: setup
	cargo fmt --check
	cargo clippy --release --all-targets -- -D warnings
	cargo test --release --no-fail-fast
