"""A recording where the car stands still: a real LiDAR sweep around a parked ego, 2 s.

Every stage that makes sense for it works (detect reports the parked cars, map, scenario,
replay, the pipeline's report); those that need a moving car (splat, DAVE-2, closed-loop drive,
behaviour metrics) say so in one line, never with a traceback.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pytest
from pyproj import Transformer
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
from cam2sim.core.workspace import Workspace
from cam2sim.detect.route import Route
from cam2sim.recording.bagwriter import BagWriter
from cam2sim.recording.image import compressed_image_fields

if TYPE_CHECKING:
    from pathlib import Path

T0 = 1_700_000_000_000_000_000
LON, LAT = 11.5516, 48.1860  # inside munich.osm
YAW = np.pi / 4


def _stationary_bag(path: Path, sweep: np.ndarray, image: np.ndarray) -> None:
    """2 s parked: odometry at 50 Hz, the same real sweep at 10 Hz, the camera at 20 Hz."""
    cloud = np.zeros(len(sweep), dtype=[(n, "<f4") for n in ("x", "y", "z", "intensity")])
    for i, name in enumerate(("x", "y", "z", "intensity")):
        cloud[name] = sweep[:, i]
    e, n = Transformer.from_crs("EPSG:4326", "EPSG:32632", always_xy=True).transform(LON, LAT)
    quat = (0.0, 0.0, np.sin(YAW / 2), np.cos(YAW / 2))
    events = [(T0 + i * 20_000_000, "odom") for i in range(100)]
    events += [(T0 + 5_000_000 + i * 100_000_000, "lidar") for i in range(20)]
    events += [(T0 + 7_000_000 + i * 50_000_000, "camera") for i in range(40)]
    jpeg = compressed_image_fields(image, "jpeg", quality=90)
    with BagWriter(path, "mcap") as w:
        for stamp, kind in sorted(events):
            if kind == "odom":
                w.write_odometry("/odom", stamp, (e, n), quat, receive_ns=stamp)
            elif kind == "lidar":
                w.write_point_cloud("/lidar", stamp, cloud, receive_ns=stamp)
            else:
                header = {"header": {"stamp": stamp, "frame_id": "camera"}}
                w.write_fields(
                    "/camera",
                    "sensor_msgs/msg/CompressedImage",
                    {**header, **jpeg},
                    receive_ns=stamp,
                )


@pytest.fixture(scope="module")
def parked_ws(tmp_path_factory: pytest.TempPathFactory) -> Workspace:
    from conftest import SHARED_DATA

    folder = SHARED_DATA / "lidar" / "nuscenes-sample"
    sweeps = sorted(folder.glob("*LIDAR_TOP*.pcd.bin"))
    images = sorted(folder.glob("*CAM_FRONT*.jpg"))
    if not sweeps or not images:
        pytest.skip(f"no nuScenes sample in {folder}")
    import cv2

    sweep = np.fromfile(sweeps[0], dtype=np.float32).reshape(-1, 5)[:, :4]
    image = cv2.resize(cv2.imread(str(images[0]))[..., ::-1], (320, 180))
    root = tmp_path_factory.mktemp("parked")
    _stationary_bag(root / "parked.mcap", sweep, image)
    config = Config(
        recording=RecordingConfig(bags=[str(root / "parked.mcap")]),
        topics=TopicsConfig(camera="/camera", pose="/odom", lidar="/lidar"),
        pose=PoseConfig(crs="EPSG:32632"),
        # nuScenes LIDAR_TOP: x right, y forward -> 90 degrees of yaw to the body frame.
        lidar=LidarConfig(mount=MountConfig(xyz=(0.94, 0.0, 1.84), rpy_deg=(0.0, 0.0, 90.0))),
        camera=CameraConfig(
            intrinsics=IntrinsicsConfig(
                fx=252.0, fy=252.0, cx=160.0, cy=90.0, width=320, height=180
            )
        ),
    )
    return Workspace.create(root / "ws", config)


def _cli(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(app, list(args))
    return result.exit_code, result.output


def test_a_parked_car_s_route_is_its_heading_line() -> None:
    xy = np.zeros((30, 2))
    route = Route.from_xy(xy, heading=np.full(30, 0.5))
    assert route.path.length_m == pytest.approx(10.0)
    assert route.side([[-np.sin(0.5), np.cos(0.5)]]) == ["left"]  # 1 m to the car's left
    assert route.orientation([[5.0, 5.0]], [0.5 + np.pi]) == ["parallel"]
    with pytest.raises(ValueError, match="two distinct positions"):
        Route.from_xy(xy)  # no heading: nothing to go on


def test_every_stage_that_makes_sense_runs_on_a_parked_recording(
    parked_ws: Workspace, shared_data: Path
) -> None:
    ws = str(parked_ws.root)
    code, out = _cli("extract", ws)
    assert code == 0, out
    code, out = _cli("detect", ws, "--source", "lidar")
    assert code == 0, out
    assert "Traceback" not in out
    from cam2sim.detect.vehicles import ParkedVehicles

    doc = ParkedVehicles.load(parked_ws.detections_dir / "parked_vehicles.json")
    # The two annotated cars within 40 m with >= 10 points (tests/detect/test_lidar.py), both
    # kerb-parked along the ego's heading.
    assert len(doc.vehicles) >= 2
    assert all(v.orientation == "parallel" for v in doc.vehicles)
    code, out = _cli("map", ws, "--osm", str(shared_data / "osm" / "munich.osm"))
    assert code == 0, out
    code, out = _cli("scenario", ws)
    assert code == 0, out
    code, out = _cli("replay", ws)
    assert code == 0, out
    code, out = _cli("drive", ws, "--policy", "constant:0")
    assert code == 1
    assert "Traceback" not in out
    assert "stood still" in out


def test_the_pipeline_says_which_steps_need_a_moving_car(
    parked_ws: Workspace, shared_data: Path
) -> None:
    from cam2sim.stages.pipeline import PipelineOptions, run_pipeline

    osm = shared_data / "osm" / "munich.osm"
    result = run_pipeline(parked_ws, options=PipelineOptions(osm=osm, splat_on_cpu=True))
    states = {o.name: (o.state, o.message) for o in result.outcomes}
    assert not result.failed, states
    for step in ("splat", "ads", "drive", "evaluate"):
        assert states[step][0] == "not_applicable"
        assert "stood still" in states[step][1]
    assert states["detect"][0] in ("done", "up_to_date")
    assert states["replay"][0] == "done"
    assert (parked_ws.root / "report" / "report.html").is_file()
