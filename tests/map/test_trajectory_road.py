"""The road along the driven path: geometry, lanes, and real poses (KITTI 03)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from cam2sim.core.errors import ConfigError, StageError
from cam2sim.map.opendrive import parse_opendrive
from cam2sim.map.query import DRIVING, RoadMap
from cam2sim.map.report import fit_route
from cam2sim.map.trajectory_road import TrajectoryRoadOptions, smooth_path, trajectory_road

from .map_helpers import has_carla

KITTI_POSES = (
    Path(__file__).resolve().parents[2].parent
    / "shared"
    / "data"
    / "posed"
    / "kitti-odometry-03"
    / "poses.txt"
)


def _l_path(noise_m: float = 0.0) -> np.ndarray:
    """100 m straight east, a quarter circle of 20 m radius to the north, 60 m north."""
    straight = np.column_stack([np.arange(0, 100, 0.5), np.zeros(200)])
    a = np.linspace(0, np.pi / 2, 80)
    bend = np.column_stack([100 + 20 * np.sin(a), 20 - 20 * np.cos(a)])
    north = np.column_stack([np.full(120, 120.0), 20 + np.arange(0.5, 60.5, 0.5)])
    xy = np.concatenate([straight, bend, north])
    rng = np.random.default_rng(0)
    xy = xy + rng.normal(0, noise_m, xy.shape)
    return np.column_stack([xy, np.full(len(xy), 0.7)])


def _kitti_xyz() -> np.ndarray:
    if not KITTI_POSES.is_file():
        pytest.skip(f"KITTI 03 poses not found at {KITTI_POSES}")
    cam = np.loadtxt(KITTI_POSES).reshape(-1, 3, 4)[:, :, 3]
    # KITTI's camera frame: x right, y down, z forward; the ground plane is x-z.
    return np.column_stack([cam[:, 2], -cam[:, 0], -cam[:, 1]])


def test_the_car_drives_in_the_right_lane_of_a_road_that_follows_its_path() -> None:
    xyz = _l_path(noise_m=0.05)
    road = trajectory_road(xyz, TrajectoryRoadOptions(pose_height_m=0.7))
    drive = parse_opendrive(road.xodr)
    assert len(drive.roads) == 1
    assert not drive.junctions
    road_map = RoadMap.from_xodr(road.xodr)
    fit = fit_route(road_map, xyz[:, :2], np.arange(len(xyz)) * 0.05, None)
    assert fit.report.covered_fraction == pytest.approx(1.0)
    # Lane -1's centre is the path: within a few centimetres on the straights, the bend cut by
    # the smoothing by less than half a metre.
    assert float(np.median(fit.offset_m)) < 0.1
    assert float(fit.offset_m.max()) < 0.5
    assert road.fit_m < 0.15
    # The road is 2 x 3.35 m: its centre 1.675 m left of the eastward straight (y > 0); it
    # starts 10 m before the first pose and ends 10 m after the last.
    start = road.centre_xy[0]
    assert start == pytest.approx([-10.0, 1.675], abs=0.1)
    assert road.length_m == pytest.approx(20 + 100 + np.pi * (20 - 1.675) / 2 + 60, rel=0.02)
    assert 'a="0.000000"' in road.xodr  # the road under a pose 0.7 m above it


def test_left_hand_traffic_puts_the_road_on_the_other_side() -> None:
    road = trajectory_road(_l_path(), TrajectoryRoadOptions(driving_side="left", lanes=2))
    assert road.centre_xy[0][1] == pytest.approx(-3.35 * 1.5, abs=0.1)  # right of the path
    assert 'rule="LHT"' in road.xodr
    assert RoadMap.from_xodr(road.xodr).lane_indices(DRIVING).size == 4


def test_a_path_too_short_or_bad_options_are_clear_errors() -> None:
    with pytest.raises(StageError, match=r"drove only 4\.5 m.*--osm"):
        trajectory_road(_l_path()[:10])
    with pytest.raises(ConfigError, match="lanes=7"):
        TrajectoryRoadOptions(lanes=7)
    nan = _l_path()
    nan[3, 0] = np.nan
    with pytest.raises(StageError, match="no finite positions"):
        trajectory_road(nan)


def test_smoothing_keeps_the_ends_and_drops_standstills() -> None:
    xyz = _l_path()
    stand = np.concatenate([xyz[:1].repeat(30, axis=0), xyz])  # the car waited at the start
    s, smooth = smooth_path(stand)
    assert s[-1] == pytest.approx(smooth_path(xyz)[0][-1], rel=1e-6)
    assert np.allclose(smooth[0, :2], xyz[0, :2], atol=1e-6)
    assert np.allclose(smooth[-1, :2], xyz[-1, :2], atol=1e-6)


def test_a_tight_turn_keeps_its_radius_and_the_noise_still_goes() -> None:
    """A 6 m U-turn: a plain Gaussian of 2 m pulled the road 0.3 m inside the driven path."""
    a = np.linspace(0.0, np.pi, 60)
    xy = np.concatenate(
        [
            np.column_stack([np.arange(-60.0, 0.0, 0.5), np.zeros(120)]),
            np.column_stack([6.0 * np.sin(a), 6.0 - 6.0 * np.cos(a)]),
            np.column_stack([np.arange(-0.5, -60.5, -0.5), np.full(120, 12.0)]),
        ]
    )
    _, smooth = smooth_path(xy, smooth_m=2.0)
    bend = smooth[:, 0] > 0.5
    radius = np.hypot(smooth[bend, 0], smooth[bend, 1] - 6.0)
    assert np.abs(radius - 6.0).max() < 0.06
    noisy = xy + np.random.default_rng(0).normal(0.0, 0.1, xy.shape)
    _, smooth = smooth_path(noisy, smooth_m=2.0)
    straight = (smooth[:, 0] < -10.0) & (smooth[:, 1] < 6.0)
    assert np.abs(smooth[straight, 1]).max() < 0.1  # the 0.1 m jitter, smoothed out


def test_kitti_03s_poses_give_a_road_it_drove_on() -> None:
    xyz = _kitti_xyz()
    road = trajectory_road(xyz, TrajectoryRoadOptions(pose_height_m=1.65))
    assert 560 < road.length_m < 600  # the 561 m country road and 10 m at each end
    road_map = RoadMap.from_xodr(road.xodr)
    fit = fit_route(road_map, xyz[:, :2], np.arange(len(xyz)) / 10.0, None)
    assert fit.report.covered_fraction == pytest.approx(1.0)
    assert float(np.median(fit.offset_m)) < 0.1
    assert road.fit_m < 0.2


@pytest.mark.skipif(not has_carla(), reason="needs carla (pip install cam2sim[map])")
def test_carla_reads_the_road_and_puts_the_car_in_lane_minus_one() -> None:
    import pyproj

    os.environ.setdefault("PROJ_DATA", pyproj.datadir.get_data_dir())
    import carla

    xyz = _l_path()
    road = trajectory_road(xyz, TrajectoryRoadOptions(pose_height_m=0.7))  # the road at z = 0
    town = carla.Map("path", road.xodr)
    assert len(town.generate_waypoints(5.0)) > 50
    for k in (20, 230, 350):  # straight, bend, north; CARLA's y points the other way
        here = carla.Location(x=float(xyz[k, 0]), y=float(-xyz[k, 1]), z=0.0)
        waypoint = town.get_waypoint(here)
        assert waypoint.lane_id == -1
        assert waypoint.transform.location.distance(here) < 0.5
