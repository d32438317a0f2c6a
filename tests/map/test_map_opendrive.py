"""OpenDRIVE plan-view evaluation against closed forms, and parse errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cam2sim.core.errors import StageError
from cam2sim.map.opendrive import (
    Geometry,
    LaneDef,
    LaneSection,
    Poly3,
    Road,
    lane_borders,
    parse_opendrive,
    reference_line,
    station_grid,
)


def road_of(*geoms: Geometry, offsets: tuple[Poly3, ...] = ()) -> Road:
    length = sum(g.length for g in geoms)
    return Road("1", "", length, "-1", geoms, offsets, (LaneSection(0.0, ()),))


def test_line_and_arc_match_closed_forms() -> None:
    radius = 20.0
    arc = Geometry(10.0, 10.0, 0.0, 0.0, math.pi * radius / 2, "arc", (1.0 / radius,))
    road = road_of(Geometry(0.0, 0.0, 0.0, 0.0, 10.0, "line"), arc)
    s = np.linspace(0.0, road.length, 101)
    x, y, hdg = reference_line(road, s)
    on_arc = s > 10.0
    ang = (s[on_arc] - 10.0) / radius
    np.testing.assert_allclose(x[~on_arc], s[~on_arc], atol=1e-12)
    np.testing.assert_allclose(y[~on_arc], 0.0, atol=1e-12)
    np.testing.assert_allclose(x[on_arc], 10.0 + radius * np.sin(ang), atol=1e-9)
    np.testing.assert_allclose(y[on_arc], radius * (1.0 - np.cos(ang)), atol=1e-9)
    np.testing.assert_allclose(hdg[on_arc], ang, atol=1e-12)


def test_param_poly3_is_evaluated_by_arc_length() -> None:
    # u(p) = 10 p + 5 p^2 on a straight line: p is not proportional to the arc length.
    g = Geometry(0.0, 1.0, 2.0, math.pi / 2, 15.0, "paramPoly3", (0, 10, 5, 0, 0, 0, 0, 0))
    s = np.linspace(0.0, 15.0, 31)
    x, y, hdg = reference_line(road_of(g), s)
    np.testing.assert_allclose(x, 1.0, atol=1e-9)
    np.testing.assert_allclose(y, 2.0 + s, atol=1e-4)  # sub-millimetre arc-length inversion
    np.testing.assert_allclose(hdg, math.pi / 2, atol=1e-9)


def test_param_poly3_in_arc_length_range_follows_its_curve() -> None:
    # A parabola v = 0.02 u^2 given with pRange=arcLength: every point must lie on it.
    length = 12.0
    g = Geometry(0.0, 0.0, 0.0, 0.0, length, "paramPoly3", (0, 1, 0, 0, 0, 0, 0.02, 0))
    g = Geometry(g.s, g.x, g.y, g.hdg, g.length, g.kind, g.params, normalized=False)
    x, y, hdg = reference_line(road_of(g), np.linspace(0.0, length, 25))
    np.testing.assert_allclose(y, 0.02 * x**2, atol=1e-9)
    np.testing.assert_allclose(np.tan(hdg), 0.04 * x, atol=1e-9)


def test_spiral_curvature_grows_linearly() -> None:
    g = Geometry(0.0, 0.0, 0.0, 0.0, 20.0, "spiral", (0.0, 0.1))
    s = np.linspace(0.0, 20.0, 201)
    x, y, hdg = reference_line(road_of(g), s)
    np.testing.assert_allclose(hdg, 0.1 * s**2 / 40.0, atol=1e-9)
    # Fresnel integrals by brute force.
    t = np.linspace(0.0, 20.0, 200_001)
    theta = 0.1 * t**2 / 40.0
    xr = np.trapezoid(np.cos(theta), t)
    yr = np.trapezoid(np.sin(theta), t)
    assert abs(x[-1] - xr) < 1e-3
    assert abs(y[-1] - yr) < 1e-3


def test_poly3_points_lie_on_the_cubic() -> None:
    g = Geometry(0.0, 0.0, 0.0, 0.0, 10.0, "poly3", (0.5, 0.0, 0.01, 0.0))
    x, y, _ = reference_line(road_of(g), np.linspace(0.0, 10.0, 21))
    np.testing.assert_allclose(y, 0.5 + 0.01 * x**2, atol=1e-9)


def test_lane_borders_add_widths_outwards_from_the_offset() -> None:
    sec = LaneSection(
        0.0,
        (
            LaneDef(1, "driving", (Poly3(0.0, 3.0, 0.0, 0.0, 0.0),)),
            LaneDef(-1, "driving", (Poly3(0.0, 3.0, 0.1, 0.0, 0.0),)),
            LaneDef(-2, "sidewalk", (Poly3(0.0, 2.0, 0.0, 0.0, 0.0), Poly3(5.0, 1.0, 0, 0, 0))),
        ),
    )
    s = np.array([0.0, 10.0])
    borders = lane_borders(sec, s, np.array([0.5, 0.5]))
    np.testing.assert_allclose(borders[1][1], [3.5, 3.5])
    np.testing.assert_allclose(borders[-1][1], [-2.5, -3.5])
    np.testing.assert_allclose(borders[-2][1], [-4.5, -4.5])


def test_station_grid_refines_curves_only() -> None:
    road = road_of(
        Geometry(0.0, 0.0, 0.0, 0.0, 10.0, "line"),
        Geometry(10.0, 10.0, 0.0, 0.0, 10.0, "arc", (0.2,)),
    )
    s = station_grid(road, 0.0, 20.0, 1.0, chord_tolerance_m=0.005)
    steps = np.diff(s)
    assert steps[s[:-1] < 10.0].max() == pytest.approx(1.0)
    assert steps[s[:-1] >= 10.0].max() <= math.sqrt(8 * 5.0 * 0.005) + 1e-9


XODR = """<?xml version="1.0"?>
<OpenDRIVE>
  <header revMajor="1" revMinor="4"><geoReference><![CDATA[+proj=tmerc +lat_0=1]]></geoReference>
  </header>
  <road name="a" length="10" id="7" junction="-1">
    <planView><geometry s="0" x="0" y="0" hdg="0" length="10"><line/></geometry></planView>
    <lanes><laneSection s="0"><center><lane id="0" type="none"/></center>
      <right><lane id="-1" type="driving">
        <width sOffset="0" a="3" b="0" c="0" d="0"/></lane></right>
    </laneSection></lanes>
  </road>
  <junction id="3" name="j"><connection id="0" incomingRoad="7" connectingRoad="8"/></junction>
</OpenDRIVE>
"""


def test_parse_reads_header_roads_and_junctions() -> None:
    od = parse_opendrive(XODR)
    assert od.geo_reference == "+proj=tmerc +lat_0=1"
    assert od.offset == (0.0, 0.0, 0.0, 0.0)
    assert [r.id for r in od.roads] == ["7"]
    assert od.roads[0].sections[0].lanes == (
        LaneDef(-1, "driving", (Poly3(0.0, 3.0, 0.0, 0.0, 0.0),)),
    )
    assert od.junctions[0].connecting_roads == ("8",)


def test_parse_errors_name_source_and_road() -> None:
    with pytest.raises(StageError, match=r"m\.xodr, line \d+, column \d+: malformed OpenDRIVE"):
        parse_opendrive(XODR.replace("</road>", "</rod>"), source="m.xodr")
    with pytest.raises(StageError, match=r"<road id='7'> has no <planView>"):
        parse_opendrive(XODR.replace("planView", "plan"), source="m.xodr")
    with pytest.raises(StageError, match=r"<road id='7'> <geometry s='0'> holds <clothoid>"):
        parse_opendrive(XODR.replace("<line/>", "<clothoid/>"), source="m.xodr")
    with pytest.raises(StageError, match="expected <OpenDRIVE>"):
        parse_opendrive("<osm/>")
