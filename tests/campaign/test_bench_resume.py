"""Which results ``cam2sim bench`` takes as done: only those the same world made."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from cam2sim.campaign.bench import _set_aside_stale, bench_folder
from cam2sim.campaign.suite import expand_suite, load_suite
from cam2sim.metrics.benchmark import MethodRow, WorldResult

if TYPE_CHECKING:
    from pathlib import Path

SUITE = """
name: s
seeds: 3
worlds:
  - builtin: l-street
  - builtin: paper
"""


def _result(label: str, spec_id: str) -> WorldResult:
    real = MethodRow(
        method="Real", runs=4, failures=0, recorded=1, completion_mean=1.0, min_frechet_m=0.1,
        corridor_violation_pct=50.0, jitter=0.9,
    )  # fmt: skip
    return WorldResult(
        label=label, spec_id=spec_id, title=label, tuned=False, source="built-in",
        seconds=1.0, methods=[real],
    )  # fmt: skip


def test_a_result_of_another_version_of_the_world_is_kept_aside_and_run_again(
    tmp_path: Path, caplog: object
) -> None:
    suite = tmp_path / "suite.yaml"
    suite.write_text(SUITE, encoding="utf-8")
    specs = expand_suite(load_suite(suite), tmp_path)
    folder = bench_folder(suite, tmp_path / "out")
    same, other = (folder / "worlds" / s.label / "result.json" for s in specs)
    _result("l-street", specs[0].spec_id).save(same)
    # The paper street's result was made with shared seeds (another id): no longer this world.
    _result("paper", "paper-0123456789").save(other)
    with caplog.at_level(logging.WARNING):  # type: ignore[attr-defined]
        _set_aside_stale(folder, specs)
    assert same.is_file()  # made by this very world: done
    assert not other.is_file()  # runs again ...
    kept = other.with_name("result.0123456789.json")
    assert WorldResult.load(kept).spec_id == "paper-0123456789"  # ... and nothing is lost
    assert "made by another version" in caplog.text  # type: ignore[attr-defined]
    # A result from before the ids were recorded counts as done, as it did.
    _result("paper", "").save(other)
    _set_aside_stale(folder, specs)
    assert other.is_file()
