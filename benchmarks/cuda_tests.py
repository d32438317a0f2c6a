"""Run the CUDA training tests on a GPU machine whose image lacks the test suite's packages.

The tests' ``conftest.py`` needs packages the GPU image does not have, so this calls the CUDA
tests of ``tests/splat/test_train.py`` directly, reports each one, and exits 1 if any failed.
It is a file (not a here-document) with a ``__main__`` guard because training on CUDA trains
two chunks at once in spawned worker processes, and a spawned child re-imports the parent's
main module by its path.

    CUDA_VISIBLE_DEVICES=0 python3 benchmarks/cuda_tests.py > tests.txt
"""

from __future__ import annotations

import sys
import tempfile
import traceback
from pathlib import Path


def main() -> int:
    """Run the four CUDA training tests; return 1 if any failed."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "splat"))
    import test_train as t  # noqa: PLC0415 -- only in the parent, not in spawned workers

    grows = t.test_mcmc_training_grows_to_its_cap_and_learns
    cases = [
        ("gsplat densifies and resets", t.test_gsplat_training_densifies_and_resets, ()),
        ("mcmc, opacity draw", grows, (0.0, False)),
        ("mcmc, error-weighted draw", grows, (1.0, False)),
        ("mcmc, moments inherited", grows, (0.0, True)),
    ]
    failed = 0
    for name, test, args in cases:
        with tempfile.TemporaryDirectory() as tmp:
            try:
                test(Path(tmp), *args)
                print("PASSED", name, flush=True)
            except Exception:  # noqa: BLE001 -- report every failure, run every case
                failed += 1
                print("FAILED", name, flush=True)
                traceback.print_exc()
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
