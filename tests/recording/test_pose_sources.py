"""Pose sources and camera options, end to end through stage extract.

Poses from a /tf chain, sensor mounts from /tf_static, NavSatFix with heading from motion, the
receive time base, CompressedImage cameras, JPEG frames and frame decimation.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np
import pyproj
import pytest

from cam2sim.core import frames
from cam2sim.core.config import (
    CameraConfig,
    Config,
    FramesConfig,
    IntrinsicsConfig,
    LidarConfig,
    MountConfig,
    PoseConfig,
    RecordingConfig,
    TfLink,
    TopicsConfig,
)
from cam2sim.core.dataset import Calibration, DatasetInfo
from cam2sim.core.errors import RecordingError
from cam2sim.core.table import read_table
from cam2sim.core.workspace import DatasetPaths, Workspace
from cam2sim.recording.bagwriter import BagWriter
from cam2sim.recording.image import compressed_image_fields, image_message_fields
from cam2sim.recording.pointcloud import pointcloud_message_fields
from cam2sim.stages.extract import extract

T0 = 1_700_000_000_000_000_000
MS = 1_000_000
CAMERA = "/camera/image_raw"
INTRINSICS = IntrinsicsConfig(fx=20.0, fy=20.0, cx=8.0, cy=6.0, width=16, height=12)
# Camera frames at 10 Hz, 50 ms after each pose sample, all inside a 2 s pose span.
CAMERA_NS = T0 + 50 * MS + 100 * MS * np.arange(19, dtype=np.int64)
R_LINK_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def _image(i: int) -> np.ndarray:
    """A smooth 16x12 RGB image (JPEG keeps it close), different for every frame."""
    y, x = np.mgrid[0:12, 0:16]
    return np.stack([x * 12 + 3 * i, y * 16 + 2 * i, (x + y) * 6 + i], -1).astype(np.uint8)


CameraKind = Literal["image", "jpeg", "png"]


def _write_camera(w: BagWriter, i: int, header_ns: int, receive_ns: int, kind: CameraKind) -> None:
    if kind == "image":
        fields: dict[str, Any] = dict(image_message_fields(_image(i), "rgb8"))
        msgtype = "sensor_msgs/msg/Image"
    else:
        fields = dict(compressed_image_fields(_image(i), kind))
        msgtype = "sensor_msgs/msg/CompressedImage"
    fields["header"] = {"stamp": header_ns, "frame_id": "camera"}
    w.write_fields(CAMERA, msgtype, fields, receive_ns=receive_ns)


def _read_frame(path: Path) -> np.ndarray:
    return cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)


def _config(bag: Path, **updates: Any) -> Config:
    base = Config(
        recording=RecordingConfig(bags=[str(bag)]),
        topics=TopicsConfig(camera=CAMERA, pose="/odom"),
        camera=CameraConfig(intrinsics=INTRINSICS),
    )
    return base.model_copy(update=updates)


# -- (a, b) poses from a /tf chain, mounts from /tf_static -------------------------------------
TF_NS = T0 + 50 * MS * np.arange(41, dtype=np.int64)  # odom -> base_link at 20 Hz for 2 s
P_MAP_ODOM = np.array([10.0, 20.0, 0.5])
YAW_MAP_ODOM = math.radians(30.0)
T_BASE_CAMLINK = frames.Pose.from_xyz_rpy([1.6, -0.1, 1.3], [0.0, math.radians(4.0), 0.0])
T_CAMLINK_OPTICAL = frames.Pose(np.zeros(3), frames.quat_from_matrix(R_LINK_OPTICAL))
T_BASE_VELODYNE = frames.Pose.from_xyz_rpy([0.5, 0.0, 1.9], [0.0, 0.0, math.radians(3.0)])


def _odom_base(stamp_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """odom -> base_link: 5 m/s along odom x while yawing at 0.1 rad/s (exactly linear)."""
    t = (stamp_ns - T0) / 1e9
    pos = np.stack([5.0 * t, np.zeros_like(t), np.zeros_like(t)], -1)
    return pos, frames.quat_from_yaw(0.1 * t)


def _map_base(stamp_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The ground truth map -> base_link at any time."""
    pos, quat = _odom_base(stamp_ns)
    q_mo = frames.quat_from_yaw(YAW_MAP_ODOM)
    return P_MAP_ODOM + frames.quat_rotate(q_mo, pos), frames.quat_multiply(q_mo, quat)


def _transform(parent: str, child: str, stamp: int, pos: Any, quat: Any) -> dict[str, Any]:
    return {
        "header": {"stamp": int(stamp), "frame_id": parent},
        "child_frame_id": child,
        "transform": {
            "translation": dict(zip("xyz", np.asarray(pos).tolist(), strict=True)),
            "rotation": dict(zip("xyzw", np.asarray(quat).tolist(), strict=True)),
        },
    }


def _cloud(i: int) -> dict[str, Any]:
    rng = np.random.default_rng(i)
    pts = np.zeros(32, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    for name in ("x", "y", "z"):
        pts[name] = rng.normal(size=32).astype(np.float32)
    return dict(pointcloud_message_fields(pts))


def write_tf_bag(path: Path) -> Path:
    """/tf (map -> odom held constant, odom -> base_link moving), /tf_static mounts, sensors."""
    tf_msg = "tf2_msgs/msg/TFMessage"
    ob_pos, ob_q = _odom_base(TF_NS)
    q_mo = frames.quat_from_yaw(YAW_MAP_ODOM)
    events: list[tuple[int, str, int]] = [(int(s), "tf", i) for i, s in enumerate(TF_NS)]
    events += [(int(s), "cam", i) for i, s in enumerate(CAMERA_NS)]
    events += [(int(s), "lidar", i) for i, s in enumerate(CAMERA_NS[::4])]
    with BagWriter(path, "mcap") as w:
        statics = [
            _transform(
                "base_link", "camera_link", T0, T_BASE_CAMLINK.position, T_BASE_CAMLINK.quat
            ),
            _transform("camera_link", "camera_optical", T0, np.zeros(3), T_CAMLINK_OPTICAL.quat),
            _transform("base_link", "velodyne", T0, T_BASE_VELODYNE.position, T_BASE_VELODYNE.quat),
        ]
        w.write_fields("/tf_static", tf_msg, {"transforms": statics}, receive_ns=T0 - 1)
        for stamp, kind, i in sorted(events):
            if kind == "tf":
                transforms = [_transform("odom", "base_link", stamp, ob_pos[i], ob_q[i])]
                if i % 10 == 0:
                    transforms.append(_transform("map", "odom", stamp, P_MAP_ODOM, q_mo))
                w.write_fields("/tf", tf_msg, {"transforms": transforms}, receive_ns=stamp)
            elif kind == "cam":
                _write_camera(w, i, stamp, stamp + 1, "image")
            else:
                fields = _cloud(i)
                fields["fields"] = [
                    w.message("sensor_msgs/msg/PointField", f) for f in fields["fields"]
                ]
                fields["header"] = {"stamp": stamp, "frame_id": "velodyne"}
                w.write_fields(
                    "/velodyne_points", "sensor_msgs/msg/PointCloud2", fields, receive_ns=stamp + 2
                )
    return path


def _tf_config(bag: Path, **updates: Any) -> Config:
    cfg = _config(
        bag,
        topics=TopicsConfig(camera=CAMERA),
        pose=PoseConfig(source="tf", tf=TfLink(parent="map", child="base_link")),
    )
    return cfg.model_copy(update=updates)


def test_extract_pose_from_tf_chain_reproduces_tf_poses_at_camera_times(tmp_path: Path) -> None:
    ws = Workspace.create(tmp_path / "ws", _tf_config(write_tf_bag(tmp_path / "bag")))
    info = extract(ws).info
    assert not info.heading_from_motion  # the tf chain gives the orientation
    poses = read_table(DatasetPaths(ws.dataset_dir).poses_csv)
    np.testing.assert_array_equal(poses["stamp_ns"], CAMERA_NS)
    assert info.counts.frames == len(CAMERA_NS)
    assert info.counts.pose_samples == len(TF_NS)
    want_pos, want_q = _map_base(CAMERA_NS)
    xyz = np.stack([poses["x"], poses["y"], poses["z"]], -1)
    assert np.abs(xyz - want_pos).max() < 2e-6  # poses.csv keeps 6 decimals
    quat = np.stack([poses["qx"], poses["qy"], poses["qz"], poses["qw"]], -1)
    assert frames.quat_angle_between(quat, want_q).max() < 1e-8
    want_heading = frames.yaw_from_quat(want_q)
    assert np.abs(frames.angle_difference(poses["heading"], want_heading)).max() < 1e-8


@pytest.mark.parametrize(
    ("tf_frame", "axes"), [("camera_optical", "optical"), ("camera_link", "link")]
)
def test_extract_reads_camera_and_lidar_mounts_from_tf_static(
    tmp_path: Path, tf_frame: str, axes: Literal["link", "optical"]
) -> None:
    cfg = _tf_config(
        write_tf_bag(tmp_path / "bag"),
        topics=TopicsConfig(camera=CAMERA, lidar="/velodyne_points"),
        camera=CameraConfig(intrinsics=INTRINSICS, mount=MountConfig(tf_frame=tf_frame, axes=axes)),
        lidar=LidarConfig(mount=MountConfig(tf_frame="velodyne")),
    )
    ws = Workspace.create(tmp_path / "ws", cfg)
    info = extract(ws).info
    assert info.counts.lidar_scans == len(CAMERA_NS[::4])
    calib = Calibration.load(DatasetPaths(ws.dataset_dir).calibration_json)
    want_cam = T_BASE_CAMLINK @ T_CAMLINK_OPTICAL
    cam = calib.camera_mount
    assert cam.axes == "optical"
    assert cam.source == f"tf_static base_link -> {tf_frame}"
    assert np.abs(np.array(cam.translation_m) - want_cam.position).max() < 1e-12
    assert frames.quat_angle_between(cam.quat_xyzw, want_cam.quat) < 1e-9
    lidar = calib.lidar_mount
    assert lidar is not None
    assert lidar.axes == "link"
    assert np.abs(np.array(lidar.translation_m) - T_BASE_VELODYNE.position).max() < 1e-12
    assert frames.quat_angle_between(lidar.quat_xyzw, T_BASE_VELODYNE.quat) < 1e-9


# -- (c) NavSatFix with heading from motion ----------------------------------------------------
LAT0, LON0 = 48.17, 11.59
FIX_NS = T0 + 100 * MS * np.arange(21, dtype=np.int64)  # 10 Hz for 2 s
_LOCAL = f"+proj=tmerc +lat_0={LAT0} +lon_0={LON0} +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m"


def _fixes_north_east(jitter_m: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Latitude, longitude of a straight drive to the north-east at 5 m/s (seeded jitter)."""
    s = 5.0 * (FIX_NS - T0) / 1e9
    noise = np.random.default_rng(7).normal(0.0, jitter_m, (2, len(s)))
    to_wgs84 = pyproj.Transformer.from_crs(_LOCAL, "EPSG:4326", always_xy=True)
    lon, lat = to_wgs84.transform(s / math.sqrt(2) + noise[0], s / math.sqrt(2) + noise[1])
    return np.asarray(lat), np.asarray(lon)


def write_navsatfix_bag(
    path: Path, *, no_fix: tuple[int, ...] = (), every: int = 1, jitter_m: float = 0.0
) -> Path:
    lat, lon = _fixes_north_east(jitter_m)
    events = [(int(s), "fix", i) for i, s in enumerate(FIX_NS) if i % every == 0]
    events += [(int(s), "cam", i) for i, s in enumerate(CAMERA_NS)]
    with BagWriter(path, "mcap") as w:
        for stamp, kind, i in sorted(events):
            if kind == "cam":
                _write_camera(w, i, stamp, stamp + 1, "image")
                continue
            w.write_fields(
                "/gps/fix",
                "sensor_msgs/msg/NavSatFix",
                {
                    "header": {"stamp": stamp, "frame_id": "gps"},
                    "status": {"status": -1 if i in no_fix else 0, "service": 1},
                    "latitude": lat[i],
                    "longitude": lon[i],
                    "altitude": 520.0,
                },
                receive_ns=stamp + 1,
            )
    return path


def _fix_config(bag: Path, **pose: Any) -> Config:
    return _config(
        bag,
        topics=TopicsConfig(camera=CAMERA, pose="/gps/fix"),
        pose=PoseConfig(heading="motion", **pose),
    )


def test_extract_navsatfix_heading_from_motion_and_positions_match_pyproj(
    tmp_path: Path,
) -> None:
    ws = Workspace.create(tmp_path / "ws", _fix_config(write_navsatfix_bag(tmp_path / "bag")))
    info = extract(ws).info
    lat, lon = _fixes_north_east()
    world = info.world
    assert world.source_crs == "EPSG:4326"
    assert world.origin_lat_deg == pytest.approx(lat[0], abs=1e-10)
    assert world.origin_lon_deg == pytest.approx(lon[0], abs=1e-10)
    assert world.proj_string is not None
    poses = read_table(DatasetPaths(ws.dataset_dir).poses_csv)
    # The world frame is a tmerc at the first fix: north-east is ~45 degrees everywhere.
    heading_deg = np.degrees(poses["heading"])
    assert np.abs(heading_deg - 45.0).max() < 0.5
    assert info.heading_from_motion  # the splat's preparation bundle-adjusts these poses
    to_world = pyproj.Transformer.from_crs("EPSG:4326", world.proj_string, always_xy=True)
    fx, fy = to_world.transform(lon, lat)
    rel = (FIX_NS - T0).astype(float)
    q = (poses["stamp_ns"] - T0).astype(float)
    want = np.stack([np.interp(q, rel, fx), np.interp(q, rel, fy)], -1)
    xy = np.stack([poses["x"], poses["y"]], -1)
    assert np.abs(xy - want).max() < 1e-3
    assert np.abs(poses["z"]).max() < 1e-6
    assert np.abs(poses["speed"] - 5.0).max() < 0.05


def test_extract_smooths_jittery_navsatfix_before_the_heading_and_speed(tmp_path: Path) -> None:
    """0.1 m of jitter at 10 Hz: 0.2 s chords would make the speed 5 +- 0.7 m/s."""
    bag = write_navsatfix_bag(tmp_path / "bag", jitter_m=0.1)
    ws = Workspace.create(tmp_path / "ws", _fix_config(bag))
    world = extract(ws).info.world
    assert world.proj_string is not None
    poses = read_table(DatasetPaths(ws.dataset_dir).poses_csv)
    lat, lon = _fixes_north_east()  # the drive without the jitter
    to_world = pyproj.Transformer.from_crs("EPSG:4326", world.proj_string, always_xy=True)
    fx, fy = to_world.transform(lon, lat)
    rel, q = (FIX_NS - T0).astype(float), (poses["stamp_ns"] - T0).astype(float)
    true = np.stack([np.interp(q, rel, fx), np.interp(q, rel, fy)], -1)
    err = np.linalg.norm(np.stack([poses["x"], poses["y"]], -1) - true, axis=1)
    assert np.sqrt(np.mean(err**2)) < 0.07  # the fixes were 0.14 m off
    assert np.abs(poses["speed"] - 5.0).max() < 0.3
    assert np.abs(np.degrees(poses["heading"]) - 45.0).max() < 2.0


def test_extract_a_1_hz_navsatfix_poses_every_camera_frame(tmp_path: Path) -> None:
    """A GPS receiver logging once a second is slow, not broken: frames between fixes stay."""
    every = write_navsatfix_bag(tmp_path / "fast")
    slow = write_navsatfix_bag(tmp_path / "slow", every=10)  # fixes at 0, 1 and 2 s
    counts = []
    for bag in (every, slow):
        ws = Workspace.create(tmp_path / f"ws_{bag.name}", _fix_config(bag))
        info = extract(ws).info
        counts.append(info.counts.frames)
        assert not info.dropped.get("camera")
    assert counts[1] == counts[0] > 3


def test_extract_navsatfix_without_fix_suggests_dropping(tmp_path: Path) -> None:
    bag = write_navsatfix_bag(tmp_path / "bag", no_fix=(4, 5, 6))
    ws = Workspace.create(tmp_path / "ws", _fix_config(bag))
    with pytest.raises(RecordingError, match=r"3 no-fix messages.*pose.on_invalid: drop"):
        extract(ws)


def test_extract_navsatfix_without_fix_counts_dropped_messages(tmp_path: Path) -> None:
    bag = write_navsatfix_bag(tmp_path / "bag", no_fix=(4, 5, 6))
    ws = Workspace.create(tmp_path / "ws", _fix_config(bag, on_invalid="drop"))
    info = extract(ws).info
    assert info.dropped["pose"] == {"no_fix": 3}
    assert info.counts.pose_samples == len(FIX_NS) - 3
    saved = DatasetInfo.load(DatasetPaths(ws.dataset_dir).dataset_json)
    assert saved.dropped["pose"]["no_fix"] == 3


# -- (d-g) a local odometry drive with camera variants -----------------------------------------
ODOM_NS = T0 + 50 * MS * np.arange(41, dtype=np.int64)


def write_odom_bag(
    path: Path, *, camera: CameraKind = "image", header_offset_ns: int = 0
) -> tuple[Path, np.ndarray]:
    """Odometry along x at 5 m/s and a camera; header stamps = receive times + offset.

    Returns:
        The bag and the camera receive times.
    """
    events = [(int(s), "odom", i) for i, s in enumerate(ODOM_NS)]
    events += [(int(s), "cam", i) for i, s in enumerate(CAMERA_NS)]
    with BagWriter(path, "mcap") as w:
        for receive, kind, i in sorted(events):
            header = receive + header_offset_ns
            if kind == "cam":
                _write_camera(w, i, header, receive, camera)
                continue
            x = 5.0 * (receive - T0) / 1e9
            w.write_fields(
                "/odom",
                "nav_msgs/msg/Odometry",
                {
                    "header": {"stamp": header, "frame_id": "odom"},
                    "child_frame_id": "base_link",
                    "pose": {"pose": {"position": {"x": x}, "orientation": {"w": 1.0}}},
                },
                receive_ns=receive,
            )
    return path, CAMERA_NS.copy()


def test_extract_receive_time_base_uses_bag_record_times(tmp_path: Path) -> None:
    bag, camera_receive = write_odom_bag(tmp_path / "bag", header_offset_ns=10_000_000_000)
    cfg = _config(bag, recording=RecordingConfig(bags=[str(bag)], time_base="receive"))
    ws = Workspace.create(tmp_path / "ws", cfg)
    info = extract(ws).info
    assert info.time_base == "receive"
    poses = read_table(DatasetPaths(ws.dataset_dir).poses_csv)
    np.testing.assert_array_equal(poses["stamp_ns"], camera_receive)
    np.testing.assert_allclose(poses["x"], 5.0 * (camera_receive - T0) / 1e9, atol=2e-6)


def test_extract_header_time_base_uses_header_stamps(tmp_path: Path) -> None:
    bag, camera_receive = write_odom_bag(tmp_path / "bag", header_offset_ns=10_000_000_000)
    ws = Workspace.create(tmp_path / "ws", _config(bag))
    extract(ws)
    poses = read_table(DatasetPaths(ws.dataset_dir).poses_csv)
    np.testing.assert_array_equal(poses["stamp_ns"], camera_receive + 10_000_000_000)


@pytest.mark.parametrize("fmt", ["jpeg", "png"])
def test_extract_decodes_compressed_image_camera_topics(
    tmp_path: Path, fmt: Literal["jpeg", "png"]
) -> None:
    bag, _ = write_odom_bag(tmp_path / "bag", camera=fmt)
    ws = Workspace.create(tmp_path / "ws", _config(bag))
    info = extract(ws).info
    assert info.counts.frames == len(CAMERA_NS)
    paths = DatasetPaths(ws.dataset_dir)
    for i in range(len(CAMERA_NS)):
        on_disk = _read_frame(paths.frame_file(i, "png"))
        data = np.frombuffer(compressed_image_fields(_image(i), fmt)["data"], np.uint8)
        decoded = cv2.cvtColor(cv2.imdecode(data, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
        # The frame is exactly the decoded message; for PNG that is the recorded image.
        np.testing.assert_array_equal(on_disk, decoded)
        if fmt == "png":
            np.testing.assert_array_equal(on_disk, _image(i))
        else:
            assert np.abs(on_disk.astype(int) - _image(i)).max() <= 12


def test_extract_writes_jpeg_frames_when_asked(tmp_path: Path) -> None:
    bag, _ = write_odom_bag(tmp_path / "bag")
    cfg = _config(bag, frames=FramesConfig(format="jpeg", jpeg_quality=95))
    ws = Workspace.create(tmp_path / "ws", cfg)
    info = extract(ws).info
    assert info.frame_format == "jpeg"
    paths = DatasetPaths(ws.dataset_dir)
    files = sorted(paths.frames_dir.iterdir())
    assert [f.name for f in files] == [f"{i:06d}.jpg" for i in range(len(CAMERA_NS))]
    assert all(f.read_bytes()[:3] == b"\xff\xd8\xff" for f in files)
    for i, f in enumerate(files):
        assert np.abs(_read_frame(f).astype(int) - _image(i)).max() <= 12


def test_extract_keeps_every_third_frame(tmp_path: Path) -> None:
    bag, camera_ns = write_odom_bag(tmp_path / "bag")
    ws = Workspace.create(tmp_path / "ws", _config(bag, frames=FramesConfig(every=3)))
    info = extract(ws).info
    poses = read_table(DatasetPaths(ws.dataset_dir).poses_csv)
    np.testing.assert_array_equal(poses["stamp_ns"], camera_ns[::3])
    np.testing.assert_array_equal(poses["frame"], np.arange(len(camera_ns[::3])))
    assert info.counts.frames == 7
    paths = DatasetPaths(ws.dataset_dir)
    assert len(list(paths.frames_dir.iterdir())) == 7
    np.testing.assert_array_equal(_read_frame(paths.frame_file(2, "png")), _image(6))
