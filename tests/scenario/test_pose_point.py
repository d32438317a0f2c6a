"""Where the poses sit along the car, from the path's slip in the turns (``fit_pose_point``)."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from cam2sim.core.vehicle import SteeringCalibration
from cam2sim.scenario.calibration import fit_pose_point, steering_from_poses

Drive = Callable[..., tuple[np.ndarray, ...]]


def test_a_camera_ahead_of_the_rear_axle_is_found_from_the_turns(bicycle_drive: Drive) -> None:
    t, xy, heading, v, _ = bicycle_drive(1.3)
    fit = fit_pose_point(t, xy, heading, v)
    assert fit is not None
    assert fit.ahead_m == pytest.approx(1.3, abs=0.05)
    assert fit.stderr_m < 0.05
    assert abs(fit.yaw_offset_rad) < 1e-3
    assert fit.turning >= 20


def test_poses_at_the_rear_axle_and_a_heading_askew_of_the_travel(bicycle_drive: Drive) -> None:
    t, xy, heading, v, _ = bicycle_drive(0.0)
    fit = fit_pose_point(t, xy, heading + math.radians(1.0), v)  # a sensor yawed 1 degree
    assert fit is not None
    assert fit.ahead_m == pytest.approx(0.0, abs=0.05)
    assert fit.yaw_offset_rad == pytest.approx(-math.radians(1.0), abs=2e-3)


def test_a_straight_drive_cannot_tell(bicycle_drive: Drive) -> None:
    t, xy, heading, v, _ = bicycle_drive(1.0, turns=())
    assert fit_pose_point(t, xy, heading, v) is None


def test_derived_steering_of_the_rear_axle_keeps_a_sharp_turns_peak(bicycle_drive: Drive) -> None:
    """The rear axle's path (not the camera's) and a 2 m window: the command as driven."""
    cal = SteeringCalibration()
    t, xy, heading, v, kap = bicycle_drive(1.3, turns=(-0.14,))  # KITTI 03's 7 m junction
    rear = xy - 1.3 * np.stack([np.cos(heading), np.sin(heading)], -1)
    ts, steer = steering_from_poses(t, rear, heading, v, cal)
    peak = float(np.min(steer))
    assert peak == pytest.approx(-0.14 / cal.curvature_per_unit, rel=0.005)  # 1.6 % short: camera
    driven = np.interp(ts, t, kap / cal.curvature_per_unit)
    inside = (ts > 1.0) & (ts < t[-1] - 1.0)
    assert np.abs(steer[inside] - driven[inside]).mean() < 0.25  # a 6 m window: 0.47


def _kitti_poses(path: Path) -> tuple[np.ndarray, ...]:
    """KITTI camera-to-world lines as times (10 Hz), ground-plane positions, headings, speeds."""
    m = np.loadtxt(path).reshape(-1, 3, 4)
    xy = np.stack([m[:, 2, 3], -m[:, 0, 3]], -1)  # optical z forward, x right -> x fwd, y left
    heading = np.arctan2(-m[:, 0, 2], m[:, 2, 2])  # the optical axis in that plane
    t = np.arange(m.shape[0]) / 10.0
    speed = np.concatenate([[0.0], np.hypot(*np.diff(xy, axis=0).T) * 10.0])
    return t, xy, heading, speed


def test_kitti_03s_camera_sits_0_88_m_ahead_of_the_rear_axle(shared_data: Path) -> None:
    """Measured on the real drive: 0.88 m (KITTI's camera is ~1.1 m ahead of its GPS/IMU)."""
    t, xy, heading, speed = _kitti_poses(shared_data / "posed" / "kitti-odometry-03" / "poses.txt")
    fit = fit_pose_point(t, xy, heading, speed)
    assert fit is not None
    assert fit.ahead_m == pytest.approx(0.88, abs=0.05)
    assert fit.stderr_m < 0.05


@pytest.mark.parametrize("n", [1, 2, 3])
def test_the_reference_drives_poses_are_at_the_rear_axle(shared_data: Path, n: int) -> None:
    drives = shared_data / "reference-drives"
    tr = np.genfromtxt(drives / f"trajectory{n}.csv", delimiter=",", names=True)
    t = tr["timestamp"]
    xy = np.stack([tr["x"], tr["y"]], -1)
    grid = np.arange(t[0], t[-1], 0.2)  # speed over 0.2 s: the stamps come in bursts
    gx, gy = np.interp(grid, t, xy[:, 0]), np.interp(grid, t, xy[:, 1])
    speed = np.interp(t, grid, np.hypot(np.gradient(gx, grid), np.gradient(gy, grid)))
    fit = fit_pose_point(t, xy, tr["yaw"] - math.pi / 2, speed)  # odometry yaw -> ENU
    assert fit is not None
    assert abs(fit.ahead_m) < 0.15  # base_link: the rear axle
