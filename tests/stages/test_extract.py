"""Stage extract on bags written by the tests, carrying the real reference drive's poses."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from cam2sim.core import frames
from cam2sim.core.config import (
    CameraConfig,
    Config,
    IntrinsicsConfig,
    LidarConfig,
    MountConfig,
    PoseConfig,
    RecordingConfig,
    SignalConfig,
    TopicsConfig,
    save_config,
)
from cam2sim.core.dataset import Calibration, DatasetInfo
from cam2sim.core.errors import ConfigError, RecordingError
from cam2sim.core.table import read_table
from cam2sim.core.workspace import DatasetPaths, Workspace
from cam2sim.recording.bagwriter import BagWriter
from cam2sim.stages import extract as extract_module
from cam2sim.stages.extract import extract
from conftest import ReferenceDrive, temporary_leftovers, write_drive_bag

UTM32N = "EPSG:32632"


def _config(bags: list[Path], **overrides: object) -> Config:
    topics = TopicsConfig(
        camera="/camera/image_raw",
        pose="/odom",
        lidar=overrides.pop("lidar", None),  # type: ignore[arg-type]
        signals={"steering": SignalConfig(topic="/vehicle/steering_pct")},
    )
    base = Config(
        recording=RecordingConfig(bags=[str(b) for b in bags]),
        topics=topics,
        pose=PoseConfig(crs=UTM32N, axis_convention="x_left"),
    )
    return base.model_copy(update=overrides)


def _expected(drive: ReferenceDrive, stamps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Reference UTM positions and ENU headings at ``stamps`` (linear / unwrapped interp)."""
    rel = (drive.stamp_ns - drive.stamp_ns[0]).astype(float)
    q = (stamps - drive.stamp_ns[0]).astype(float)
    xy = np.stack([np.interp(q, rel, drive.easting), np.interp(q, rel, drive.northing)], -1)
    heading = np.interp(q, rel, np.unwrap(drive.yaw_odom)) - math.pi / 2
    return xy, heading


@pytest.mark.parametrize(("fmt", "seconds"), [("mcap", None), ("ros1", 15.0), ("sqlite3", 15.0)])
def test_extract_reproduces_reference_trajectory_at_camera_times(
    tmp_path: Path, reference_drive: ReferenceDrive, fmt: str, seconds: float | None
) -> None:
    name = "drive.bag" if fmt == "ros1" else f"drive-{fmt}"
    bag = write_drive_bag(
        tmp_path / name,
        fmt,
        reference_drive,
        seconds=seconds,
        camera_hz=15.0,  # type: ignore[arg-type]
    )
    ws = Workspace.create(tmp_path / "ws", _config([bag.path]))
    with pytest.warns(UserWarning, match="no camera intrinsics"):
        result = extract(ws)
    poses = read_table(DatasetPaths(ws.dataset_dir).poses_csv)
    stamps = poses["stamp_ns"]
    assert len(stamps) == result.info.counts.frames > 0
    world = result.info.world
    wf = frames.WorldFrame(world.origin_lat_deg, world.origin_lon_deg, world.origin_alt_m)  # type: ignore[arg-type]
    xyz = np.stack([poses["x"], poses["y"], poses["z"]], -1)
    utm = wf.to_crs(UTM32N, xyz)
    heading_utm = wf.heading_to_crs(UTM32N, xyz[:, :2], poses["heading"])
    exp_xy, exp_heading = _expected(reference_drive, stamps)
    assert np.abs(utm[:, :2] - exp_xy).max() < 1e-3
    diff = np.degrees(np.abs(frames.angle_difference(heading_utm, exp_heading)))
    assert diff.max() < 0.1
    # Frames before and after pose coverage are dropped, and counted.
    assert result.info.dropped["camera"]["outside_pose_coverage"] > 0
    kept_or_dropped = len(stamps) + sum(result.info.dropped["camera"].values())
    assert kept_or_dropped == len(bag.camera_ns)


def test_extract_drops_frames_inside_long_pose_gaps(
    tmp_path: Path, reference_drive: ReferenceDrive
) -> None:
    bag = write_drive_bag(tmp_path / "drive", "mcap", reference_drive, camera_hz=10.0)
    gaps = np.diff(reference_drive.stamp_ns)
    long_gaps = gaps > 0.5e9
    assert long_gaps.any(), "the reference drive has 0.6-0.8 s gaps"
    ws = Workspace.create(tmp_path / "ws", _config([bag.path]))
    with pytest.warns(UserWarning, match="intrinsics"):
        info = extract(ws).info
    starts = reference_drive.stamp_ns[:-1][long_gaps]
    ends = reference_drive.stamp_ns[1:][long_gaps]
    inside = ((bag.camera_ns[:, None] > starts) & (bag.camera_ns[:, None] < ends)).any(axis=1)
    assert info.dropped["camera"]["pose_gap"] == int(inside.sum())
    kept = read_table(DatasetPaths(ws.dataset_dir).poses_csv)["stamp_ns"]
    assert not np.isin(kept, bag.camera_ns[inside]).any()


def test_extract_writes_frames_lidar_signals_and_calibration(
    tmp_path: Path, reference_drive: ReferenceDrive
) -> None:
    bag = write_drive_bag(tmp_path / "drive", "mcap", reference_drive, seconds=5, lidar_hz=10)
    mount = MountConfig(xyz=(0.62, 0.0, 1.43), rpy_deg=(0.0, 0.0, 0.0))
    intrinsics = IntrinsicsConfig(
        fx=20.0,
        fy=20.0,
        cx=8.0,
        cy=6.0,
        width=16,
        height=12,
        distortion=[-0.27, 0.03, 0.002, -0.001, 0.0],
    )
    cfg = _config([bag.path], lidar="/velodyne_points")
    cfg = cfg.model_copy(
        update={"lidar": LidarConfig(mount=mount), "camera": CameraConfig(intrinsics=intrinsics)}
    )
    ws = Workspace.create(tmp_path / "ws", cfg)
    info = extract(ws).info
    paths = DatasetPaths(ws.dataset_dir)
    poses = read_table(paths.poses_csv)
    # PNG frames are the exact images that were recorded at those stamps.
    by_stamp = {int(s): img for s, img in zip(bag.camera_ns, bag.images, strict=True)}
    for frame, stamp in zip(poses["frame"][:20], poses["stamp_ns"][:20], strict=True):
        on_disk = cv2.cvtColor(
            cv2.imread(str(paths.frame_file(int(frame), "png"))), cv2.COLOR_BGR2RGB
        )
        np.testing.assert_array_equal(on_disk, by_stamp[int(stamp)])
    # LiDAR scans: exact points, sensor pose = body pose composed with the mount.
    scans = read_table(paths.lidar_csv)
    assert info.counts.lidar_scans == len(scans["scan"]) == len(bag.lidar_ns)
    points = np.load(paths.lidar_file(0))
    assert set(points.dtype.names or ()) == {"x", "y", "z", "intensity"}
    assert scans["points"][0] == points.shape[0]
    traj = read_table(paths.trajectory_csv)
    heading = np.interp(scans["t"], traj["t"], np.unwrap(traj["heading"]))
    xs = np.interp(scans["t"], traj["t"], traj["x"]) + 0.62 * np.cos(heading)
    ys = np.interp(scans["t"], traj["t"], traj["y"]) + 0.62 * np.sin(heading)
    assert np.abs(scans["x"] - xs).max() < 2e-3
    assert np.abs(scans["y"] - ys).max() < 2e-3
    assert np.abs(scans["z"] - 1.43).max() < 1e-6
    # Signals keep every sample.
    steering = read_table(paths.signal_file("steering"))
    np.testing.assert_allclose(steering["value"], bag.steering, atol=1e-9)
    # Calibration: K from config; the camera mount is an optical frame looking forward.
    calib = Calibration.load(paths.calibration_json)
    assert calib.camera is not None
    assert calib.camera.K[0][0] == 20.0
    assert calib.camera.distortion[0] == -0.27
    forward = frames.quat_rotate(np.array(calib.camera_mount.quat_xyzw), np.array([0.0, 0.0, 1.0]))
    np.testing.assert_allclose(forward, [1.0, 0.0, 0.0], atol=1e-12)
    assert info.counts.signals == {"steering": len(bag.steering)}
    manifest = ws.read_manifest()
    assert manifest.stages["extract"].state == "done"
    assert manifest.world == info.world


def test_extract_skips_when_inputs_unchanged_and_force_reruns(
    tmp_path: Path, reference_drive: ReferenceDrive
) -> None:
    bag = write_drive_bag(tmp_path / "drive", "mcap", reference_drive, seconds=2)
    ws = Workspace.create(tmp_path / "ws", _config([bag.path]))
    with pytest.warns(UserWarning):
        assert not extract(ws).skipped
    assert extract(ws).skipped
    with pytest.warns(UserWarning):
        assert not extract(ws, force=True).skipped


def test_extract_reads_a_recording_split_over_several_bags(
    tmp_path: Path, reference_drive: ReferenceDrive
) -> None:
    whole = write_drive_bag(tmp_path / "whole.bag", "ros1", reference_drive, seconds=4)
    # Split the same messages over two ROS1 bags at the middle of the drive.
    from cam2sim.recording.bag import Recording

    parts = [tmp_path / "part1.bag", tmp_path / "part2.bag"]
    with Recording([whole.path]) as rec:
        raws = list(rec.raw_messages())
    middle = raws[len(raws) // 2].receive_ns
    for part, keep in zip(parts, (lambda r: r < middle, lambda r: r >= middle), strict=True):
        with BagWriter(part, "ros1") as w:
            for raw in raws:
                if keep(raw.receive_ns):
                    msg = w.typestore.deserialize_ros1(raw.rawdata, raw.msgtype)
                    w.write(raw.topic, msg, receive_ns=raw.receive_ns)
    ws1 = Workspace.create(tmp_path / "ws1", _config([whole.path]))
    ws2 = Workspace.create(tmp_path / "ws2", _config(parts))
    with pytest.warns(UserWarning):
        a = extract(ws1).info
    with pytest.warns(UserWarning):
        b = extract(ws2).info
    assert a.counts == b.counts
    ta = read_table(DatasetPaths(ws1.dataset_dir).poses_csv)
    tb = read_table(DatasetPaths(ws2.dataset_dir).poses_csv)
    np.testing.assert_array_equal(ta["x"], tb["x"])


# -- bad input -----------------------------------------------------------------------------------
def test_extract_missing_topic_lists_topics_and_closest_match(
    tmp_path: Path, reference_drive: ReferenceDrive
) -> None:
    bag = write_drive_bag(tmp_path / "drive", "mcap", reference_drive, seconds=1)
    cfg = _config([bag.path])
    cfg = cfg.model_copy(
        update={"topics": cfg.topics.model_copy(update={"camera": "/camera/imag_raw"})}
    )
    ws = Workspace.create(tmp_path / "ws", cfg)
    with pytest.raises(
        RecordingError,
        match=r"'/camera/imag_raw'.*Closest: /camera/image_raw.*Topics present: .*/odom",
    ):
        extract(ws)
    record = ws.stage_record("extract")
    assert record is not None
    assert record.state == "failed"
    assert not ws.dataset_dir.exists()


def _write_odom_bag(path: Path, stamps: list[int], xs: list[float], *, camera: list[int]) -> None:
    with BagWriter(path, "mcap") as w:
        events = [(s, "odom", i) for i, s in enumerate(stamps)] + [
            (s, "cam", i) for i, s in enumerate(camera)
        ]
        for stamp, kind, i in sorted(events, key=lambda e: (e[0], e[1])):
            if kind == "odom":
                w.write_fields(
                    "/odom",
                    "nav_msgs/msg/Odometry",
                    {
                        "header": {"stamp": stamp},
                        "pose": {"pose": {"position": {"x": xs[i]}, "orientation": {"w": 1.0}}},
                    },
                    receive_ns=stamp + 1,
                )
            else:
                w.write_fields(
                    "/camera/image_raw",
                    "sensor_msgs/msg/Image",
                    {
                        "header": {"stamp": stamp},
                        "height": 2,
                        "width": 2,
                        "encoding": "rgb8",
                        "step": 6,
                        "data": np.zeros(12, np.uint8),
                    },
                    receive_ns=stamp + 1,
                )


def _local_config(bag: Path) -> Config:
    return Config(
        recording=RecordingConfig(bags=[str(bag)]),
        topics=TopicsConfig(camera="/camera/image_raw", pose="/odom"),
    )


def test_extract_rejects_nan_poses_with_the_fix(tmp_path: Path) -> None:
    stamps = [10**9 + i * 10**7 for i in range(20)]
    xs = [float(i) for i in range(20)]
    xs[5] = float("nan")
    _write_odom_bag(tmp_path / "bag", stamps, xs, camera=stamps[2:10])
    ws = Workspace.create(tmp_path / "ws", _local_config(tmp_path / "bag"))
    with pytest.raises(RecordingError, match="NaN.*pose.on_invalid: drop"):
        extract(ws)
    cfg = _local_config(tmp_path / "bag")
    ws2 = Workspace.create(
        tmp_path / "ws2", cfg.model_copy(update={"pose": PoseConfig(on_invalid="drop")})
    )
    with pytest.warns(UserWarning):
        info = extract(ws2).info
    assert info.dropped["pose"] == {"invalid": 1}


def test_extract_rejects_timestamps_going_backwards(tmp_path: Path) -> None:
    stamps = [10**9 + i * 10**7 for i in range(20)]
    stamps[7], stamps[8] = stamps[8], stamps[7]
    with BagWriter(tmp_path / "bag", "mcap") as w:
        for i, s in enumerate(stamps):
            w.write_fields(
                "/odom",
                "nav_msgs/msg/Odometry",
                {"header": {"stamp": s}, "pose": {"pose": {"orientation": {"w": 1.0}}}},
                receive_ns=10**9 + i * 10**7 + 5,
            )
            w.write_fields(
                "/camera/image_raw",
                "sensor_msgs/msg/Image",
                {
                    "header": {"stamp": s},
                    "height": 1,
                    "width": 1,
                    "encoding": "mono8",
                    "step": 1,
                    "data": np.zeros(1, np.uint8),
                },
                receive_ns=10**9 + i * 10**7 + 6,
            )
    ws = Workspace.create(tmp_path / "ws", _local_config(tmp_path / "bag"))
    with pytest.raises(RecordingError, match="go backwards at message 8.*time_base: receive"):
        extract(ws)


def test_extract_reports_no_overlap_between_camera_and_poses(tmp_path: Path) -> None:
    stamps = [10**9 + i * 10**7 for i in range(20)]
    _write_odom_bag(tmp_path / "bag", stamps, [0.0] * 20, camera=[5 * 10**9 + i for i in range(5)])
    ws = Workspace.create(tmp_path / "ws", _local_config(tmp_path / "bag"))
    with pytest.raises(RecordingError, match="do not overlap in time"):
        extract(ws)
    assert ws.stage_record("extract").state == "failed"  # type: ignore[union-attr]


def test_extract_reports_a_truncated_bag(tmp_path: Path, reference_drive: ReferenceDrive) -> None:
    bag = write_drive_bag(tmp_path / "drive.bag", "ros1", reference_drive, seconds=2)
    data = bag.path.read_bytes()
    bag.path.write_bytes(data[: len(data) // 2])
    ws = Workspace.create(tmp_path / "ws", _config([bag.path]))
    with pytest.raises(RecordingError, match="truncated"):
        extract(ws)


def test_extract_unknown_encoding_fails_and_keeps_the_previous_dataset(
    tmp_path: Path, reference_drive: ReferenceDrive
) -> None:
    good = write_drive_bag(tmp_path / "good", "mcap", reference_drive, seconds=1)
    ws = Workspace.create(tmp_path / "ws", _config([good.path]))
    with pytest.warns(UserWarning):
        extract(ws)
    before = sorted(p.relative_to(ws.root) for p in ws.dataset_dir.rglob("*"))
    with BagWriter(tmp_path / "bad", "mcap") as w:
        for i in range(5):
            s = int(reference_drive.stamp_ns[0]) + i * 10**7
            w.write_fields(
                "/odom",
                "nav_msgs/msg/Odometry",
                {
                    "header": {"stamp": s},
                    "pose": {
                        "pose": {
                            "position": {"x": 692932.0, "y": 5339068.0},
                            "orientation": {"w": 1.0},
                        }
                    },
                },
                receive_ns=s,
            )
            w.write_fields(
                "/camera/image_raw",
                "sensor_msgs/msg/Image",
                {
                    "header": {"stamp": s},
                    "height": 1,
                    "width": 1,
                    "encoding": "32FC7",
                    "step": 28,
                    "data": np.zeros(28, np.uint8),
                },
                receive_ns=s + 1,
            )
    cfg = _config([tmp_path / "bad"])
    cfg = cfg.model_copy(update={"topics": cfg.topics.model_copy(update={"signals": {}})})
    save_config(cfg, ws.config_path)
    with pytest.raises(RecordingError, match="32FC7"):
        extract(ws)
    after = sorted(p.relative_to(ws.root) for p in ws.dataset_dir.rglob("*"))
    assert before == after
    assert ws.stage_record("extract").state == "failed"  # type: ignore[union-attr]
    assert temporary_leftovers(ws.root) == []


def test_interrupted_extract_leaves_the_workspace_as_it_was(
    tmp_path: Path, reference_drive: ReferenceDrive, monkeypatch: pytest.MonkeyPatch
) -> None:
    bag = write_drive_bag(tmp_path / "drive", "mcap", reference_drive, seconds=2)
    ws = Workspace.create(tmp_path / "ws", _config([bag.path]))
    with pytest.warns(UserWarning):
        extract(ws)
    manifest_before = ws.manifest_path.read_text()
    info_before = DatasetInfo.load(DatasetPaths(ws.dataset_dir).dataset_json)

    calls = {"n": 0}
    original = extract_module._FrameWriter.submit

    def interrupt(self, index, msgtype, msg):  # type: ignore[no-untyped-def]
        calls["n"] += 1
        if calls["n"] == 10:
            raise KeyboardInterrupt
        return original(self, index, msgtype, msg)

    monkeypatch.setattr(extract_module._FrameWriter, "submit", interrupt)
    with pytest.raises(KeyboardInterrupt):
        extract(ws, force=True)
    assert ws.manifest_path.read_text() == manifest_before
    assert DatasetInfo.load(DatasetPaths(ws.dataset_dir).dataset_json) == info_before
    assert temporary_leftovers(ws.root) == []


def test_extract_requires_a_camera_topic(tmp_path: Path) -> None:
    ws = Workspace.create(tmp_path / "ws", Config(recording=RecordingConfig(bags=["x.bag"])))
    with pytest.raises(ConfigError, match="topics.camera"):
        extract(ws)


def test_dataset_json_is_schema_versioned(tmp_path: Path, reference_drive: ReferenceDrive) -> None:
    bag = write_drive_bag(tmp_path / "drive", "mcap", reference_drive, seconds=1)
    ws = Workspace.create(tmp_path / "ws", _config([bag.path]))
    with pytest.warns(UserWarning):
        extract(ws)
    raw = json.loads(DatasetPaths(ws.dataset_dir).dataset_json.read_text())
    assert raw["schema_version"] == 1


def test_extract_takes_a_tools_calibration_file_for_a_bag_without_camera_info(
    tmp_path: Path, reference_drive: ReferenceDrive
) -> None:
    """`cam2sim run --calibration ost.yaml` keeps it as camera.calibration: a ROS camera_info
    YAML for 64x48 frames, the bag's 16x12 frames (the same shape) get it scaled by a quarter."""
    bag = write_drive_bag(tmp_path / "drive", "mcap", reference_drive, seconds=2)
    calib = tmp_path / "ost.yaml"
    calib.write_text(
        "image_width: 64\nimage_height: 48\ncamera_matrix:\n  rows: 3\n  cols: 3\n"
        "  data: [80.0, 0, 31.5, 0, 80.0, 23.5, 0, 0, 1]\ndistortion_model: plumb_bob\n"
        "distortion_coefficients:\n  rows: 1\n  cols: 5\n  data: [-0.2, 0.05, 0, 0, 0]\n"
    )
    cfg = _config([bag.path]).model_copy(update={"camera": CameraConfig(calibration=str(calib))})
    ws = Workspace.create(tmp_path / "ws", cfg)
    extract(ws)
    camera = Calibration.load(DatasetPaths(ws.dataset_dir).calibration_json).camera
    assert camera is not None
    assert (camera.width, camera.height) == (16, 12)
    assert camera.K[0][0] == pytest.approx(20.0)
    assert camera.K[0][2] == pytest.approx(7.5)  # (31.5 + 0.5) / 4 - 0.5
    assert camera.distortion == (-0.2, 0.05, 0.0, 0.0, 0.0)
    assert "ROS camera_info YAML" in camera.source
