"""The map stage end to end on a real Munich street: outputs, skipping, sources, bad input."""

from __future__ import annotations

import dataclasses
import datetime as dt
import math
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

from cam2sim.core.config import Config
from cam2sim.core.errors import StageError
from cam2sim.core.workspace import Workspace, WorldFrameRecord
from cam2sim.map.convert import ConvertOptions
from cam2sim.map.opendrive import parse_opendrive
from cam2sim.map.overpass import OverpassOptions
from cam2sim.map.report import MapReport
from cam2sim.stages.map import MAP_FILES, MapOptions, build_map, load_road_map, route_box

from .map_helpers import MUNICH, Route, closed_port_url, make_workspace, osm_file, requires_carla

pytestmark = requires_carla


def snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


def old_map(ws: Workspace) -> dict[str, bytes]:
    """Stand-in for a map an earlier run wrote; returns its content."""
    ws.map_dir.mkdir()
    (ws.map_dir / MAP_FILES["xodr"]).write_text("<OpenDRIVE/>")
    (ws.map_dir / MAP_FILES["report"]).write_text("{}")
    return snapshot(ws.map_dir)


def test_map_stage_writes_a_map_the_route_lies_on(street_ws: Workspace) -> None:
    result = build_map(street_ws, options=MapOptions(osm=osm_file("munich.osm")))
    assert not result.skipped
    files = {p.name for p in street_ws.map_dir.iterdir()}
    assert {"source.osm", "map.xodr", "map_report.json", "map.png"} <= files
    report = MapReport.load(street_ws.map_dir / MAP_FILES["report"])
    assert report == result.report
    world = street_ws.world_frame()
    assert world is not None
    assert report.proj_string == world.proj_string
    xodr = result.xodr_path.read_text(encoding="utf-8")
    assert parse_opendrive(xodr).geo_reference == world.proj_string
    route = report.route
    assert route.poses == 445
    assert route.covered_fraction is not None
    assert route.covered_fraction > 0.99
    assert route.off_map_stretch_count == 0
    assert route.against_lane_direction_fraction == 0.0
    assert route.lateral_offset.mean_m is not None
    assert route.lateral_offset.mean_m < 0.1  # the route runs on the right lane's centre
    assert report.roads.roads > 5
    assert report.roads.junctions > 2
    assert report.source.kind == "file"
    assert report.warnings == []
    assert report.osm_alignment.rotation_deg is not None
    assert abs(report.osm_alignment.rotation_deg) < 0.01
    record = street_ws.stage_record("map")
    assert record is not None
    assert record.state == "done"
    assert (street_ws.map_dir / MAP_FILES["picture"]).read_bytes()[:4] == b"\x89PNG"
    road_map = load_road_map(street_ws)
    assert road_map.opendrive.geo_reference == world.proj_string


def test_load_road_map_before_the_stage_says_to_run_it(street_ws: Workspace) -> None:
    with pytest.raises(StageError, match="run `cam2sim map"):
        load_road_map(street_ws)


def test_map_stage_skips_when_up_to_date(street_ws: Workspace) -> None:
    options = MapOptions(osm=osm_file("munich.osm"))
    first = build_map(street_ws, options=options)
    again = build_map(street_ws, options=options)
    assert again.skipped
    assert again.report == first.report
    forced = build_map(street_ws, options=options, force=True)
    assert not forced.skipped


def test_box_covers_the_whole_route_plus_margin(street_route: Route) -> None:
    box = route_box(street_route.frame, street_route.xy, 100.0)
    corners = street_route.frame.from_wgs84(
        [box.south, box.north, box.south, box.north], [box.west, box.west, box.east, box.east]
    )
    lo, hi = street_route.xy.min(axis=0), street_route.xy.max(axis=0)
    assert np.all(corners[:, :2].min(axis=0) <= lo - 99.9)
    assert np.all(corners[:, :2].max(axis=0) >= hi + 99.9)


def test_osm_file_not_covering_the_route_fails_and_keeps_the_map(street_ws: Workspace) -> None:
    before = old_map(street_ws)
    elsewhere = MapOptions(osm=osm_file("tram_crossing.osm"))
    with pytest.raises(StageError, match=r"445 of 445 recorded poses \(100.0%\) lie outside it"):
        build_map(street_ws, options=elsewhere)
    assert snapshot(street_ws.map_dir) == before
    record = street_ws.stage_record("map")
    assert record is not None
    assert record.state == "failed"


def test_malformed_osm_names_the_line_and_keeps_the_map(
    street_ws: Workspace, tmp_path: Path
) -> None:
    before = old_map(street_ws)
    broken = tmp_path / "broken.osm"
    lines = MUNICH.read_text(encoding="utf-8").splitlines()
    lines[100] = lines[100].replace("/>", ">")  # an unclosed <node>
    broken.write_text("\n".join(lines), encoding="utf-8")
    with pytest.raises(StageError, match=r"broken\.osm, line \d+, column \d+: malformed XML"):
        build_map(street_ws, options=MapOptions(osm=broken))
    assert snapshot(street_ws.map_dir) == before


def test_no_drivable_roads_in_the_box_is_a_clear_error(street_ws: Workspace) -> None:
    before = old_map(street_ws)
    only_motorways = ConvertOptions(road_types=("motorway",))
    with pytest.raises(StageError, match=r"no drivable roads \(highway=motorway\) in lat"):
        build_map(street_ws, options=MapOptions(osm=MUNICH, convert=only_motorways))
    assert snapshot(street_ws.map_dir) == before


def test_route_off_the_roads_warns(tmp_path: Path, street_route: Route) -> None:
    far = dataclasses.replace(street_route, xy=street_route.xy + np.array([0.0, 40.0]))
    ws = make_workspace(tmp_path / "ws", far)
    with pytest.warns(UserWarning) as caught:
        result = build_map(ws, options=MapOptions(osm=MUNICH))
    messages = [str(w.message) for w in caught]
    assert any(re.match(r"only \d+\.\d% of the route lies on a driving lane", m) for m in messages)
    route = result.report.route
    assert route.covered_fraction is not None
    assert route.covered_fraction < 0.95
    assert route.off_map_stretch_count >= 1
    assert result.report.warnings


def test_sidewalks_as_parking_lanes(street_ws: Workspace) -> None:
    options = MapOptions(osm=MUNICH, convert=ConvertOptions(sidewalks="parking"))
    result = build_map(street_ws, options=options)
    xodr = result.xodr_path.read_text(encoding="utf-8")
    assert 'type="sidewalk"' not in xodr
    assert re.search(r'type="parking"', xodr)
    assert "parking" in result.report.roads.lanes_by_type


def test_overpass_is_queried_and_cached(street_ws: Workspace, fake_overpass) -> None:
    server = fake_overpass([(200, MUNICH.read_bytes())])
    options = MapOptions(overpass=OverpassOptions(url=server.url, timeout_s=5.0, backoff_s=0.0))
    result = build_map(street_ws, options=options)
    assert result.report.source.kind == "overpass"
    assert not result.report.source.from_cache
    assert result.report.route.covered_fraction == pytest.approx(1.0)
    cached = list((street_ws.map_dir / MAP_FILES["cache"]).iterdir())
    assert len(cached) == 1
    server.close()  # offline from now on: the cache answers
    again = build_map(street_ws, options=options, force=True)
    assert again.report.source.from_cache
    assert len(server.requests) == 1


def test_unreachable_overpass_says_to_pass_osm(street_ws: Workspace) -> None:
    options = MapOptions(overpass=OverpassOptions(url=closed_port_url(), retries=0), road="osm")
    before = old_map(street_ws)
    with pytest.raises(StageError, match=r"when offline, pass --osm FILE"):
        build_map(street_ws, options=options)
    assert snapshot(street_ws.map_dir) == before


def test_offline_without_osm_builds_the_road_from_the_driven_path(street_ws: Workspace) -> None:
    options = MapOptions(overpass=OverpassOptions(url=closed_port_url(), retries=0))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = build_map(street_ws, options=options)
    said = " | ".join(str(w.message) for w in caught)
    assert "no OSM data could be had" in said
    assert "follows the driven path" in said
    report = MapReport.load(street_ws.map_dir / MAP_FILES["report"])
    assert report.source.kind == "trajectory"
    assert report.georeferenced  # the poses have a CRS: the road is placed on the Earth
    assert report.route.covered_fraction == pytest.approx(1.0)
    assert report.roads.junctions == 0
    assert "<geoReference>" in result.xodr_path.read_text()
    assert not (street_ws.map_dir / MAP_FILES["source"]).exists()  # no OSM, no buildings


def test_workspace_without_world_frame_says_to_extract(tmp_path: Path) -> None:
    ws = Workspace.create(tmp_path / "ws", Config())
    with pytest.raises(StageError, match="run `cam2sim extract"):
        build_map(ws, options=MapOptions(osm=MUNICH))


def test_local_world_frame_cannot_hold_osm_but_gets_a_road_along_the_path(
    tmp_path: Path, street_route: Route
) -> None:
    ws = make_workspace(tmp_path / "ws", street_route)
    ws.record_stage(
        "extract",
        state="done",
        started=dt.datetime.now(dt.UTC),
        world=WorldFrameRecord(proj_string=None),
    )
    with pytest.raises(StageError, match="not geo-referenced.*drop --osm"):
        build_map(ws, options=MapOptions(osm=MUNICH))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = build_map(ws)
    assert any("not geo-referenced" in str(w.message) for w in caught)
    assert result.report.source.kind == "trajectory"
    assert not result.report.georeferenced
    assert result.report.proj_string is None
    assert result.report.box is None
    assert result.report.route.covered_fraction == pytest.approx(1.0)
    assert "geoReference" not in result.xodr_path.read_text()


def test_a_users_xodr_is_used_as_it_is(tmp_path: Path, street_ws: Workspace) -> None:
    first = build_map(street_ws, options=MapOptions(osm=MUNICH))
    mine = tmp_path / "mine.xodr"
    mine.write_text(first.xodr_path.read_text())
    result = build_map(street_ws, options=MapOptions(xodr=mine))
    assert result.report.source.kind == "xodr"
    assert result.xodr_path.read_text() == mine.read_text()
    broken = tmp_path / "broken.xodr"
    broken.write_text("<OpenDRIVE><road")
    before = snapshot(street_ws.map_dir)
    with pytest.raises(StageError, match="broken.xodr"):
        build_map(street_ws, options=MapOptions(xodr=broken))
    assert snapshot(street_ws.map_dir) == before


def test_margin_is_validated() -> None:
    with pytest.raises(ValueError, match="--margin"):
        MapOptions(margin_m=-1.0)
    with pytest.raises(ValueError, match="--margin"):
        MapOptions(margin_m=math.inf)


def test_missing_osm_file_is_a_clear_error(street_ws: Workspace, tmp_path: Path) -> None:
    with pytest.raises(StageError, match="does not exist"):
        build_map(street_ws, options=MapOptions(osm=tmp_path / "nope.osm"))
