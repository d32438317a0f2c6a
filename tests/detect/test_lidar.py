"""The geometric LiDAR detector on synthetic streets and on a real nuScenes sweep."""

from __future__ import annotations

import math
import pickle
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest

from cam2sim.core.frames import Pose, quat_rotate
from cam2sim.core.scene import Ground, SceneBox, StreetScene, car_on_ground
from cam2sim.demo.lidar import (
    LABEL_GROUND,
    LABEL_STRUCTURE,
    LidarModel,
    SyntheticScan,
    parked_street,
    scan_scene,
)
from cam2sim.detect.detector import LidarDetector, load_detector
from cam2sim.detect.lidar import GeometricDetector, GeometricOptions

if TYPE_CHECKING:
    from pathlib import Path

    import numpy.typing as npt

    from cam2sim.detect.boxes import Boxes

LIDAR = LidarModel(azimuths=3600)
DETECTOR = GeometricDetector()


def _sensor_pose(scene: StreetScene, seed: int) -> Pose:
    """A roof LiDAR 1.8 m above the road, in the middle of the street, any heading."""
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(-20.0, 20.0), rng.uniform(-1.0, 1.0)
    z = float(scene.ground.height_at(np.array([x, y]))) + 1.8
    return Pose.from_xyz_rpy([x, y, z], [0.0, 0.0, rng.uniform(-math.pi, math.pi)])


def _cars_in_sensor(scene: StreetScene, pose: Pose) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centres ``(K, 3)``, yaws ``(K,)`` and sizes ``(K, 3)`` of the cars in the sensor frame."""
    centre = pose.inverse().apply(np.array([c.center for c in scene.cars]))
    yaw = np.array([c.yaw for c in scene.cars]) - pose.heading
    return centre, yaw, np.array([c.size for c in scene.cars])


def _clearly_visible(
    scan: SyntheticScan, centre: np.ndarray, yaw: np.ndarray, size: np.ndarray, max_range: float
) -> list[int]:
    """Cars within ``max_range`` whose returns cover their whole length without a gap."""
    out = []
    for k in range(len(centre)):  # a few cars per scene
        pts = scan.points[scan.labels == k, :2].astype(np.float64)
        pts = pts[np.hypot(pts[:, 0], pts[:, 1]) >= 2.0]
        if len(pts) < 30 or np.hypot(*centre[k, :2]) > max_range:
            continue
        along = np.sort(pts @ [math.cos(yaw[k]), math.sin(yaw[k])])
        if np.ptp(along) >= 0.95 * size[k, 0] and np.diff(along).max() <= 0.5:
            out.append(k)
    return out


def _yaw_error_deg(a: float, b: float) -> float:
    """Angle between two box axes (a box has no front), degrees."""
    d = (a - b) % math.pi
    return math.degrees(min(d, math.pi - d))


# (seed, ground, share of cars parked across the kerb)
STREETS: list[tuple[int, Ground, float]] = [
    (0, Ground(), 0.0),
    (1, Ground(slope=(0.08, 0.02)), 0.0),
    (2, Ground(slope=(-0.10, 0.0), kerb_height_m=0.15), 0.0),
    (3, Ground(road_half_width_m=8.0), 0.5),
    (4, Ground(slope=(0.05, -0.03), road_half_width_m=8.0), 0.3),
]
STREET_IDS = ["flat", "uphill-8%", "downhill-10%", "perpendicular", "sloped-mixed"]


@pytest.mark.parametrize(("seed", "ground", "perpendicular"), STREETS, ids=STREET_IDS)
def test_every_clearly_visible_car_is_found(
    seed: int, ground: Ground, perpendicular: float
) -> None:
    scene = parked_street(seed=seed, ground=ground, perpendicular_fraction=perpendicular)
    pose = _sensor_pose(scene, seed)
    scan = scan_scene(scene, pose, lidar=LIDAR, seed=seed)
    boxes = DETECTOR.detect(scan.points)
    centre, yaw, size = _cars_in_sensor(scene, pose)
    visible = _clearly_visible(scan, centre, yaw, size, max_range=20.0)
    assert len(visible) >= 4
    for k in visible:
        d = np.hypot(*(boxes.center[:, :2] - centre[k, :2]).T)
        j = int(np.argmin(d))
        assert d[j] < 0.3, f"car {k} at {centre[k].round(2)}: nearest box {d[j]:.2f} m away"
        assert _yaw_error_deg(boxes.yaw[j], yaw[k]) < 10.0
        length, width, height = boxes.size[j]
        assert abs(length - size[k, 0]) < 0.8
        assert abs(width - size[k, 1]) < 0.3
        assert abs(height - size[k, 2]) < 0.35
        assert abs(boxes.center[j, 2] - centre[k, 2]) < 0.3  # geometric centre, not bottom


def test_boxes_lie_on_cars() -> None:
    """Precision over five streets: a box within 25 m is at most 1 m from some car."""
    near, false = 0, []
    for seed, ground, perpendicular in STREETS:
        scene = parked_street(seed=seed, ground=ground, perpendicular_fraction=perpendicular)
        pose = _sensor_pose(scene, seed)
        boxes = DETECTOR.detect(scan_scene(scene, pose, lidar=LIDAR, seed=seed).points)
        centre, _, _ = _cars_in_sensor(scene, pose)
        for c in boxes.center[np.hypot(boxes.center[:, 0], boxes.center[:, 1]) < 25.0]:
            near += 1
            if np.hypot(*(centre[:, :2] - c[:2]).T).min() > 1.0:
                false.append(c.round(1))
    assert near >= 40
    assert len(false) <= 0.05 * near, false


def test_scores_and_sigmas_follow_the_boxes_doc() -> None:
    scene = parked_street(seed=0)
    boxes = DETECTOR.detect(scan_scene(scene, _sensor_pose(scene, 0), lidar=LIDAR).points)
    assert len(boxes) > 0
    assert boxes.axes == "link"
    assert np.all((boxes.score >= DETECTOR.options.min_score) & (boxes.score <= 1.0))
    assert np.all(boxes.sigma_m > 0)
    assert np.all((boxes.yaw >= -math.pi / 2) & (boxes.yaw < math.pi / 2))
    assert np.all(boxes.size[:, 0] >= boxes.size[:, 1])


def _one_car_scan(
    car_xy: tuple[float, float], yaw: float, detector: GeometricDetector = DETECTOR
) -> Boxes:
    """Detect one 4.5 x 1.8 m car alone on a flat plain, the sensor at the origin."""
    ground = Ground(kerb_height_m=0.0, road_half_width_m=100.0)
    car = car_on_ground(ground, car_xy, yaw, (4.5, 1.8, 1.5))
    scene = StreetScene(ground=ground, cars=(car,))
    pose = Pose.from_xyz_rpy([0.0, 0.0, 1.8], [0.0, 0.0, 0.0])
    return detector.detect(scan_scene(scene, pose, lidar=LIDAR).points)


def test_side_view_grows_the_width_away_from_the_sensor() -> None:
    # A car 6 m to the left, parallel to the sensor's x axis: only its right side is in view.
    boxes = _one_car_scan((0.0, 6.0), 0.0)
    assert len(boxes) == 1
    assert np.hypot(*(boxes.center[0, :2] - [0.0, 6.0])) < 0.15
    assert boxes.size[0, 1] == pytest.approx(1.8, abs=0.05)
    assert boxes.sigma_m[0] > DETECTOR.options.sigma_base_m  # half the box was not seen


def test_end_view_grows_the_length_away_from_the_sensor() -> None:
    # A car 9.75 m ahead, pointing at the sensor: only its end (and its roof) are in view.
    boxes = _one_car_scan((12.0, 0.0), 0.0)
    assert len(boxes) == 1
    assert boxes.center[0, 0] == pytest.approx(12.0, abs=0.3)  # not 7.5, towards the sensor
    assert boxes.size[0, 0] == pytest.approx(4.5, abs=0.05)
    assert _yaw_error_deg(boxes.yaw[0], 0.0) < 10.0
    no_end_views = GeometricDetector(replace(DETECTOR.options, end_views=False))
    assert len(_one_car_scan((12.0, 0.0), 0.0, no_end_views)) == 0


def test_detections_turn_with_the_sensor_frame() -> None:
    """Nothing assumes x forward: a scan turned 90 degrees (nuScenes-style) gives turned boxes."""
    scene = parked_street(seed=5)
    points = scan_scene(scene, _sensor_pose(scene, 5), lidar=LIDAR).points
    quarter = [0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4)]
    turned = points.copy()
    turned[:, :3] = quat_rotate(quarter, points[:, :3])
    a, b = DETECTOR.detect(points), DETECTOR.detect(turned)
    assert len(a) == len(b) > 3
    expected = quat_rotate(quarter, a.center)
    for c, yaw in zip(expected, a.yaw, strict=True):
        j = int(np.argmin(np.hypot(*(b.center[:, :2] - c[:2]).T)))
        assert np.hypot(*(b.center[j, :2] - c[:2])) < 0.1
        assert _yaw_error_deg(b.yaw[j], yaw + math.pi / 2) < 2.0


def test_walls_and_buildings_are_no_cars() -> None:
    ground = Ground(slope=(0.04, 0.0))
    walls = [
        SceneBox((x, 7.0, 4.0), (length, 0.4, 10.0), 0.0)
        for x, length in [(-25.0, 12.0), (-12.0, 3.5), (-6.0, 4.5), (2.0, 5.0), (15.0, 18.0)]
    ]
    walls += [
        SceneBox((0.0, -7.0, 0.6), (30.0, 0.3, 1.2), 0.0),  # a long garden wall
        SceneBox((20.0, -9.0, 4.0), (8.0, 6.0, 10.0), 0.3),  # a kiosk-sized block, turned
    ]
    scene = StreetScene(ground=ground, structures=tuple(walls))
    pose = Pose.from_xyz_rpy([0.0, 0.0, 1.8], [0.0, 0.0, 1.0])
    scan = scan_scene(scene, pose, lidar=LIDAR)
    assert np.count_nonzero(scan.labels == LABEL_STRUCTURE) > 1000
    assert len(DETECTOR.detect(scan.points)) == 0


def test_sloped_street_with_kerbs_and_no_car_gives_nothing() -> None:
    ground = Ground(slope=(0.10, -0.04), kerb_height_m=0.18, road_half_width_m=4.0)
    scene = StreetScene(ground=ground)
    points = scan_scene(scene, Pose.from_xyz_rpy([5.0, 1.0, 2.3], [0.0, 0.0, 2.0]), lidar=LIDAR)
    assert len(points.points) > 50_000
    assert len(DETECTOR.detect(points.points)) == 0


@pytest.mark.parametrize(
    "points",
    [
        pytest.param(np.zeros((0, 4), dtype=np.float32), id="no-points"),
        pytest.param(np.full((50, 4), np.nan, dtype=np.float32), id="all-nan"),
        pytest.param(np.array([[5.0, 0.0, -1.8, 0.1]] * 3, dtype=np.float32), id="three-points"),
        pytest.param(np.zeros((1000, 4), dtype=np.float32), id="all-at-the-sensor"),
    ],
)
def test_degenerate_scans_give_no_boxes(points: npt.NDArray[np.float32]) -> None:
    boxes = DETECTOR.detect(points)
    assert len(boxes) == 0
    assert boxes.center.shape == (0, 3)


def test_ground_only_scan_gives_no_boxes() -> None:
    scene = StreetScene(ground=Ground(kerb_height_m=0.0, road_half_width_m=100.0))
    scan = scan_scene(scene, Pose.from_xyz_rpy([0.0, 0.0, 1.8], [0.0, 0.0, 0.0]), lidar=LIDAR)
    assert np.all(scan.labels == LABEL_GROUND)
    assert len(DETECTOR.detect(scan.points)) == 0


def test_scan_of_the_wrong_shape_is_refused() -> None:
    with pytest.raises(ValueError, match=r"\(N, 4\) array"):
        DETECTOR.detect(np.zeros((10, 2), dtype=np.float32))


def test_detector_meets_the_protocol_and_loads_by_name() -> None:
    assert isinstance(DETECTOR, LidarDetector)
    assert DETECTOR.name == "geometric"
    assert isinstance(load_detector("geometric", "lidar"), GeometricDetector)


def test_options_are_a_frozen_record() -> None:
    opts = GeometricOptions()
    with pytest.raises(AttributeError):
        opts.min_score = 0.0  # type: ignore[misc]
    assert GeometricDetector(replace(opts, min_score=0.9)).options.min_score == 0.9


# -- the synthetic LiDAR ---------------------------------------------------------------------


def test_synthetic_returns_lie_on_what_they_hit() -> None:
    ground = Ground(slope=(0.05, 0.02))
    scene = parked_street(seed=7, ground=ground)
    pose = Pose.from_xyz_rpy([3.0, -0.5, 1.9], [0.0, 0.02, 0.7])
    lidar = LidarModel(beams=16, azimuths=900, range_noise_m=0.0)
    scan = scan_scene(scene, pose, lidar=lidar)
    assert scan.points.dtype == np.float32
    assert scan.points.shape[1] == 4
    assert len(scan.points) <= 16 * 900
    world = pose.apply(scan.points[:, :3].astype(np.float64))
    on_ground = scan.labels == LABEL_GROUND
    assert np.allclose(world[on_ground, 2], ground.height_at(world[on_ground, :2]), atol=0.2)
    for k, car in enumerate(scene.cars):  # a few dozen cars
        hit = world[scan.labels == k]
        c, s = math.cos(car.yaw), math.sin(car.yaw)
        d = hit - np.asarray(car.center)
        local = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], d[:, 2]], -1)
        assert np.all(np.abs(local) <= np.asarray(car.size) / 2 + 1e-3)
    assert np.all((scan.points[:, 3] >= 0) & (scan.points[:, 3] <= 1))


def test_synthetic_scan_is_seeded_and_counts_its_rays() -> None:
    scene = parked_street(seed=1)
    pose = Pose.from_xyz_rpy([0.0, 0.0, 1.8], [0.0, 0.0, 0.0])
    a = scan_scene(scene, pose, lidar=LidarModel(beams=32, azimuths=1000), seed=3)
    b = scan_scene(scene, pose, lidar=LidarModel(beams=32, azimuths=1000), seed=3)
    assert np.array_equal(a.points, b.points)
    assert 0.5 * 32_000 < len(a.points) <= 32_000
    assert a.car_hits(len(scene.cars)).sum() == np.count_nonzero(a.labels >= 0)


@pytest.mark.parametrize(
    "xyz_rpy",
    [
        ([3.0, -0.5, 1.9], [0.0, 0.02, 0.7]),  # mid-street, tilted
        ([0.0, 4.6, 1.2], [0.0, 0.0, -1.3]),  # beside a parked car, looking across the street
        ([-50.0, 0.0, 1.8], [0.0, -0.05, math.pi]),  # at the street's end, facing out
    ],
)
def test_the_angular_windows_drop_no_hit(
    monkeypatch: pytest.MonkeyPatch, xyz_rpy: tuple[list[float], list[float]]
) -> None:
    """A scan equals one whose every ray is tested against every box (no window, no range cut)."""
    from cam2sim.demo import lidar as lidar_module

    scene = parked_street(seed=5, ground=Ground(slope=(0.03, -0.02)), perpendicular_fraction=0.3)
    pose = Pose.from_xyz_rpy(*xyz_rpy)
    model = LidarModel(beams=16, azimuths=720)
    windowed = scan_scene(scene, pose, lidar=model, seed=2)
    everything = (np.arange(model.beams), np.arange(model.azimuths))
    monkeypatch.setattr(
        lidar_module, "_angular_windows", lambda boxes, *_: [everything] * len(boxes)
    )
    brute = scan_scene(scene, pose, lidar=model, seed=2)
    assert np.array_equal(windowed.labels, brute.labels)
    assert np.array_equal(windowed.points, brute.points)
    assert np.count_nonzero(windowed.labels >= 0) > 50  # cars were hit


# -- a real nuScenes sweep --------------------------------------------------------------------

CAR, OTHER_VEHICLES = 0, (1, 2, 3, 4)  # car; truck, trailer, bus, construction vehicle
RANGE_M, MIN_LIDAR_POINTS, MATCH_M = 40.0, 10, 1.0


def _inside_expanded(xy: np.ndarray, box: np.ndarray, margin: float) -> bool:
    """Whether ``xy`` lies in the footprint of an mmdet3d box ``x y z l w h yaw`` plus margin."""
    c, s = math.cos(box[6]), math.sin(box[6])
    dx, dy = xy[0] - box[0], xy[1] - box[1]
    along, across = abs(c * dx + s * dy), abs(-s * dx + c * dy)
    return bool(along <= box[3] / 2 + margin and across <= box[4] / 2 + margin)


def test_nuscenes_sweep_precision_and_recall(shared_data: Path) -> None:
    """Protocol (also in benchmarks/detect_nuscenes.py).

    Recall: annotated cars (label 0) whose centre lies within 40 m (xy) and with at least 10
    LiDAR points count; one is found when a box centre lies within 1 m (xy) of its centre.
    Precision: boxes within 40 m; a box within 1 m of any annotated car is right, one in (or
    within 1 m of) the footprint of an annotated truck, bus, trailer or construction vehicle is
    not counted, any other box is false. Measured: recall 2/2, precision 2/2.
    """
    folder = shared_data / "lidar" / "nuscenes-sample"
    infos = sorted(folder.glob("*.pkl"))
    sweeps = sorted(folder.glob("*LIDAR_TOP*.pcd.bin"))
    if not infos or not sweeps:
        pytest.skip(f"no nuScenes sample in {folder}")
    with infos[0].open("rb") as f:
        info: dict[str, Any] = pickle.load(f)  # a local mmdet3d info file
    instances = info["data_list"][0]["instances"]
    boxes3d = np.array([i["bbox_3d"] for i in instances], dtype=np.float64)  # z is the centre
    labels = np.array([i["bbox_label_3d"] for i in instances])
    n_points = np.array([i["num_lidar_pts"] for i in instances])
    points = np.fromfile(sweeps[0], dtype=np.float32).reshape(-1, 5)[:, :4]
    found = DETECTOR.detect(np.ascontiguousarray(points))

    cars = boxes3d[labels == CAR]
    in_range = np.hypot(cars[:, 0], cars[:, 1]) <= RANGE_M
    targets = cars[in_range & (n_points[labels == CAR] >= MIN_LIDAR_POINTS)]
    det_xy = found.center[np.hypot(found.center[:, 0], found.center[:, 1]) <= RANGE_M, :2]
    matched = [len(det_xy) > 0 and np.hypot(*(det_xy - t[:2]).T).min() <= MATCH_M for t in targets]
    recall = float(np.mean(matched)) if len(targets) else 1.0
    others = boxes3d[np.isin(labels, OTHER_VEHICLES)]
    right = wrong = 0
    for xy in det_xy:
        if np.hypot(*(cars[:, :2] - xy).T).min() <= MATCH_M:
            right += 1
        elif not any(_inside_expanded(xy, o, MATCH_M) for o in others):
            wrong += 1
    precision = right / (right + wrong) if right + wrong else 1.0
    assert len(targets) == 2
    assert recall >= 0.5  # measured 1.0 (2 of 2)
    assert precision >= 0.6  # measured 1.0 (2 of 2): at most one false box
