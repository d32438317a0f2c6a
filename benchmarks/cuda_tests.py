"""Run the CUDA training tests on a GPU machine whose image lacks the test suite's packages.

The tests' ``conftest.py`` needs packages the GPU image does not have, so this calls the CUDA
tests of ``tests/splat/test_train.py`` (those marked ``requires_cuda``, every
parametrized case) directly, reports each one, and exits 1 if any failed
or skipped (on a machine without gsplat or a GPU nothing was tested).
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
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Callable


def cases_of(test: Callable[..., None]) -> list[tuple[str, tuple[object, ...]]]:
    """The test's cases: one per ``pytest.mark.parametrize`` value, or one without arguments."""
    for mark in getattr(test, "pytestmark", []):
        if mark.name == "parametrize":
            values = mark.args[1]
            return [(f"{test.__name__}{list(v)}", tuple(v)) for v in values]
    return [(test.__name__, ())]


def main() -> int:
    """Run the CUDA training tests (every parametrized case); return 1 if any failed."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "splat"))
    import pytest  # noqa: PLC0415
    import test_train as t  # noqa: PLC0415 -- only in the parent, not in spawned workers

    tests = [  # those marked requires_cuda; each takes tmp_path alone
        f
        for name, f in vars(t).items()
        if name.startswith("test_")
        and any(m.name == "requires_cuda" for m in getattr(f, "pytestmark", []))
    ]
    cases = [(name, test, args) for test in tests for name, args in cases_of(test)]
    failed = 0
    for name, test, args in cases:
        with tempfile.TemporaryDirectory() as tmp:
            try:
                test(Path(tmp), *args)
                print("PASSED", name, flush=True)
            except pytest.skip.Exception as skip:  # no gsplat, no GPU: nothing was tested
                failed += 1
                print("SKIPPED", name, "--", skip.msg, flush=True)
            except Exception:  # noqa: BLE001 -- report every failure, run every case
                failed += 1
                print("FAILED", name, flush=True)
                traceback.print_exc()
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
