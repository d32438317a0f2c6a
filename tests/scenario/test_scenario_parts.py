"""Scenario building blocks: body points, CARLA frame round trips, parked-vehicle checks."""

from __future__ import annotations

import json
import math
from typing import TYPE_CHECKING

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cam2sim.core.config import VehicleConfig
from cam2sim.core.frames import WorldFrame
from cam2sim.detect.vehicles import ParkedVehicle
from cam2sim.scenario.body import body_point_positions, vehicle_geometry
from cam2sim.scenario.carla_export import carla_trajectory, trajectory_from_carla
from cam2sim.scenario.checks import check_parked

if TYPE_CHECKING:
    from pathlib import Path

UTM32N = "EPSG:32632"


@pytest.mark.parametrize("reference", ["rear_axle", "center", "offset"])
def test_body_points_keep_the_configured_offsets(reference: str) -> None:
    cfg = VehicleConfig(reference=reference, reference_offset_m=(0.4, 0.2, 0.3))  # type: ignore[arg-type]
    geom = vehicle_geometry(cfg)
    rng = np.random.default_rng(0)
    ref = rng.uniform(-100, 100, (200, 3))
    heading = rng.uniform(-math.pi, math.pi, 200)
    centre = body_point_positions(ref, heading, geom.reference_xyz, (0.0, 0.0, 0.0))
    rear = body_point_positions(ref, heading, geom.reference_xyz, geom.rear_axle_xyz)
    r = np.array(geom.reference_xyz)
    # Distances equal the configured offsets, for every pose.
    np.testing.assert_allclose(np.linalg.norm(centre - ref, axis=1), np.linalg.norm(r), atol=1e-9)
    np.testing.assert_allclose(
        np.linalg.norm(rear - centre, axis=1), abs(cfg.rear_axle_x_m), atol=1e-9
    )
    # The rear axle lies straight behind the centre along the heading.
    d = rear - centre
    np.testing.assert_allclose(np.arctan2(-d[:, 1], -d[:, 0]), heading, atol=1e-9)
    if reference == "rear_axle":
        np.testing.assert_allclose(rear, ref, atol=1e-12)
        # The centre is 1.393 m ahead of the recorded point (not 1.393 - 0.13 m).
        ahead = (centre - ref)[:, 0] * np.cos(heading) + (centre - ref)[:, 1] * np.sin(heading)
        np.testing.assert_allclose(ahead, 1.393, atol=1e-9)
    if reference == "center":
        np.testing.assert_allclose(centre, ref, atol=1e-12)


@settings(max_examples=50, deadline=None)
@given(
    xy=st.lists(st.floats(-5e4, 5e4), min_size=3, max_size=3),
    heading=st.floats(-math.pi, math.pi),
)
def test_carla_trajectory_round_trips(xy: list[float], heading: float) -> None:
    entries = carla_trajectory([7], [1.5], [xy], [heading])
    assert entries[0]["frame_id"] == 7
    assert entries[0]["transform"]["location"]["y"] == pytest.approx(-xy[1], abs=1e-6)
    pos, h = trajectory_from_carla(json.loads(json.dumps(entries)))
    np.testing.assert_allclose(pos[0], xy, atol=1e-6)
    assert abs(math.remainder(float(h[0]) - heading, 2 * math.pi)) < 1e-7


def test_real_reference_drive_round_trips_through_carla_within_a_millimetre(
    shared_data: Path,
) -> None:
    csv = shared_data / "reference-drives" / "trajectory1.csv"
    if not csv.is_file():
        pytest.skip(f"{csv} is absent")
    data = np.genfromtxt(csv, delimiter=",", names=True)
    utm = np.column_stack([data["x"], data["y"], data["z"]])
    world = WorldFrame.at_crs_point(UTM32N, utm[0, 0], utm[0, 1])
    xyz = world.from_crs(UTM32N, utm)
    heading = world.heading_from_crs(UTM32N, utm[:, :2], data["yaw"] - math.pi / 2)
    geom = vehicle_geometry(VehicleConfig())
    centre = body_point_positions(xyz, heading, geom.reference_xyz, (0.0, 0.0, 0.0))
    t = data["timestamp"] - data["timestamp"][0]
    for points in (xyz, centre):
        entries = json.loads(json.dumps(carla_trajectory(np.arange(len(t)), t, points, heading)))
        back, h = trajectory_from_carla(entries)
        assert np.abs(back - points).max() < 1e-3  # every pose within 1 mm
        assert np.abs(np.angle(np.exp(1j * (h - heading)))).max() < 1e-6
    assert len(t) > 1000


def _car(vid: str, x: float, y: float, yaw: float = 0.0, conf: float = 0.8) -> ParkedVehicle:
    return ParkedVehicle(
        id=vid,
        position=(x, y, 0.0),
        yaw=yaw,
        size=(4.5, 1.8, 1.5),
        confidence=conf,
        hits=5,
        side="right" if y < 0 else "left",
        orientation="parallel",
        source="lidar",
    )


def test_checks_report_cars_on_the_path_and_overlapping_cars() -> None:
    path = np.column_stack([np.linspace(0, 100, 201), np.zeros(201)])
    cars = [
        _car("ok", 20.0, -4.0),
        _car("on_path", 40.0, -0.8),  # half the footprint in the ego's 2.16 m swept path
        _car("a", 60.0, 4.0, conf=0.9),
        _car("b", 61.5, 4.2, conf=0.5),  # overlaps a, less confident
        _car("touching", 66.6, 4.0),  # 0.1 m gap to a's neighbour area: no overlap
    ]
    reasons = check_parked(cars, path, 2.16, None)
    assert set(reasons) == {"on_path", "b"}
    assert "recorded path" in reasons["on_path"][0]
    assert "overlaps a" in reasons["b"][0]
    assert check_parked([], path, 2.16, None) == {}
