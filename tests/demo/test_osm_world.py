"""Demo worlds from real OSM files: route picking, the street, buildings, errors."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from cam2sim.core.errors import ConfigError, StageError
from cam2sim.demo.osm_world import MIN_RADIUS_M, PICK_CUT_M, osm_demo_world
from cam2sim.demo.route import PiecewiseRoute

OSM_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "osm"


def _real(name: str) -> Path:
    path = OSM_DIR / name
    if not path.is_file():
        pytest.skip(f"real OSM data not available ({path})")
    return path


# -- rounding a polyline -------------------------------------------------------------------------


def test_from_polyline_rounds_corners_and_keeps_the_ends() -> None:
    xy = np.array([[0.0, 0.0], [100.0, 0.0], [100.0, 100.0], [200.0, 120.0]])
    route = PiecewiseRoute.from_polyline(xy, max_radius_m=30.0)
    end, heading = route.points([route.length_m])
    np.testing.assert_allclose(end[0], xy[-1], atol=1e-9)
    assert heading[0] == pytest.approx(math.atan2(20.0, 100.0))
    arcs = [k for _, k in route.pieces if k != 0.0]
    np.testing.assert_allclose(np.abs(arcs), 1.0 / 30.0)
    # Continuous: unit speed along the whole route.
    s = np.arange(0.0, route.length_m, 0.1)
    p, _ = route.points(s)
    np.testing.assert_allclose(np.hypot(*np.diff(p, axis=0).T), 0.1, atol=1e-6)
    turns = route.bend_turns()
    assert [round(math.degrees(t)) for _, _, t in turns] == [90, -79]


def test_from_polyline_keeps_a_curve_drawn_with_many_points() -> None:
    th = np.linspace(0.0, math.pi / 2.0, 40)
    arc = np.column_stack([30.0 * np.sin(th), 30.0 - 30.0 * np.cos(th)])
    route = PiecewiseRoute.from_polyline(arc)
    curv = np.array([k for _, k in route.pieces if k != 0.0])
    np.testing.assert_allclose(curv, 1.0 / 30.0, rtol=0.01)
    assert len(route.bend_turns()) == 1  # one bend, not 38


def test_from_polyline_refuses_a_corner_too_sharp_to_drive() -> None:
    with pytest.raises(ValueError, match="turns by 90 degrees and fits only a 10.0 m radius"):
        PiecewiseRoute.from_polyline([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]], min_radius_m=20.0)
    # Per-corner caps: a junction corner stays tight while the street's curve keeps 60 m.
    xy = [[0.0, 0.0], [200.0, 0.0], [200.0, 200.0]]
    tight = PiecewiseRoute.from_polyline(xy, max_radius_m=[60.0, 20.0, 60.0])
    assert [k for _, k in tight.pieces if k] == [pytest.approx(1 / 20.0)]


def test_gentle_curves_are_not_bends() -> None:
    route = PiecewiseRoute(((50.0, 0.0), (100.0, 0.001), (40.0, 0.0), (20.0, 0.02), (20.0, 0.03)))
    turns = route.bend_turns()  # the 0.1 rad curve is gentle; the two arcs after it merge
    assert len(turns) == 1
    assert turns[0][:2] == (190.0, 230.0)
    assert turns[0][2] == pytest.approx(1.0)


# -- real extracts -------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("name", "crs"),
    [
        ("munich.osm", "EPSG:32632"),
        ("West-Oakland.osm.bz2", "EPSG:32610"),
        ("aguascalientes.osm.pbf", "EPSG:32613"),
    ],
)
def test_real_extracts_give_a_drivable_route_with_two_bends(name: str, crs: str) -> None:
    import shapely

    plan = osm_demo_world(_real(name))
    street = plan.world.street
    assert street.crs == crs
    assert 295.0 <= street.length_m <= PICK_CUT_M + 5.0  # picked paths are cut at 400 m
    assert len(street.route.bend_turns()) >= 2
    assert all(abs(k) <= 1 / MIN_RADIUS_M + 1e-9 for _, k in plan.route.route.pieces)
    # The street's reference line follows the OSM way; the car drives half a lane right of it.
    s = np.arange(0.0, street.length_m, 2.0)
    xy, _ = street.route_points(s, street.lane_m / 2.0)
    way = shapely.LineString(plan.route.xy)
    off = shapely.distance(shapely.points(xy), way)
    assert float(np.max(off)) < 8.0  # corners are rounded by at most 20-60 m
    assert float(np.median(off)) < 0.3
    drive, _ = street.route_points(s)
    assert float(np.median(shapely.distance(shapely.points(drive), way))) == pytest.approx(
        street.lane_m / 2.0, abs=0.1
    )
    # No building stands on the street; no car parks where parking is banned.
    ref, _ = street.route_points(np.arange(-30.0, street.length_m + 30.0, 1.0), street.lane_m / 2)
    corridor = shapely.LineString(ref).buffer(street.lane_m + street.parking_m + street.sidewalk_m)
    assert not any(shapely.Polygon(b.xy).intersects(corridor) for b in plan.world.buildings)
    assert plan.world.cars
    # Deterministic: the same file gives the same world (and the same folder name).
    again = osm_demo_world(_real(name))
    assert again.world == plan.world


def test_real_buildings_are_used_where_the_extract_has_them() -> None:
    plan = osm_demo_world(_real("munich.osm"))
    kept = [n for n in plan.notes if "real building footprints kept" in n]
    assert kept
    assert int(kept[0].split()[0]) > 20
    odd = [b for b in plan.world.buildings if len(b.xy) != 4]
    assert odd  # real outlines, not only rectangles


def test_a_small_extract_gives_its_longest_route_and_says_so() -> None:
    from cam2sim.map.osm import parse_osm_xml

    plan = osm_demo_world(_real("tram_crossing.osm"))
    assert any("took the longest" in n for n in plan.notes)
    assert 100.0 <= plan.world.street.length_m < 300.0
    # The route follows ways past the file's bounds: the extract written for the map stage
    # declares bounds that hold the whole drive (else the map stage refuses the recording).
    written = parse_osm_xml(plan.world.osm_xml().encode(), source="demo.osm")
    ll = plan.frame.to_wgs84(plan.route.xy)
    assert written.bounds is not None
    assert written.bounds.contains(ll.lat_deg, ll.lon_deg).all()


def test_route_between_two_points_and_bad_points() -> None:
    path = _real("West-Oakland.osm.bz2")
    picked = osm_demo_world(path)
    ends = picked.route.xy[[0, len(picked.route.xy) // 2]]
    ll = picked.frame.to_wgs84(ends)
    a = f"{ll.lat_deg[0]:.6f},{ll.lon_deg[0]:.6f}"
    b = f"{ll.lat_deg[1]:.6f},{ll.lon_deg[1]:.6f}"
    plan = osm_demo_world(path, route=(a, b))
    assert plan.world.street.name != picked.world.street.name
    assert any(n.startswith(f"route from {a} to {b}") for n in plan.notes)
    got = plan.frame.to_wgs84(plan.route.xy[[0, -1]])
    back = picked.frame.from_wgs84(got.lat_deg, got.lon_deg)[:, :2]
    np.testing.assert_allclose(back, ends, atol=0.5)  # from node to node
    with pytest.raises(ConfigError, match="m from the nearest drivable road"):
        osm_demo_world(path, route=(a, "37.0,-122.0"))
    with pytest.raises(ConfigError, match="is not LAT,LON"):
        osm_demo_world(path, route=(a, "somewhere"))


# -- bad files ----------------------------------------------------------------------------------


def _osm(tmp_path: Path, body: str) -> Path:
    path = tmp_path / "x.osm"
    path.write_text(
        f"<?xml version='1.0' encoding='UTF-8'?>\n<osm version='0.6'>\n{body}\n</osm>\n",
        encoding="utf-8",
    )
    return path


def test_an_extract_without_drivable_roads_says_what_it_has(tmp_path: Path) -> None:
    nodes = "".join(
        f"<node id='{k}' lat='48.0' lon='{11.0 + k * 1e-3}' version='1'/>" for k in range(1, 4)
    )
    way = (
        "<way id='10' version='1'><nd ref='1'/><nd ref='2'/><nd ref='3'/>"
        "<tag k='highway' v='footway'/></way>"
    )
    with pytest.raises(StageError, match=r"no drivable road.*footway \(1\)"):
        osm_demo_world(_osm(tmp_path, nodes + way))


def _straight_way(
    way_id: int, first_node: int, n: int, lon0: float, highway: str, gap_m: float
) -> str:
    """``n`` nodes ``gap_m`` apart eastwards at 48 N from ``lon0``, joined by one way."""
    step = gap_m / (111_320.0 * math.cos(math.radians(48.0)))
    ids = range(first_node, first_node + n)
    nodes = "".join(
        f"<node id='{i}' lat='48.0' lon='{lon0 + k * step:.7f}' version='1'/>"
        for k, i in enumerate(ids)
    )
    refs = "".join(f"<nd ref='{i}'/>" for i in ids)
    tags = f"<tag k='highway' v='{highway}'/><tag k='lanes' v='2'/>"
    return nodes + f"<way id='{way_id}' version='1'>{refs}{tags}</way>"


def test_an_extract_of_main_roads_gives_a_route_on_them_and_says_so(tmp_path: Path) -> None:
    # A residential stub of 50 m (too short for a route) and a primary road of 400 m.
    stub = _straight_way(20, 100, 2, 11.01, "residential", 50.0)
    path = _osm(tmp_path, stub + _straight_way(10, 1, 5, 11.0, "primary", 100.0))
    plan = osm_demo_world(path)
    assert any(n.startswith("no route on residential/unclassified/tertiary") for n in plan.notes)
    assert plan.world.street.length_m == pytest.approx(400.0, abs=5.0)
    assert plan.world.street.lane_markings  # main roads are marked
    # Without the primary road the stub alone is refused, the message naming what was tried.
    with pytest.raises(StageError, match="no drivable path of 100 m or more on residential"):
        osm_demo_world(_osm(tmp_path, stub))


def test_a_real_junction_of_main_roads_gives_routes(tmp_path: Path) -> None:
    from cam2sim.demo.osm_world import count_routes

    path = _real("moosacher_lerchenauer.osm")  # primary and secondary roads only
    plan = osm_demo_world(path)
    assert any("may use living_street/secondary/primary" in n for n in plan.notes)
    assert plan.world.street.length_m >= 300.0
    assert len(count_routes(path, 3)) >= 2
    # An extract with residential routes keeps to them.
    assert not any("no route on" in n for n in osm_demo_world(_real("munich.osm")).notes)


def test_an_extract_of_only_deletes_is_refused(tmp_path: Path) -> None:
    body = "<node id='1' lat='48.0' lon='11.0' action='delete' version='1'/>"
    with pytest.raises(StageError):
        osm_demo_world(_osm(tmp_path, body))


# -- several routes of one extract (cam2sim bench) ------------------------------------------------


@pytest.mark.parametrize("name", ["munich.osm", "West-Oakland.osm.bz2"])
def test_an_extract_gives_several_distinct_routes(name: str) -> None:
    from cam2sim.demo.osm_world import _graph, _shared, pick_route, pick_routes
    from cam2sim.map.osm import read_osm

    graph = _graph(read_osm(_real(name)))
    routes = [r for r, _ in pick_routes(graph, 4)]
    assert len(routes) == 4
    assert routes[0].nodes == pick_route(graph)[0].nodes  # the first is the demo's own
    for i, a in enumerate(routes):
        assert a.route.length_m >= 150.0
        for b in routes[i + 1 :]:
            assert _shared(a, b) <= 0.3  # different streets, not one street twice
    mids = np.array([r.route.points([r.route.length_m / 2])[0][0] for r in routes])
    spread = np.hypot(*(mids[:, None] - mids[None]).transpose(2, 0, 1))
    assert spread[np.triu_indices(4, 1)].min() > 50.0


def test_a_picked_route_builds_its_own_world_and_too_many_are_refused() -> None:
    path = _real("tram_crossing.osm")
    first = osm_demo_world(path)
    second = osm_demo_world(path, pick=1)
    assert first.world.street.name != second.world.street.name
    assert first.route.nodes != second.route.nodes
    with pytest.raises(StageError, match=r"distinct drivable route\(s\).*ask for fewer"):
        osm_demo_world(path, pick=5)


def test_a_picked_route_cut_at_400_m_is_built_as_picked() -> None:
    from cam2sim.demo.osm_world import _graph, pick_routes
    from cam2sim.map.osm import read_osm

    # West-Oakland's fourth route runs on past 400 m: picked cut there, it was built cut at
    # 500 m instead (452 m where 389 m were picked).
    path = _real("West-Oakland.osm.bz2")
    picked, _ = pick_routes(_graph(read_osm(path)), 4)[3]
    kept = float(np.hypot(*np.diff(picked.xy, axis=0).T).sum())
    assert kept == pytest.approx(PICK_CUT_M, abs=0.01)  # the path was cut
    plan = osm_demo_world(path, pick=3)
    assert plan.route.route.length_m == pytest.approx(picked.route.length_m, abs=0.01)
    assert plan.route.nodes == picked.nodes
    assert plan.world.street.length_m < PICK_CUT_M
