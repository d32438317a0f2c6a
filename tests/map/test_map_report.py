"""Route fit, warnings, the report artifact and the picture, on a hand-made map."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from cam2sim.core.errors import SchemaVersionError
from cam2sim.map.check import OsmAlignment
from cam2sim.map.query import RoadMap
from cam2sim.map.report import (
    AlignmentReport,
    MapReport,
    SourceReport,
    fit_route,
    plot_map,
    road_counts,
    route_warnings,
)

from .test_map_query import XODR


@pytest.fixture(scope="module")
def road_map() -> RoadMap:
    return RoadMap.from_xodr(XODR)


def test_route_on_its_lane_is_fully_covered(road_map: RoadMap) -> None:
    x = np.arange(0.0, 100.0, 1.0)
    xy = np.stack([x, np.full_like(x, -1.5)], axis=-1)  # 0.25 m left of the lane centre
    fit = fit_route(road_map, xy, x / 10.0, np.zeros_like(x))
    r = fit.report
    assert r.poses == 100
    assert r.length_m == pytest.approx(99.0)
    assert r.covered_length_m == pytest.approx(99.0)
    assert r.covered_fraction == pytest.approx(1.0)
    assert r.on_lane_fraction == pytest.approx(1.0)
    assert r.against_lane_direction_fraction == 0.0
    assert r.lateral_offset.mean_m == pytest.approx(0.25)
    assert r.lateral_offset.max_m == pytest.approx(0.25)
    assert r.off_map_stretch_count == 0
    assert route_warnings(r) == []


def test_route_leaving_the_map_is_reported_in_stretches(road_map: RoadMap) -> None:
    x = np.arange(0.0, 100.0, 1.0)
    y = np.full_like(x, -1.75)
    y[20:30] = -10.0  # 10 poses on the pavement and beyond
    y[60:65] = 20.0
    fit = fit_route(road_map, np.stack([x, y], axis=-1), x, None)
    r = fit.report
    assert r.on_lane_fraction == pytest.approx(0.85)
    assert r.off_map_stretch_count == 2
    first, second = r.off_map_stretches
    assert (first.start_index, first.end_index) == (20, 29)
    assert (first.start_t_s, first.end_t_s) == (20.0, 29.0)
    assert first.length_m == pytest.approx(9.0)
    assert first.max_offset_m == pytest.approx(8.25)
    assert (second.start_index, second.end_index) == (60, 64)
    length = 95.0 + 2 * math.hypot(1.0, 8.25) + 2 * math.hypot(1.0, 21.75)
    assert r.length_m == pytest.approx(length)
    assert r.covered_length_m == pytest.approx(19.0 + 29.0 + 34.0)
    assert r.covered_fraction == pytest.approx(82.0 / length)
    assert r.against_lane_direction_fraction is None  # no headings given
    (warning,) = route_warnings(r)
    assert "of the route lies on a driving lane" in warning
    assert "2 stretches leave it" in warning


def test_driving_against_the_lane_is_flagged(road_map: RoadMap) -> None:
    x = np.arange(0.0, 100.0, 1.0)
    xy = np.stack([x, np.full_like(x, -1.75)], axis=-1)
    fit = fit_route(road_map, xy, x, np.full_like(x, math.pi))
    assert fit.report.against_lane_direction_fraction == pytest.approx(1.0)
    assert any("against the lane direction" in w for w in route_warnings(fit.report))


def test_empty_route_has_no_fractions(road_map: RoadMap) -> None:
    r = fit_route(road_map, np.zeros((0, 2)), np.zeros(0)).report
    assert (r.poses, r.length_m, r.on_lane_fraction, r.covered_fraction) == (0, 0.0, None, None)


def make_report(road_map: RoadMap) -> MapReport:
    x = np.arange(0.0, 50.0, 1.0)
    fit = fit_route(road_map, np.stack([x, np.full_like(x, -1.75)], axis=-1), x)
    nan = math.nan
    return MapReport(
        proj_string="+proj=tmerc +lat_0=48 +lon_0=11",
        box=(47.9, 10.9, 48.1, 11.1),
        margin_m=100.0,
        options={"lane_width_m": 3.35},
        source=SourceReport(
            kind="file", path="a.osm", sha256="0" * 64, nodes=3, ways=1, deleted_dropped=0
        ),
        roads=road_counts(road_map),
        route=fit.report,
        osm_alignment=AlignmentReport.from_alignment(
            OsmAlignment(0, 0, 0, nan, nan, nan, nan, 0, nan, nan, nan, nan)
        ),
        warnings=[],
    )


def test_report_round_trips_through_json(tmp_path: Path, road_map: RoadMap) -> None:
    report = make_report(road_map)
    path = tmp_path / "map_report.json"
    report.save(path)
    assert MapReport.load(path) == report
    assert report.roads.roads == 2
    assert report.roads.lanes_by_type == {"driving": 3, "sidewalk": 1}
    assert report.osm_alignment.median_m is None  # NaN is written as null


def test_report_from_a_newer_schema_is_refused(tmp_path: Path, road_map: RoadMap) -> None:
    path = tmp_path / "map_report.json"
    path.write_text(
        make_report(road_map).model_dump_json().replace('"schema_version":1', '"schema_version":99')
    )
    with pytest.raises(SchemaVersionError, match="schema_version 99"):
        MapReport.load(path)


def test_plot_writes_a_png(tmp_path: Path, road_map: RoadMap) -> None:
    x = np.arange(0.0, 100.0, 1.0)
    path = tmp_path / "map.png"
    plot_map(road_map, np.stack([x, np.full_like(x, -1.75)], axis=-1), x < 50, path, title="t")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
