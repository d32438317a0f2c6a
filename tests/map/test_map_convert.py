"""OSM -> OpenDRIVE with CARLA's converter: projection, options, failures, CARLA accepts it."""

from __future__ import annotations

import os
import re

import pytest

from cam2sim.core.errors import BackendUnavailableError, ConfigError, StageError
from cam2sim.core.frames.projection import WorldFrame
from cam2sim.map import convert
from cam2sim.map.convert import ConvertOptions, osm_to_xodr
from cam2sim.map.opendrive import parse_opendrive
from cam2sim.map.osm import read_osm

from .map_helpers import osm_file, requires_carla

FRAME = WorldFrame(48.1791, 11.5891)  # at tram_crossing.osm


@pytest.fixture(scope="module")
def tram_xml() -> str:
    return read_osm(osm_file("tram_crossing.osm")).to_xml()


@pytest.fixture(scope="module")
def tram_xodr(tram_xml: str) -> str:
    if not convert.has_carla():
        pytest.skip("needs carla (pip install cam2sim[map])")
    return osm_to_xodr(tram_xml, FRAME.proj_string)


@requires_carla
def test_map_is_written_in_the_world_projection_without_offset(tram_xodr: str) -> None:
    od = parse_opendrive(tram_xodr)
    assert od.geo_reference == FRAME.proj_string
    assert od.offset == (0.0, 0.0, 0.0, 0.0)
    assert re.search(r"<offset\s", tram_xodr) is None
    # Roads lie around the frame origin (the box is about 200 m across), not 800 km away.
    xs = [g.x for r in od.roads for g in r.geometries]
    assert max(abs(x) for x in xs) < 500.0


@requires_carla
def test_carla_map_loads_the_result_and_generates_waypoints(
    tram_xodr: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    import pyproj

    monkeypatch.setitem(os.environ, "PROJ_LIB", pyproj.datadir.get_data_dir())
    import carla

    waypoints = carla.Map("tram", tram_xodr).generate_waypoints(2.0)
    assert len(waypoints) > 50
    assert {w.lane_type for w in waypoints} == {carla.LaneType.Driving}


@requires_carla
def test_sidewalks_become_parking_lanes_on_request(tram_xml: str, tram_xodr: str) -> None:
    parking = osm_to_xodr(tram_xml, FRAME.proj_string, ConvertOptions(sidewalks="parking"))
    kerb_sidewalks = len(re.findall(r'type="sidewalk"', tram_xodr))
    assert kerb_sidewalks > 0
    assert 'type="sidewalk"' not in parking
    assert len(re.findall(r'type="parking"', parking)) == kerb_sidewalks


@requires_carla
def test_lane_width_option_reaches_the_map(tram_xml: str) -> None:
    xodr = osm_to_xodr(tram_xml, FRAME.proj_string, ConvertOptions(lane_width_m=3.0))
    widths = {
        ln.widths[0].a
        for r in parse_opendrive(xodr).roads
        for sec in r.sections
        for ln in sec.lanes
        if ln.type == "driving"
    }
    assert 3.0 in widths
    assert 3.35 not in widths


@requires_carla
def test_a_failed_conversion_does_not_break_the_next_one(tram_xml: str) -> None:
    # In-process, libcarla's converter fails every call after a failed one; we run it apart.
    empty = "<?xml version='1.0'?><osm version='0.6'></osm>"
    with pytest.raises(StageError, match="CARLA's OSM converter failed: No nodes loaded"):
        osm_to_xodr(empty, FRAME.proj_string)
    assert "<road " in osm_to_xodr(tram_xml, FRAME.proj_string)


def test_missing_carla_names_the_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(convert, "has_carla", lambda: False)
    with pytest.raises(BackendUnavailableError, match=r"pip install cam2sim\[map\]"):
        osm_to_xodr("<osm/>", FRAME.proj_string)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"road_types": ("footway",)}, "not drivable OSM highway values"),
        ({"road_types": ()}, "not drivable"),
        ({"lane_width_m": 0.5}, "lane width 0.5"),
        ({"lane_width_m": float("nan")}, "lane width nan"),
        ({"sidewalks": "grass"}, "choose 'kerb' or 'parking'"),
    ],
)
def test_options_are_validated(kwargs: dict[str, object], match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        ConvertOptions(**kwargs)  # type: ignore[arg-type]
