"""Runs a test module's `test_*` functions without pytest (`python -m training.x.test_y`),
for machines where only the training requirements are installed."""

import sys
import time


def run_tests(namespace: dict) -> None:
    failed = 0
    for name, fn in list(namespace.items()):
        if name.startswith("test_") and callable(fn):
            t = time.time()
            try:
                fn()
                print(f"PASS {name} ({time.time() - t:.1f}s)")
            except Exception as e:  # noqa: BLE001 - report every failure, keep going
                failed += 1
                print(f"FAIL {name}: {type(e).__name__}: {e}")
    sys.exit(1 if failed else 0)
