# The two entry points of the README: `make run` and `make test`.
.PHONY: run test setup

setup:
	./scripts/setup.sh

run:
	cargo run --release -- $(ARGS)

test: setup
	cargo test --release --no-fail-fast
