"""From recorded poses to a model trained at adjusted ones: the smoothed corrections."""

from __future__ import annotations

import numpy as np
import pytest

from cam2sim.core import frames as fr
from cam2sim.splat.geometry import on_route_ground, recorded_to_model, smoothed_corrections


def _poses(x: np.ndarray, y: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Cameras (optical axes: z forward, x right, y down) driving along world x."""
    base = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # cam -> body axes
    T = np.tile(np.eye(4), (len(x), 1, 1))
    T[:, :3, :3] = fr.quat_to_matrix(fr.quat_from_yaw(yaw)) @ base
    T[:, :3, 3] = np.stack([x, y, np.full_like(x, 1.6)], -1)
    return T


def test_smoothed_corrections_keep_the_drift_and_drop_the_jitter() -> None:
    """GPS-like records of a straight drive: a slow 0.5 m drift and a 3-degree heading error
    (what an adjustment corrects), and 0.1 m of jitter at every fix (what a smooth pose in the
    closed loop does not have). From a smooth recorded pose the corrections reach the adjusted
    (true) one within centimetres; the raw per-frame correction would add the jitter back."""
    n = 400
    s = np.arange(n) * 0.75
    truth = _poses(s, np.zeros(n), np.zeros(n))
    drift = 0.5 * np.sin(s / 60.0)
    heading_error = np.radians(3.0) * np.cos(s / 80.0)
    smooth = _poses(s, drift, heading_error)
    jitter = np.random.default_rng(0).normal(0.0, 0.1, n)
    recorded = _poses(s, drift + jitter, heading_error)
    held = np.arange(n) % 8 == 4
    rows = smoothed_corrections(recorded, truth, s, ~held, sigma_m=2.0)
    mapped = recorded_to_model(smooth, rows)
    inside = (s > 10) & (s < s[-1] - 10)
    err = np.linalg.norm(mapped[:, :3, 3] - truth[:, :3, 3], axis=1)[inside]
    assert err.mean() < 0.05
    turn = np.degrees(fr.quat_angle_between(
        fr.quat_from_matrix(mapped[:, :3, :3]), fr.quat_from_matrix(truth[:, :3, :3])
    ))[inside]  # fmt: skip
    assert turn.max() < 0.1
    raw = smoothed_corrections(recorded, truth, s, ~held, sigma_m=0.01)
    raw_err = np.linalg.norm(recorded_to_model(smooth, raw)[:, :3, 3] - truth[:, :3, 3], axis=1)
    assert raw_err[inside].mean() > 2 * err.mean()
    # At a recorded pose itself, nearly unsmoothed corrections give the adjusted pose back.
    used = ~held
    assert np.allclose(recorded_to_model(recorded, raw)[used], truth[used], atol=1e-3)
    one = recorded_to_model(smooth[10], rows[10])
    assert one.shape == (4, 4)
    assert np.allclose(one, mapped[10])


def test_smoothed_corrections_refuse_mismatched_input() -> None:
    T = _poses(np.arange(5.0), np.zeros(5), np.zeros(5))
    with pytest.raises(ValueError, match="N, 4, 4"):
        smoothed_corrections(T, T[:4], np.arange(5.0), np.ones(5, bool), sigma_m=1.0)
    with pytest.raises(ValueError, match="at least one"):
        smoothed_corrections(T, T, np.arange(5.0), np.zeros(5, bool), sigma_m=1.0)


def _tilted(yaw: float, pitch: float, roll: float, xyz: tuple[float, float, float]) -> np.ndarray:
    """A camera (optical axes) on a car with ROS yaw, pitch (nose down) and roll, at ``xyz``."""
    base = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    T = np.eye(4)
    T[:3, :3] = fr.quat_to_matrix(fr.quat_from_euler(roll, pitch, yaw)) @ base
    T[:3, 3] = xyz
    return T


def test_on_route_ground_keeps_the_vehicles_place_and_heading_and_takes_height_and_tilt() -> None:
    """A planar car's camera (level, at a jittered GPS height) given the recorded view's height
    and tilt: its own x, y and heading stay; it ends up as the recorded camera would stand
    there, the car pitched 4 degrees on a grade and rolled 2 degrees."""
    view = _tilted(np.radians(30.0), np.radians(4.0), np.radians(2.0), (5.0, 2.0, 1.65))
    car = _tilted(np.radians(37.0), 0.0, 0.0, (5.3, 1.8, 1.95))
    out = on_route_ground(car, 1.65, view[:3, 2], view[:3, 1])
    want = _tilted(np.radians(37.0), np.radians(4.0), np.radians(2.0), (5.3, 1.8, 1.65))
    np.testing.assert_allclose(out, want, atol=1e-9)
    np.testing.assert_allclose(out[:3, :3] @ out[:3, :3].T, np.eye(3), atol=1e-12)
    only_height = on_route_ground(car, 1.65, view[:3, 2], None)
    np.testing.assert_allclose(only_height[:3, :3], car[:3, :3])
    assert only_height[2, 3] == 1.65
