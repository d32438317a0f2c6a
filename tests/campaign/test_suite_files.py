"""The benchmark suites the docs run (benchmarks/suites/*.yaml) load, and name each street once."""

from __future__ import annotations

from pathlib import Path

import pytest

from cam2sim.campaign.suite import expand_suite, load_suite

SUITES = sorted((Path(__file__).parents[2] / "benchmarks" / "suites").glob("*.yaml"))


@pytest.mark.parametrize("path", SUITES, ids=[p.stem for p in SUITES])
def test_a_suite_the_docs_run_loads_and_names_each_street_once(path: Path) -> None:
    suite = load_suite(path)
    labels = [spec.label for spec in expand_suite(suite, path.parent)]
    assert labels
    assert len(set(labels)) == len(labels)


def test_the_preset_suites_cover_the_whole_gpu_suite() -> None:
    """The GPU suite rerun in parts: every street of streets-gpu.yaml in a part, tuned alike.

    (A part may repeat a street an earlier part did not finish: streets-gpu-preset-2's
    West-Oakland and Aguascalientes route 1 ran out of GPU time, and preset-3 lists them.)
    """
    folder = SUITES[0].parent

    def specs(name: str) -> dict[str, bool]:
        path = folder / f"{name}.yaml"
        return {s.label: s.tuned for s in expand_suite(load_suite(path), folder)}

    whole = specs("streets-gpu")
    parts = [specs(f"streets-gpu-preset{tail}") for tail in ("", "-2", "-3", "-4")]
    assert {k: v for part in parts for k, v in part.items()} == whole
    assert not set(parts[2]) & set(parts[3])  # the two parts left for the next sessions
