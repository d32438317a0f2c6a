"""Stage detect end to end: a bag with odometry and LiDAR of a parked street -> vehicles."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

import numpy as np
import pytest
from typer.testing import CliRunner

from cam2sim.cli.main import app
from cam2sim.core.config import (
    CameraConfig,
    Config,
    IntrinsicsConfig,
    LidarConfig,
    MountConfig,
    PoseConfig,
    RecordingConfig,
    TopicsConfig,
)
from cam2sim.core.errors import ConfigError, StageError
from cam2sim.core.frames import Pose, WorldFrame
from cam2sim.core.scene import Ground, SceneBox, StreetScene
from cam2sim.core.table import read_table
from cam2sim.core.workspace import Workspace
from cam2sim.demo.lidar import LidarModel, scan_scene
from cam2sim.detect.vehicles import ParkedVehicles
from cam2sim.recording.bagwriter import BagWriter
from cam2sim.stages.detect import DetectOptions, run_detect
from cam2sim.stages.extract import extract

if TYPE_CHECKING:
    from pathlib import Path

UTM32N = "EPSG:32632"
E0, N0 = 691_000.0, 5_336_000.0  # Munich, UTM 32N
SPEED = 5.0  # m/s along +easting
DURATION_S = 10.0
LIDAR_HZ = 4.0
MOUNT = (0.5, 0.0, 1.8)
# Ground truth in the street frame (metres from (E0, N0)): x, y, yaw; three right, two left.
CARS = np.array(
    [
        [14.0, -3.9, 0.0],
        [19.5, -3.9, 0.03],
        [32.0, -4.0, -0.02],
        [22.0, 3.9, np.pi],
        [40.0, 5.6, np.pi / 2],  # perpendicular, on the sidewalk side
    ]
)


def _scene() -> StreetScene:
    cars = tuple(
        SceneBox(center=(float(x), float(y), 0.75), size=(4.5, 1.85, 1.5), yaw=float(yaw))
        for x, y, yaw in CARS
    )
    walls = (
        SceneBox(center=(30.0, -12.0, 4.0), size=(120.0, 2.0, 10.0), yaw=0.0),
        SceneBox(center=(30.0, 12.0, 4.0), size=(120.0, 2.0, 10.0), yaw=0.0),
    )
    return StreetScene(ground=Ground(road_half_width_m=5.0), cars=cars, structures=walls)


def _write_bag(path: Path) -> None:
    scene = _scene()
    lidar = LidarModel(beams=32, azimuths=900)
    t0 = 1_700_000_000_000_000_000
    odom_ns = t0 + np.arange(0, int(DURATION_S * 50)) * 20_000_000
    lidar_ns = (
        t0 + 100_000_000 + np.arange(0, int((DURATION_S - 0.5) * LIDAR_HZ)) * int(1e9 / LIDAR_HZ)
    )
    cam_ns = lidar_ns + 1_000_000
    events = [(int(s), "odom", i) for i, s in enumerate(odom_ns)]
    events += [(int(s), "lidar", i) for i, s in enumerate(lidar_ns)]
    events += [(int(s), "cam", i) for i, s in enumerate(cam_ns)]
    events.sort()
    with BagWriter(path, "mcap") as w:
        for stamp, kind, i in events:
            t = (stamp - t0) / 1e9
            if kind == "odom":
                w.write_odometry("/odom", stamp, (E0 + SPEED * t, N0))
            elif kind == "lidar":
                sensor = Pose(
                    np.array([SPEED * t + MOUNT[0], MOUNT[1], MOUNT[2]]), np.array([0, 0, 0, 1.0])
                )
                pts = scan_scene(scene, sensor, lidar=lidar, seed=i).points
                w.write_point_cloud("/lidar", stamp, pts)
            else:
                w.write_fields(
                    "/camera/image_raw",
                    "sensor_msgs/msg/Image",
                    {
                        "header": {"stamp": stamp, "frame_id": "camera"},
                        "height": 4,
                        "width": 4,
                        "encoding": "rgb8",
                        "step": 12,
                        "data": np.full(48, i % 255, dtype=np.uint8),
                    },
                    receive_ns=stamp,
                )


@pytest.fixture(scope="module")
def street_ws(tmp_path_factory: pytest.TempPathFactory) -> Workspace:
    root = tmp_path_factory.mktemp("detect")
    _write_bag(root / "street")
    cfg = Config(
        recording=RecordingConfig(bags=[str(root / "street")]),
        topics=TopicsConfig(camera="/camera/image_raw", pose="/odom", lidar="/lidar"),
        pose=PoseConfig(crs=UTM32N),
        lidar=LidarConfig(mount=MountConfig(xyz=MOUNT, rpy_deg=(0.0, 0.0, 0.0))),
        camera=CameraConfig(
            intrinsics=IntrinsicsConfig(fx=4.0, fy=4.0, cx=2.0, cy=2.0, width=4, height=4)
        ),
    )
    ws = Workspace.create(root / "ws", cfg)
    extract(ws)
    return ws


def _truth_world(ws: Workspace) -> np.ndarray:
    rec = ws.world_frame()
    assert rec is not None
    assert rec.origin_lat_deg is not None
    assert rec.origin_lon_deg is not None
    world = WorldFrame(rec.origin_lat_deg, rec.origin_lon_deg, rec.origin_alt_m)
    utm = np.column_stack([CARS[:, 0] + E0, CARS[:, 1] + N0, np.zeros(len(CARS))])
    return world.from_crs(UTM32N, utm)


def test_detect_finds_every_parked_car_in_the_world_frame(street_ws: Workspace) -> None:
    result = run_detect(street_ws, force=True)
    doc = result.vehicles
    assert doc is not None
    saved = ParkedVehicles.load(result.path)
    assert saved == doc
    assert doc.source == "lidar"
    assert doc.detector == "geometric"
    assert doc.frames_used == len(read_table(street_ws.dataset_dir / "lidar.csv")["scan"])
    truth = _truth_world(street_ws)
    pos = np.array([v.position for v in doc.vehicles])
    assert len(doc.vehicles) == len(CARS), pos
    d = np.linalg.norm(pos[:, None, :2] - truth[None, :, :2], axis=2)
    nearest = d.argmin(axis=1)
    assert sorted(nearest.tolist()) == list(range(len(CARS)))
    assert d.min(axis=1).max() < 0.5
    by_truth = {int(j): v for j, v in zip(nearest, doc.vehicles, strict=True)}
    assert [by_truth[j].side for j in range(len(CARS))] == ["right"] * 3 + ["left"] * 2
    assert by_truth[4].orientation == "perpendicular"
    assert all(by_truth[j].orientation == "parallel" for j in range(4))
    for v in doc.vehicles:
        assert 3.5 < v.size[0] < 5.5
        assert 1.5 < v.size[1] < 2.2
        assert abs(v.position[2]) < 0.3  # bottom on the road
        assert v.hits >= 3
    # Parallel cars face the direction of travel (+x east, world frame nearly aligned).
    assert all(abs(np.cos(by_truth[j].yaw)) > 0.99 for j in range(4))
    boxes = read_table(street_ws.detections_dir / "boxes_lidar.csv")
    assert boxes["frame"].shape[0] == doc.detections
    assert (street_ws.detections_dir / "parked_vehicles.png").stat().st_size > 10_000


def test_rerun_is_skipped_and_force_keeps_hand_edits_in_history(street_ws: Workspace) -> None:
    first = run_detect(street_ws, force=True)
    assert first.vehicles is not None
    # Up to date: nothing runs.
    assert run_detect(street_ws).vehicles is None
    # A hand edit, then a forced re-run: the edited version lands in history/.
    edited = first.vehicles.model_copy(
        update={"vehicles": (first.vehicles.vehicles[0].model_copy(update={"edited": True}),)}
    )
    edited.save(first.path)
    run_detect(street_ws, force=True)
    history = sorted((street_ws.detections_dir / "history").glob("parked_vehicles.*.json"))
    assert any(json.loads(h.read_text())["vehicles"][0]["edited"] for h in history)


def test_every_and_min_hits_options(street_ws: Workspace) -> None:
    from cam2sim.detect.fusion import FusionOptions

    res = run_detect(
        street_ws,
        options=DetectOptions(every=2, fusion=FusionOptions(min_hits=200)),
        force=True,
    )
    assert res.vehicles is not None
    assert res.vehicles.vehicles == ()
    assert (
        res.vehicles.frames_used
        == (len(read_table(street_ws.dataset_dir / "lidar.csv")["scan"]) + 1) // 2
    )


def test_camera_without_model_and_unknown_detector_fail_clearly(street_ws: Workspace) -> None:
    with pytest.raises(ConfigError, match="geometric detector works on LiDAR"):
        run_detect(street_ws, options=DetectOptions(source="camera", model="geometric"), force=True)
    with pytest.raises(ConfigError, match="unknown detector"):
        run_detect(street_ws, options=DetectOptions(model="yolo"), force=True)
    with pytest.raises(StageError, match="cam2sim map"):
        run_detect(street_ws, options=DetectOptions(snap=True), force=True)


def test_detect_needs_a_dataset(tmp_path: Path) -> None:
    ws = Workspace.create(
        tmp_path / "ws", Config(recording=RecordingConfig(bags=[str(tmp_path / "x")]))
    )
    with pytest.raises(StageError, match="cam2sim extract"):
        run_detect(ws)


def test_cli_detect_prints_the_vehicles(street_ws: Workspace) -> None:
    out = CliRunner().invoke(app, ["detect", str(street_ws.root), "--force"])
    assert out.exit_code == 0, out.output
    assert "parked vehicles" in out.output
    assert "pv_000" in out.output
    bad = CliRunner().invoke(app, ["detect", str(street_ws.root), "--model", "nope.onnx"])
    assert bad.exit_code == 1
    assert "does not exist" in bad.output


def _frame_aware_camera_model(path: Path) -> Path:
    """A TorchScript 'detector' that sees the car at street x = 30 m, 3.9 m to the right.

    Frame ``i`` of the bag has every pixel set to ``i``; the camera (at the ego origin, looking
    forward) is then at street x = SPEED * t_i, so the car's depth is 30 - SPEED * t_i. Frames
    where the car is behind the camera score 0 (dropped by the score threshold).
    """
    import torch

    t_first = 0.1 + 0.001  # camera stamps: lidar stamps + 1 ms, first lidar at 0.1 s
    step = 1.0 / LIDAR_HZ

    class Mono(torch.nn.Module):
        def forward(
            self, image: torch.Tensor, K: torch.Tensor
        ) -> tuple[torch.Tensor, torch.Tensor]:
            i = torch.round(image.mean() * 255.0)
            depth = 30.0 - SPEED * (t_first + step * i)
            boxes = torch.zeros(1, 7)
            boxes[0, 0] = 3.9 + 0.0 * K[0, 0, 0]
            boxes[0, 1] = 0.75
            boxes[0, 2] = depth
            boxes[0, 3] = 4.5
            boxes[0, 4] = 1.8
            boxes[0, 5] = 1.5
            boxes[0, 6] = 1.5707963  # length axis (cos, 0, -sin) = -z: along the road
            scores = (depth > 1.0).float().reshape(1) * 0.9
            return boxes, scores

    example = (torch.zeros(1, 3, 4, 4), torch.eye(3).reshape(1, 3, 3))
    torch.export.save(torch.export.export(Mono(), example), str(path))
    return path


def test_camera_detection_places_boxes_with_camera_poses(
    street_ws: Workspace, tmp_path: Path
) -> None:
    model = _frame_aware_camera_model(tmp_path / "mono.pt")
    res = run_detect(
        street_ws, options=DetectOptions(source="camera", model=str(model)), force=True
    )
    doc = res.vehicles
    assert doc is not None
    assert doc.source == "camera"
    assert len(doc.vehicles) == 1
    v = doc.vehicles[0]
    truth = WorldFrame(*_origin(street_ws)).from_crs(
        UTM32N, np.array([[E0 + 30.0, N0 - 3.9, 0.0]])
    )[0]
    assert np.hypot(v.position[0] - truth[0], v.position[1] - truth[1]) < 0.05
    assert v.side == "right"
    assert v.orientation == "parallel"  # yaw pi/2 about the camera's up axis: along the road
    # Every frame with the car ahead (depth > 1 m) and within 40 m contributed one box.
    boxes = read_table(street_ws.detections_dir / "boxes_camera.csv")
    assert v.hits == int((boxes["vehicle"] == 0).sum()) >= 20
    # Monocular sigma grows with depth.
    order = np.argsort(boxes["range_m"])
    assert np.all(np.diff(boxes["sigma_m"][order]) >= -1e-9)


def _origin(ws: Workspace) -> tuple[float, float, float]:
    rec = ws.world_frame()
    assert rec is not None
    assert rec.origin_lat_deg is not None
    assert rec.origin_lon_deg is not None
    return rec.origin_lat_deg, rec.origin_lon_deg, rec.origin_alt_m


def test_cli_refine_without_dataset_says_what_to_run(tmp_path: Path) -> None:
    Workspace.create(tmp_path / "ws", Config(recording=RecordingConfig(bags=[str(tmp_path)])))
    out = CliRunner().invoke(app, ["refine", str(tmp_path / "ws"), "--no-open"])
    assert out.exit_code == 1
    assert "cam2sim extract" in out.output
