"""Fusion of per-frame boxes: association, weighted means, axial yaw, votes, hit filter."""

from __future__ import annotations

import numpy as np
import pytest

from cam2sim.core.frames import Pose
from cam2sim.detect.boxes import Boxes
from cam2sim.detect.fusion import FusionOptions, WorldBoxes, boxes_to_world, fuse
from cam2sim.detect.route import Route
from cam2sim.detect.snap import snap_to_road_edges
from cam2sim.detect.vehicles import ParkedVehicle

# A straight route along +x; cars parked on both sides.
ROUTE = Route.from_xy(np.stack([np.linspace(0, 100, 201), np.zeros(201)], 1))
CARS = np.array(
    [
        # x, y, yaw, length, width
        [10.0, -3.5, 0.02, 4.5, 1.8],  # right, parallel
        [15.5, -3.5, -0.03, 4.2, 1.8],  # right, parallel, 5.5 m behind the first
        [30.0, 4.0, np.pi / 2, 4.6, 1.9],  # left, perpendicular
        [50.0, -3.4, np.pi - 0.02, 4.4, 1.8],  # right, parallel, box yaw flipped
    ]
)


def _frames(rng: np.random.Generator, n_frames: int = 30, noise: float = 0.15) -> WorldBoxes:
    """Boxes of the cars seen from poses along the route, with noise and yaw flips."""
    parts = []
    for f in range(n_frames):
        ego = np.array([f * 2.0, 0.0, 0.0])
        seen = np.linalg.norm(CARS[:, :2] - ego[:2], axis=1) < 25
        cars = CARS[seen]
        n = cars.shape[0]
        if n == 0:
            continue
        # Sensor frame: translated by the ego position (no rotation), box centres at 0.75 m.
        center = np.column_stack([cars[:, :2] - ego[:2], np.full(n, 0.75)])
        center[:, :2] += rng.normal(0, noise, (n, 2))
        yaw = cars[:, 2] + rng.normal(0, 0.05, n) + np.pi * rng.integers(0, 2, n)
        size = np.column_stack([cars[:, 3], cars[:, 4], np.full(n, 1.5)])
        boxes = Boxes(center, size, yaw, np.full(n, 0.8), np.full(n, noise), "link")
        parts.append(boxes_to_world(boxes, Pose(ego, np.array([0, 0, 0, 1.0])).as_matrix(), f))
    return WorldBoxes.concatenate(parts)


def test_fusion_recovers_each_car_once() -> None:
    rng = np.random.default_rng(0)
    boxes = _frames(rng)
    vehicles, member = fuse(boxes, ROUTE, source="lidar")
    assert len(vehicles) == len(CARS)
    assert member.shape == (len(boxes),)
    assert (member >= 0).all()
    pos = np.array([v.position[:2] for v in vehicles])
    np.testing.assert_allclose(pos, CARS[:, :2], atol=0.1)
    # Ordered along the route, ids in that order.
    assert [v.id for v in vehicles] == ["pv_000", "pv_001", "pv_002", "pv_003"]
    assert [v.side for v in vehicles] == ["right", "right", "left", "right"]
    assert [v.orientation for v in vehicles] == [
        "parallel",
        "parallel",
        "perpendicular",
        "parallel",
    ]
    # Axial mean: despite random pi flips, parallel cars face the direction of travel (+x).
    yaws = np.array([v.yaw for v in vehicles])
    assert abs(yaws[0] - 0.02) < 0.05
    assert abs(yaws[3] - (-0.02)) < 0.05
    assert abs(abs(yaws[2]) - np.pi / 2) < 0.05
    assert all(v.position[2] == pytest.approx(0.0, abs=1e-9) for v in vehicles)
    assert all(v.hits > 3 for v in vehicles)


def test_close_cars_in_one_frame_stay_apart() -> None:
    """Two cars 2.5 m apart (perpendicular parking) are seen together in every frame."""
    centre = np.array([[20.0, 4.0, 0.75], [22.5, 4.0, 0.75]])
    parts = []
    rng = np.random.default_rng(1)
    for f in range(10):
        c = centre + np.column_stack([rng.normal(0, 0.3, (2, 2)), np.zeros(2)])
        boxes = Boxes(c, [[4.5, 1.8, 1.5]] * 2, [np.pi / 2] * 2, [0.9, 0.9], [0.3, 0.3])
        parts.append(boxes_to_world(boxes, np.eye(4), f))
    vehicles, _ = fuse(WorldBoxes.concatenate(parts), ROUTE, source="lidar")
    assert len(vehicles) == 2
    assert vehicles[1].position[0] - vehicles[0].position[0] == pytest.approx(2.5, abs=0.3)


def test_min_hits_and_range_filter() -> None:
    one = Boxes([[5.0, -3.0, 0.7]], [[4.5, 1.8, 1.5]], [0.0], [0.9], [0.1])
    far = Boxes([[60.0, -3.0, 0.7]], [[4.5, 1.8, 1.5]], [0.0], [0.9], [0.1])
    parts = [boxes_to_world(one, np.eye(4), f) for f in range(2)]
    parts += [boxes_to_world(far, np.eye(4), f) for f in range(5)]
    vehicles, member = fuse(
        WorldBoxes.concatenate(parts), ROUTE, source="lidar", options=FusionOptions(min_hits=3)
    )
    assert vehicles == []  # the near one has 2 hits; the far one is out of range
    assert (member == -1).all()
    vehicles, _ = fuse(
        WorldBoxes.concatenate(parts),
        ROUTE,
        source="lidar",
        options=FusionOptions(min_hits=2, max_range_m=100),
    )
    assert len(vehicles) == 2


def test_weights_favour_confident_precise_boxes() -> None:
    """A far, uncertain box pulls the mean far less than near, precise ones."""
    near = Boxes([[10.0, -3.0, 0.7]] * 3, [[4.5, 1.8, 1.5]] * 3, [0.0] * 3, [0.9] * 3, [0.2] * 3)
    off = Boxes([[11.5, -3.0, 0.7]], [[4.5, 1.8, 1.5]], [0.0], [0.5], [1.0])
    parts = [boxes_to_world(near.select(np.array([i])), np.eye(4), i) for i in range(3)]
    parts.append(boxes_to_world(off, np.eye(4), 3))
    vehicles, _ = fuse(WorldBoxes.concatenate(parts), ROUTE, source="camera")
    assert len(vehicles) == 1
    w_near, w_off = 0.9 / 0.2**2, 0.5 / 1.0**2
    expected = (3 * w_near * 10.0 + w_off * 11.5) / (3 * w_near + w_off)
    assert vehicles[0].position[0] == pytest.approx(expected, abs=1e-6)
    assert vehicles[0].source == "camera"


def test_boxes_to_world_rotates_yaw_and_optical_axes() -> None:
    # A camera looking along world +y (optical z -> world +y, optical x -> world +x).
    R = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = [1.0, 2.0, 1.5]
    boxes = Boxes([[0.0, 0.75, 10.0]], [[4.0, 1.8, 1.5]], [0.0], [0.7], [0.5], "optical")
    wb = boxes_to_world(boxes, T, 7)
    np.testing.assert_allclose(wb.bottom[0], [1.0, 12.0, 0.0], atol=1e-12)
    assert wb.yaw[0] == pytest.approx(0.0)  # length along optical x = world +x
    assert wb.range_m[0] == pytest.approx(np.hypot(0.75, 10.0))
    assert wb.frame[0] == 7


def test_empty_input() -> None:
    vehicles, member = fuse(WorldBoxes.concatenate([]), ROUTE, source="lidar")
    assert vehicles == []
    assert member.shape == (0,)


class _FakeEdge:
    def __init__(self, side: str, y: float) -> None:
        self.side = side
        self.xy = np.stack([np.linspace(0, 100, 201), np.full(201, y)], 1)
        self.heading = np.zeros(201)


class _FakeMap:
    def road_edges(self) -> tuple[_FakeEdge, ...]:
        return (_FakeEdge("right", -4.0), _FakeEdge("left", 4.0))


def test_snap_to_road_edge_moves_parallel_cars_to_the_kerb() -> None:
    base = {"size": (4.5, 1.8, 1.5), "confidence": 0.9, "hits": 5, "source": "lidar"}
    cars = [
        ParkedVehicle(
            id="a",
            position=(10.0, -2.7, 0.0),
            yaw=0.1,
            side="right",
            orientation="parallel",
            **base,
        ),
        ParkedVehicle(
            id="b", position=(20.0, 2.5, 0.0), yaw=3.0, side="left", orientation="parallel", **base
        ),
        ParkedVehicle(
            id="c",
            position=(30.0, -2.7, 0.0),
            yaw=0.1,
            side="right",
            orientation="parallel",
            edited=True,
            **base,
        ),
        ParkedVehicle(
            id="d",
            position=(40.0, -12.0, 0.0),
            yaw=0.1,
            side="right",
            orientation="parallel",
            **base,
        ),
    ]
    out, moved = snap_to_road_edges(cars, _FakeMap())  # type: ignore[arg-type]
    assert moved == 2
    assert out[0].position[1] == pytest.approx(-4.0 + 0.9 + 0.2)
    assert out[0].yaw == pytest.approx(0.0)
    assert out[1].position[1] == pytest.approx(4.0 - 0.9 - 0.2)
    assert abs(out[1].yaw) == pytest.approx(np.pi)  # kept facing its detected way
    assert out[2] == cars[2]  # edited by hand: untouched
    assert out[3] == cars[3]  # too far from any edge
