"""RoadMap queries on a hand-made map with known answers, and against carla.Map on a real one."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest
import shapely

from cam2sim.core.frames.projection import WorldFrame
from cam2sim.map.convert import osm_to_xodr
from cam2sim.map.osm import read_osm
from cam2sim.map.query import RoadMap

from .map_helpers import osm_file, requires_carla

# Road 1: straight, 100 m east from the origin; left lane 1 (3.5 m, runs west), right lane -1
# (3.5 m, runs east) and a 2 m sidewalk. Road 2: a left quarter circle of radius 50 m, one
# right lane of 3 m (outside the curve).
XODR = """<?xml version="1.0"?>
<OpenDRIVE><header revMajor="1" revMinor="4"/>
  <road name="straight" length="100" id="1" junction="-1">
    <planView><geometry s="0" x="0" y="0" hdg="0" length="100"><line/></geometry></planView>
    <lanes><laneSection s="0">
      <left><lane id="1" type="driving"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane></left>
      <center><lane id="0" type="none"/></center>
      <right>
        <lane id="-1" type="driving"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane>
        <lane id="-2" type="sidewalk"><width sOffset="0" a="2" b="0" c="0" d="0"/></lane>
      </right>
    </laneSection></lanes>
  </road>
  <road name="curve" length="{arc}" id="2" junction="-1">
    <planView><geometry s="0" x="0" y="100" hdg="0" length="{arc}">
      <arc curvature="0.02"/></geometry></planView>
    <lanes><laneSection s="0"><center><lane id="0" type="none"/></center>
      <right><lane id="-1" type="driving">
        <width sOffset="0" a="3" b="0" c="0" d="0"/></lane></right>
    </laneSection></lanes>
  </road>
</OpenDRIVE>
""".replace("{arc}", repr(50.0 * math.pi / 2))


@pytest.fixture(scope="module")
def road_map() -> RoadMap:
    return RoadMap.from_xodr(XODR)


def lane_of(rm: RoadMap, road: str, lane: int) -> int:
    return next(i for i, ln in enumerate(rm.lanes) if (ln.road_id, ln.lane_id) == (road, lane))


def test_lane_polygons_have_the_exact_areas(road_map: RoadMap) -> None:
    polys = road_map.lane_polygons()
    assert shapely.area(polys[lane_of(road_map, "1", 1)]) == pytest.approx(350.0)
    assert shapely.area(polys[lane_of(road_map, "1", -1)]) == pytest.approx(350.0)
    assert shapely.area(polys[lane_of(road_map, "1", -2)]) == pytest.approx(200.0)
    annulus = math.pi / 4 * (53.0**2 - 50.0**2)
    assert shapely.area(polys[lane_of(road_map, "2", -1)]) == pytest.approx(annulus, rel=1e-4)
    assert len(road_map.lane_polygons("sidewalk")) == 1
    assert road_map.drivable_area().area == pytest.approx(700.0 + annulus, rel=1e-4)


def test_nearest_lane_gives_centre_heading_and_signed_offset(road_map: RoadMap) -> None:
    # The curve turns left about (0, 150): its right lane's centre has radius 51.5.
    pts = np.array([[50.0, -1.75], [50.0, 1.75], [20.0, -1.0], [0.0, 0.0]])
    pts[3] = [51.5 * math.sin(0.5), 150.0 - 51.5 * math.cos(0.5)]
    near = road_map.nearest_lane(pts)
    assert near.lane.tolist() == [
        lane_of(road_map, "1", -1),
        lane_of(road_map, "1", 1),
        lane_of(road_map, "1", -1),
        lane_of(road_map, "2", -1),
    ]
    np.testing.assert_allclose(near.distance[:3], [0.0, 0.0, 0.75], atol=1e-9)
    assert near.distance[3] < 1e-3  # chord of the sampled curve
    np.testing.assert_allclose(near.lateral[2], 0.75, atol=1e-9)  # left of an eastbound lane
    np.testing.assert_allclose(near.heading[:3], [0.0, math.pi, 0.0], atol=1e-9)
    assert near.heading[3] == pytest.approx(0.5, abs=0.01)  # tangent of the curve
    np.testing.assert_allclose(near.width, [3.5, 3.5, 3.5, 3.0])
    np.testing.assert_allclose(near.s[:3], [50.0, 50.0, 20.0], atol=1e-9)
    assert near.inside.all()


def test_nearest_lane_honours_types_and_search_radius(road_map: RoadMap) -> None:
    side = road_map.nearest_lane([[50.0, -4.5]], "sidewalk")
    assert side.lane[0] == lane_of(road_map, "1", -2)
    far = road_map.nearest_lane([[500.0, 500.0]], max_distance=10.0)
    assert far.lane[0] == -1
    assert math.isinf(far.distance[0])
    assert road_map.nearest_lane([[0.0, 0.0]], "biking").lane[0] == -1


def test_on_lane_and_lane_at(road_map: RoadMap) -> None:
    pts = np.array([[50.0, -1.0, 0.0], [50.0, -4.5, 0.0], [50.0, 30.0, 0.0]])
    np.testing.assert_array_equal(road_map.on_lane(pts), [True, False, False])
    at = road_map.lane_at(pts)
    assert at.tolist() == [lane_of(road_map, "1", -1), lane_of(road_map, "1", -2), -1]
    assert road_map.lane_at(pts, "sidewalk").tolist() == [-1, at[1], -1]


def test_road_edges_are_the_kerb_lines(road_map: RoadMap) -> None:
    edges = {(e.road_id, e.side): e for e in road_map.road_edges()}
    right = edges["1", "right"]
    np.testing.assert_allclose(right.xy[:, 1], -3.5)
    assert right.beyond_type == "sidewalk"
    assert right.outer_lane_type == "driving"
    np.testing.assert_allclose(right.heading, 0.0)
    left = edges["1", "left"]
    np.testing.assert_allclose(left.xy[:, 1], 3.5)
    assert left.beyond_type is None
    assert left.xy[0, 0] > left.xy[-1, 0]  # runs west, with its lane
    radius = np.hypot(edges["2", "right"].xy[:, 0], edges["2", "right"].xy[:, 1] - 150.0)
    np.testing.assert_allclose(radius, 53.0, atol=1e-3)


def test_lane_lengths_and_types(road_map: RoadMap) -> None:
    assert road_map.lane_types == ("driving", "sidewalk")
    lengths = road_map.lane_length_by_type()
    assert lengths["sidewalk"] == pytest.approx(100.0)  # centre-line lengths
    assert lengths["driving"] == pytest.approx(200.0 + 51.5 * math.pi / 2, rel=1e-4)


def test_queries_refuse_bad_points(road_map: RoadMap) -> None:
    with pytest.raises(ValueError, match=r"shape \(N, 2\) or \(N, 3\)"):
        road_map.nearest_lane(np.zeros((3, 4)))
    with pytest.raises(ValueError, match="NaN"):
        road_map.on_lane([[np.nan, 0.0]])
    with pytest.raises(ValueError, match="step_m"):
        RoadMap.from_xodr(XODR, step_m=0.0)


def test_from_xodr_reads_files(tmp_path: Path, road_map: RoadMap) -> None:
    path = tmp_path / "m.xodr"
    path.write_text(XODR)
    assert len(RoadMap.from_xodr(path).lanes) == len(road_map.lanes)


@requires_carla
def test_lane_centres_match_carla_map_waypoints(monkeypatch: pytest.MonkeyPatch) -> None:
    """The reference: carla.Map's own waypoints on a real converted map."""
    import pyproj

    osm = read_osm(osm_file("moosacher_lerchenauer.osm"))
    box = osm.extent()
    frame = WorldFrame((box.south + box.north) / 2, (box.west + box.east) / 2)
    xodr = osm_to_xodr(osm.to_xml(), frame.proj_string)
    monkeypatch.setitem(os.environ, "PROJ_LIB", pyproj.datadir.get_data_dir())
    import carla

    waypoints = carla.Map("moosacher", xodr).generate_waypoints(1.0)
    assert len(waypoints) > 100
    rows = []
    for w in waypoints:
        loc = w.transform.location
        yaw = -math.radians(w.transform.rotation.yaw)  # CARLA is left-handed: y and yaw flip
        rows.append((w.road_id, w.lane_id, loc.x, -loc.y, yaw, w.lane_width, w.s))
    ref = np.array(rows)
    road_map = RoadMap.from_xodr(xodr)
    near = road_map.nearest_lane(ref[:, 2:4])
    same = np.array(
        [
            (road_map.lanes[i].road_id, road_map.lanes[i].lane_id) == (str(int(r)), int(k))
            for i, r, k in zip(near.lane, ref[:, 0], ref[:, 1], strict=True)
        ]
    )
    assert same.mean() > 0.98
    assert near.distance.max() < 0.05
    assert np.percentile(near.distance, 99) < 0.01
    np.testing.assert_allclose(near.width[same], ref[same, 5], atol=1e-9)
    # Where a wide lane folds over itself in a tight curve, the nearest centre point may sit at
    # another station; compare headings where the stations agree.
    at = same & (np.abs(near.s - ref[:, 6]) < 0.05)
    assert at.mean() > 0.95
    dh = np.angle(np.exp(1j * (near.heading[at] - ref[at, 4])))
    assert np.degrees(np.abs(dh)).max() < 0.5
