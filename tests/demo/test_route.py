"""PiecewiseRoute: positions, headings, offsets and its OpenDRIVE plan view."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cam2sim.demo.route import PiecewiseRoute

L_STREET = PiecewiseRoute(((60.0, 0.0), (40.0 * math.pi / 2, 1 / 40.0), (60.0, 0.0)))


def test_an_l_street_turns_left_on_its_arc() -> None:
    xy, h = L_STREET.points([0.0, 60.0, 60.0 + 20 * math.pi, L_STREET.length_m])
    np.testing.assert_allclose(xy[1], [60.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(xy[2], [100.0, 40.0], atol=1e-9)
    np.testing.assert_allclose(xy[3], [100.0, 100.0], atol=1e-9)
    np.testing.assert_allclose(h, [0.0, 0.0, math.pi / 2, math.pi / 2], atol=1e-12)
    # Beyond the ends: straight on.
    xy, h = L_STREET.points([-10.0, L_STREET.length_m + 10.0])
    np.testing.assert_allclose(xy, [[-10.0, 0.0], [100.0, 110.0]], atol=1e-9)
    assert L_STREET.curvature([-5.0, 30.0, 80.0, 500.0]).tolist() == [0.0, 0.0, 1 / 40.0, 0.0]


def test_points_are_continuous_and_offsets_are_perpendicular() -> None:
    route = PiecewiseRoute(((50.0, 0.0), (30.0, 1 / 30.0), (40.0, -1 / 50.0), (20.0, 0.0)))
    s = np.arange(-20.0, route.length_m + 20.0, 0.05)
    xy, h = route.points(s)
    step = np.hypot(*np.diff(xy, axis=0).T)
    np.testing.assert_allclose(step, 0.05, atol=1e-6)  # unit speed: no jumps at the joints
    left, _ = route.points(s, 2.0)
    normal = np.column_stack([-np.sin(h), np.cos(h)])
    np.testing.assert_allclose(left - xy, 2.0 * normal, atol=1e-9)
    assert route.bends() == ((50.0, 80.0), (80.0, 120.0))
    assert route.in_bend([10.0, 60.0, 121.0], margin_m=2.0).tolist() == [False, True, True]


def test_offset_plan_view_follows_the_offset_line() -> None:
    carla = pytest.importorskip("carla")
    route = PiecewiseRoute(((50.0, 0.0), (30.0, 1 / 30.0), (40.0, -1 / 50.0), (20.0, 0.0)))
    geometry, total = route.offset_plan_view(1.75, lead_m=10.0)
    lanes = (
        '<laneSection s="0"><right><lane id="-1" type="driving">'
        '<width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane></right>'
        '<center><lane id="0" type="none"/></center></laneSection>'
    )
    assert total == pytest.approx(route.length_m + 20.0 - 30.0 * 1.75 / 30.0 + 40.0 * 1.75 / 50.0)
    xodr = (
        '<?xml version="1.0"?><OpenDRIVE><header revMajor="1" revMinor="4"/>'
        f'<road name="r" length="{total}" id="1" junction="-1"><planView>{geometry}</planView>'
        f"<lanes>{lanes}</lanes></road></OpenDRIVE>"
    )
    m = carla.Map("route", xodr)
    s = np.arange(0.0, route.length_m, 7.0)
    xy, h = route.points(s)
    for (x, y), hd in zip(xy, h, strict=True):  # the route is the right lane's centre
        wp = m.get_waypoint(carla.Location(x=float(x), y=float(-y), z=0.0))
        dx, dy = wp.transform.location.x - x, -wp.transform.location.y - y
        assert abs(-dx * math.sin(hd) + dy * math.cos(hd)) < 0.02  # across the lane
    with pytest.raises(ValueError, match="centre of an arc"):
        PiecewiseRoute(((10.0, 0.0), (5.0, 1 / 5.0))).offset_plan_view(6.0, lead_m=1.0)


def test_pieces_are_checked() -> None:
    with pytest.raises(ValueError, match="positive length"):
        PiecewiseRoute(((0.0, 0.0),))
