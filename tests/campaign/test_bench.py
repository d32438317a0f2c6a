"""``cam2sim bench`` end to end on a two-street CPU suite with tiny settings.

A built-in street and a street picked from an OSM file the test writes (the demo world's own
extract), one seed, a 10-step splat and a one-epoch DAVE-2: what matters here is the plumbing
(the worlds run through the campaign pool, their figures, the aggregate table with its
intervals, the report, the resume, a world that fails), not the driving.
"""

from __future__ import annotations

import csv
import json
from typing import TYPE_CHECKING

import pytest

from cam2sim.map.convert import has_carla
from conftest import has_egl

if TYPE_CHECKING:
    from pathlib import Path

pytestmark = pytest.mark.skipif(
    not (has_carla() and has_egl()), reason="the bench needs carla (map) and headless OpenGL"
)

SUITE = """
name: tiny
seeds: 1
worlds:
  - builtin: l-street
    tuned: true
  - osm: maps/street.osm
  - osm: maps/fields.osm
settings:
  ads_epochs: 1
  splat_steps: 10
  profile_every_m: 40
timeout_s: 900
"""

FIELDS = """<?xml version="1.0" encoding="UTF-8"?>
<osm version="0.6">
  <node id="1" lat="48.1" lon="11.5"/><node id="2" lat="48.101" lon="11.5"/>
  <way id="10"><nd ref="1"/><nd ref="2"/><tag k="highway" v="footway"/></way>
</osm>
"""


@pytest.fixture(scope="module")
def bench(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object]:
    from cam2sim.campaign.bench import execute_world, run_bench
    from cam2sim.campaign.executors import LocalPool
    from cam2sim.demo.world import demo_street, demo_world

    root = tmp_path_factory.mktemp("bench")
    (root / "maps").mkdir()
    xml = demo_world(0, demo_street("l-street")).osm_xml()
    (root / "maps" / "street.osm").write_text(xml, encoding="utf-8")
    (root / "maps" / "fields.osm").write_text(FIELDS, encoding="utf-8")
    (root / "suite.yaml").write_text(SUITE, encoding="utf-8")
    seen: list[tuple[str, int, int | None]] = []
    result = run_bench(
        root / "suite.yaml",
        output=root / "out",
        executor=LocalPool(1, task=execute_world),
        progress=lambda *a: seen.append(a),
    )
    assert seen[0] == ("benchmark worlds", 0, 3)
    assert seen[-1] == ("benchmark worlds", 3, 3)
    return root, result


def test_every_world_runs_the_whole_experiment(bench: tuple[Path, object]) -> None:  # noqa: PLR0915
    from cam2sim.campaign.suite import expand_suite, load_suite
    from cam2sim.metrics.benchmark import WorldResult
    from cam2sim.report.bench import steering_gap_peak

    root, result = bench
    specs = {s.label: s for s in expand_suite(load_suite(root / "suite.yaml"), root)}
    assert specs["l-street"].run_seed != specs["street-r0"].run_seed
    assert (result.worlds, result.ran, result.failed) == (3, 3, 1)  # type: ignore[attr-defined]
    labels = [w.label for w in result.results]  # type: ignore[attr-defined]
    assert labels == ["l-street", "street-r0"]
    for label in labels:
        world = WorldResult.load(root / "out" / "worlds" / label / "result.json")
        assert {m.method for m in world.methods} == {"Real", "splat", "Sim"}
        real = world.method("Real")
        assert real is not None
        assert (real.recorded, real.closed_loop_runs) == (1, 1)
        for row in world.methods:  # each completed run's Min-Fréchet, for the ratio's interval
            if row.min_frechet_m is None:
                assert row.min_frechet_runs_m == []
            else:
                runs = row.min_frechet_runs_m
                assert sum(runs) / len(runs) == pytest.approx(row.min_frechet_m)
            # Every completed closed-loop run but Real's is measured against its Real twin.
            twins = row.twin_frechet_runs_m
            if row.method == "Real":
                assert twins == []
            else:
                assert len(twins) == len(row.min_frechet_runs_m)
                assert all(t >= 0.0 for t in twins)
        assert world.splat_steps
        # Each chunk's street Gaussians at its start and end (what a training step costs).
        assert len(world.splat_gaussians) == len(world.splat_start_gaussians)
        assert len(world.splat_gaussians) == len(world.splat_steps)
        assert all(n > 0 for n in world.splat_start_gaussians)
        assert set(world.splat_stopped) == {"max_steps"}
        assert world.splat_held_out_psnr_db is not None
        # The splat against the truth every 10 m, on the path and 1 m to each side.
        assert world.profile is not None
        assert world.profile["offsets_m"] == [-1.0, 0.0, 1.0]
        assert len(world.profile["s_m"]) >= 5  # type: ignore[arg-type]
        # The drives' DAVE-2 asked for its steering on both views at every station.
        assert str(world.profile["policy"]).endswith("dave2.onnx")
        for key in ("steering_truth", "steering_splat"):
            rows = world.profile[key]
            assert len(rows) == 3  # type: ignore[arg-type]
            assert all(v is not None for v in rows[1])  # type: ignore[index]
        assert steering_gap_peak(world) is not None
        for failure in world.failures:
            assert failure.kind
            assert failure.reason  # the events say what happened
            assert failure.image is not None
            assert (root / "out" / "worlds" / label / failure.image).is_file()
            assert failure.views == ["splat", "truth", "raster"]
        assert world.tuned == (label == "l-street")
        # Each street's closed-loop runs are seeded from its label (all cameras alike).
        drives = (root / "out" / "worlds" / label / "ws" / "runs").glob("*-drive-*/run.json")
        seeds = {json.loads(p.read_text())["seed"] for p in drives}
        assert seeds == {specs[label].run_seed}
        # The result names the world that made it (a changed suite runs it again).
        assert (world.spec_id, world.run_seed) == (specs[label].spec_id, specs[label].run_seed)
        assert "recording" in world.step_seconds
        assert "report" not in world.step_seconds  # the world's own report is left out


def test_the_aggregate_table_holds_counts_and_wilson_intervals(
    bench: tuple[Path, object],
) -> None:
    from cam2sim.metrics.benchmark import wilson_interval

    root, result = bench
    agg = result.aggregate  # type: ignore[attr-defined]
    assert agg.streets == 2
    for rate in agg.rates:
        assert rate.runs == 2  # one closed-loop run a street: the recorded drive is not counted
        assert (rate.low, rate.high) == pytest.approx(wilson_interval(rate.failures, rate.runs))
    with (root / "out" / "tables" / "rates.csv").open(encoding="utf-8") as f:
        rows = {r["method"]: r for r in csv.DictReader(f)}
    assert set(rows) == {"Real", "splat", "Sim"}
    for rate in agg.rates:
        assert int(rows[rate.method]["failures"]) == rate.failures
        assert float(rows[rate.method]["95% high"]) == pytest.approx(rate.high, abs=5e-4)
    saved = json.loads((root / "out" / "aggregate.json").read_text(encoding="utf-8"))
    assert saved["verdict"] == agg.verdict
    assert agg.verdict.startswith("splat indistinguishable from Real on ")
    assert [p.label for p in agg.pairs] == ["l-street", "street-r0"]


def test_the_report_shows_the_verdict_the_streets_and_the_world_that_failed(
    bench: tuple[Path, object],
) -> None:
    from cam2sim.metrics.benchmark import WorldResult

    root, result = bench
    page = (root / "out" / "report.html").read_text(encoding="utf-8")
    assert result.aggregate.verdict in page  # type: ignore[attr-defined]
    for label in ("l-street", "street-r0"):
        assert f'id="w-{label}"' in page
    assert "fields-r0" in page  # the world without a result, with why
    assert "no drivable road" in page
    assert page.count("data:image/png;base64") >= 3  # the rates and two route profiles
    summary = (root / "out" / "summary.md").read_text(encoding="utf-8")
    assert "## Worlds without a result" in summary
    with (root / "out" / "tables" / "splat.csv").open(encoding="utf-8") as f:
        counts = {r["street"]: r["Gaussians a chunk k"] for r in csv.DictReader(f)}
    for label in ("l-street", "street-r0"):  # thousands, start-end, a chunk each
        world = WorldResult.load(root / "out" / "worlds" / label / "result.json")
        assert counts[label].count("-") == len(world.splat_steps)
    assert "Streets not used while tuning (1)" in summary


def test_a_second_run_redoes_only_the_world_without_a_result(bench: tuple[Path, object]) -> None:
    from cam2sim.campaign.bench import execute_world, run_bench
    from cam2sim.campaign.executors import LocalPool

    root, first = bench
    again = run_bench(
        root / "suite.yaml", output=root / "out", executor=LocalPool(1, task=execute_world)
    )
    assert (again.ran, again.failed) == (1, 1)  # only the failed world is tried again
    assert again.aggregate == first.aggregate  # type: ignore[attr-defined]
    state = json.loads((root / "out" / "state.json").read_text(encoding="utf-8"))
    attempts = {r["workspace"]: r["attempts"] for r in state["runs"].values()}
    assert attempts == {"l-street": 1, "street-r0": 1, "fields-r0": 2}


def test_results_gathered_from_elsewhere_are_reported_without_running_again(
    bench: tuple[Path, object],
) -> None:
    """A suite split over machines: only each world's result.json is copied into one folder."""
    import shutil

    from cam2sim.campaign.bench import execute_world, run_bench
    from cam2sim.campaign.executors import LocalPool

    root, first = bench
    gathered = root / "gathered"
    for label in ("l-street", "street-r0"):
        (gathered / "worlds" / label).mkdir(parents=True)
        shutil.copy(root / "out" / "worlds" / label / "result.json", gathered / "worlds" / label)
    two = SUITE.replace("  - osm: maps/fields.osm\n", "")
    (root / "two.yaml").write_text(two, encoding="utf-8")
    pool = LocalPool(1, task=execute_world)
    result = run_bench(root / "two.yaml", output=gathered, executor=pool)
    assert (result.worlds, result.ran, result.failed) == (2, 0, 0)
    assert result.aggregate.verdict == first.aggregate.verdict  # type: ignore[attr-defined]
    assert result.aggregate.rates == first.aggregate.rates  # type: ignore[attr-defined]
    page = (gathered / "report.html").read_text(encoding="utf-8")
    for label in ("l-street", "street-r0"):
        assert f'id="w-{label}"' in page


def test_a_world_rescored_keeps_its_figures_and_gains_the_twin_distances(
    bench: tuple[Path, object],
) -> None:
    """A result made before a measure existed is scored again from its workspace, not rerun."""
    from cam2sim.campaign.bench import rescore_world
    from cam2sim.core.errors import StageError
    from cam2sim.metrics.benchmark import WorldResult

    root, _ = bench
    world = root / "out" / "worlds" / "l-street"
    before = WorldResult.load(world / "result.json")
    stripped = [m.model_copy(update={"twin_frechet_runs_m": []}) for m in before.methods]
    old = before.model_copy(update={"methods": stripped})  # as a result of an older version
    old.save(world / "result.json")
    again = rescore_world(world)
    assert again.methods == before.methods  # the twin distances back, nothing else moved
    assert again.model_copy(update={"methods": stripped}) == old  # splat, profile, times kept
    with pytest.raises(StageError, match="run the world with `cam2sim bench` first"):
        rescore_world(root / "out" / "worlds" / "fields-r0")  # a world that failed
    before.save(world / "result.json")
