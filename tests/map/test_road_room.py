"""Room on the road for the recorded car's sweep: lanes widen where its body came near the edge."""

from __future__ import annotations

import numpy as np
import pytest
import shapely

from cam2sim.map.query import DRIVING, RoadMap
from cam2sim.map.road_room import RecordedBody, lane_widening
from cam2sim.map.trajectory_road import TrajectoryRoadOptions, trajectory_road

CAR = RecordedBody(length_m=4.6, width_m=1.85, reference_xy=(-1.4, 0.0))  # poses at the rear axle


def _u_turn(radius: float = 6.0) -> tuple[np.ndarray, np.ndarray]:
    """60 m east, a left U-turn of ``radius`` (rear axle), 60 m back west; headings."""
    a = np.arange(0.0, np.pi, 0.3 / radius)
    xy = np.concatenate(
        [
            np.column_stack([np.arange(-60.0, 0.0, 0.5), np.zeros(120)]),
            np.column_stack([radius * np.sin(a), radius - radius * np.cos(a)]),
            np.column_stack([np.arange(0.0, -60.0, -0.5), np.full(120, 2 * radius)]),
        ]
    )
    heading = np.concatenate([np.zeros(120), a, np.full(120, np.pi)])
    return xy, heading


def test_a_u_turn_widens_the_outer_lane_there_and_nowhere_else() -> None:
    xy, heading = _u_turn()
    opts = TrajectoryRoadOptions()
    narrow = trajectory_road(xy, opts)
    wide = trajectory_road(xy, opts, body=RecordedBody(**{**CAR.__dict__, "heading": heading}))
    assert narrow.widened_m == 0.0
    assert 0.5 < wide.widened_m < 1.5  # the front corner swings ~0.9 m beyond the half width
    assert wide.widened_length_m < 60.0  # the turn and its tapers, not the straights
    corners = CAR.corners(xy, heading).reshape(-1, 2)
    for road, room in ((narrow, None), (wide, 0.35)):
        area = RoadMap.from_xodr(road.xodr).drivable_area((DRIVING,))
        gap = shapely.distance(area.exterior, shapely.points(corners))
        inside = shapely.contains_xy(area, corners[:, 0], corners[:, 1])
        if room is None:  # the plain 3.35 m lane: the recorded car itself leaves it
            assert not inside.all()
        else:  # widened: every corner inside with room to spare
            assert inside.all()
            assert gap.min() > room


def test_a_straight_drive_needs_no_room_and_a_gps_heading_is_not_a_sweep() -> None:
    xy = np.column_stack([np.arange(0.0, 200.0, 0.5), np.zeros(400)])
    rng = np.random.default_rng(0)
    noisy = xy + rng.normal(0.0, 0.1, xy.shape)
    wobble = rng.normal(0.0, 0.05, len(xy))  # a heading from noisy motion: +-3 degrees
    as_recorded = trajectory_road(noisy, body=RecordedBody(**{**CAR.__dict__, "heading": wobble}))
    along_path = trajectory_road(noisy, body=CAR)
    assert along_path.widened_m == 0.0  # the car put along the smoothed path: no sweep
    assert as_recorded.widened_m > 0.1  # a noisy heading would widen the road for nothing


def test_widening_tapers_in_and_out_and_covers_each_need() -> None:
    s = np.linspace(0.0, 100.0, 401)
    xy = np.column_stack([s, np.zeros_like(s)])
    heading = np.zeros_like(s)
    # one corner 2.0 m right of the path at station 50: 0.325 m past the 1.675 m edge
    out = lane_widening(
        s, xy, heading, [[50.0, -2.0]], [49.0], band=(-1.675, 5.025),
        stations=s, room_m=0.5, taper_m=10.0, hold_m=0.0,
    )  # fmt: skip
    need = 2.0 - 1.675 + 0.5
    assert out.right_m.max() == pytest.approx(need, abs=1e-6)
    assert out.right_m[np.argmax(out.right_m)] == pytest.approx(need)
    assert s[np.argmax(out.right_m)] == pytest.approx(50.0, abs=0.25)
    assert out.right_m[s <= 39.5].max() == 0.0  # gone 10 m away
    assert out.right_m[s == 45.0][0] == pytest.approx(need / 2, abs=0.02)  # linear taper
    assert not out.left_m.any()
