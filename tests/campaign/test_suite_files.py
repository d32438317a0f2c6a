"""The benchmark suites the docs run (benchmarks/suites/*.yaml) load, and name each street once.

The suites name the project's real OSM extracts beside the checkout; the test points them at
empty stand-ins of the same names, so that it checks the suites wherever the data is.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from cam2sim.campaign.suite import expand_suite, load_suite

SUITES = sorted((Path(__file__).parents[2] / "benchmarks" / "suites").glob("*.yaml"))


def _specs(path: Path, tmp_path: Path) -> dict[str, bool]:
    """Each world's label and whether it was tuned, the extracts stood in for in ``tmp_path``."""
    text = path.read_text()
    for name in re.findall(r"osm: .*/([^/\s]+)\s*$", text, flags=re.MULTILINE):
        (tmp_path / name).touch()
    local = tmp_path / path.name
    local.write_text(re.sub(r"(osm: ).*/([^/\s]+)\s*$", r"\1\2", text, flags=re.MULTILINE))
    specs = expand_suite(load_suite(local), tmp_path)
    labels = [spec.label for spec in specs]
    assert labels
    assert len(set(labels)) == len(labels), f"{path.name} names a street twice: {labels}"
    return {spec.label: spec.tuned for spec in specs}


@pytest.mark.parametrize("path", SUITES, ids=[p.stem for p in SUITES])
def test_a_suite_the_docs_run_loads_and_names_each_street_once(path: Path, tmp_path: Path) -> None:
    _specs(path, tmp_path)


def test_the_preset_suites_cover_the_whole_gpu_suite(tmp_path: Path) -> None:
    """The GPU suite rerun in parts: every street of streets-gpu.yaml in a part, tuned alike.

    (A part may repeat a street an earlier part did not finish: streets-gpu-preset-2's
    West-Oakland and Aguascalientes route 1 ran out of GPU time, and preset-3 lists them.)
    """
    folder = SUITES[0].parent
    whole = _specs(folder / "streets-gpu.yaml", tmp_path)
    parts = [
        _specs(folder / f"streets-gpu-preset{tail}.yaml", tmp_path)
        for tail in ("", "-2", "-3", "-4")
    ]
    assert {k: v for part in parts for k, v in part.items()} == whole
    assert not set(parts[2]) & set(parts[3])  # the two parts left for the next sessions
