"""Stage init: a workspace with a starter config guessed from the recording's topics."""

from __future__ import annotations

from pathlib import Path

import pytest

from cam2sim.core.config import SignalConfig, TopicsConfig, load_config
from cam2sim.core.errors import RecordingError, WorkspaceError
from cam2sim.core.workspace import Workspace
from cam2sim.recording.bagwriter import BagWriter
from cam2sim.stages.init import init_workspace

T0 = 1_700_000_000_000_000_000

# topic -> (message type, number of messages)
BUSY_RECORDING = {
    "/cam_front/image_raw": ("sensor_msgs/msg/Image", 5),
    "/cam_rear/depth/image": ("sensor_msgs/msg/Image", 12),  # busier, but a depth image
    "/cam_rear/image/compressed": ("sensor_msgs/msg/CompressedImage", 8),
    "/cam_back/camera_info": ("sensor_msgs/msg/CameraInfo", 5),  # sorts first, wrong camera
    "/cam_front/camera_info": ("sensor_msgs/msg/CameraInfo", 5),
    "/gps/fix": ("sensor_msgs/msg/NavSatFix", 20),  # busier, but Odometry ranks higher
    "/odom": ("nav_msgs/msg/Odometry", 10),
    "/points_sparse": ("sensor_msgs/msg/PointCloud2", 3),
    "/velodyne_points": ("sensor_msgs/msg/PointCloud2", 6),
    "/other/speed": ("std_msgs/msg/Float64", 4),
    "/vehicle/gear": ("std_msgs/msg/Int32", 4),
    "/vehicle/speed": ("std_msgs/msg/Float64", 4),
    "/diagnostics_text": ("std_msgs/msg/String", 2),  # not numeric: no signal
}


def write_bag(path: Path, topics: dict[str, tuple[str, int]]) -> Path:
    """Write ``count`` default messages of each topic, interleaved in time."""
    events = [
        (T0 + i * 10_000_000 + j, name, msgtype)
        for j, (name, (msgtype, count)) in enumerate(topics.items())
        for i in range(count)
    ]
    with BagWriter(path, "mcap") as w:
        for stamp, name, msgtype in sorted(events):
            w.write_fields(name, msgtype, {}, receive_ns=stamp)
    return path


def test_init_guesses_camera_info_pose_lidar_and_signal_topics(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / "bag", BUSY_RECORDING)
    result = init_workspace(tmp_path / "ws", [bag])
    written = load_config(result.workspace.config_path)
    assert written.topics == TopicsConfig(
        camera="/cam_front/image_raw",
        camera_info="/cam_front/camera_info",
        pose="/odom",
        lidar="/velodyne_points",
        signals={
            "speed": SignalConfig(topic="/other/speed", field="data"),
            "gear": SignalConfig(topic="/vehicle/gear", field="data"),
            "speed_2": SignalConfig(topic="/vehicle/speed", field="data"),
        },
    )
    assert written.recording.bags == [str(bag.absolute())]
    assert written.pose.heading == "orientation"


def test_init_notes_name_the_alternative_camera_topics(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / "bag", BUSY_RECORDING)
    notes = init_workspace(tmp_path / "ws", [bag]).notes
    camera_note = next(n for n in notes if n.startswith("camera:"))
    assert "chose /cam_front/image_raw" in camera_note
    assert "/cam_rear/depth/image" in camera_note
    assert "/cam_rear/image/compressed" in camera_note
    assert any("signals: speed, gear, speed_2 (name the steering one" in n for n in notes)
    assert any("pose: /odom" in n and "EPSG:32632" in n for n in notes)
    # A recording whose steering topic already gets the name is not told to rename it.
    steering = write_bag(tmp_path / "bag2", {"/steering": ("std_msgs/msg/Float64", 4)})
    notes = init_workspace(tmp_path / "ws2", [steering]).notes
    assert "signals: steering" in notes
    # The notes are also written into config.yaml as comments.
    text = (tmp_path / "ws" / "config.yaml").read_text()
    assert "# Guessed by cam2sim init:" in text
    assert "other camera topics" in text


def test_init_writes_a_config_that_loads_back_equal(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / "bag", BUSY_RECORDING)
    result = init_workspace(tmp_path / "ws", [bag])
    assert load_config(result.workspace.config_path) == result.config
    assert Workspace.open(tmp_path / "ws").load_config() == result.config


def test_init_navsatfix_only_takes_heading_from_motion(tmp_path: Path) -> None:
    bag = write_bag(
        tmp_path / "bag",
        {
            "/camera/image_raw": ("sensor_msgs/msg/Image", 3),
            "/fix": ("sensor_msgs/msg/NavSatFix", 5),
        },
    )
    result = init_workspace(tmp_path / "ws", [bag])
    written = load_config(result.workspace.config_path)
    assert written.topics.pose == "/fix"
    assert written.pose.heading == "motion"
    assert "heading: motion" in result.workspace.config_path.read_text()
    assert any("NavSatFix" in n and "motion" in n for n in result.notes)


def test_init_without_camera_or_pose_says_what_to_set(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / "bag", {"/tf": ("tf2_msgs/msg/TFMessage", 3)})
    result = init_workspace(tmp_path / "ws", [bag])
    assert result.config.topics.camera is None
    assert result.config.topics.pose is None
    assert any("set topics.camera" in n for n in result.notes)
    assert any("pose.source: tf" in n for n in result.notes)


def test_init_refuses_an_existing_workspace_without_force(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / "bag", BUSY_RECORDING)
    init_workspace(tmp_path / "ws", [bag])
    before = (tmp_path / "ws" / "config.yaml").read_text()
    other = write_bag(tmp_path / "other", {"/front/image": ("sensor_msgs/msg/Image", 2)})
    with pytest.raises(WorkspaceError, match=r"already holds a cam2sim workspace.*--force"):
        init_workspace(tmp_path / "ws", [other])
    assert (tmp_path / "ws" / "config.yaml").read_text() == before


def test_init_with_force_overwrites_the_config(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / "bag", BUSY_RECORDING)
    init_workspace(tmp_path / "ws", [bag])
    other = write_bag(tmp_path / "other", {"/front/image": ("sensor_msgs/msg/Image", 2)})
    result = init_workspace(tmp_path / "ws", [other], force=True)
    written = load_config(tmp_path / "ws" / "config.yaml")
    assert written == result.config
    assert written.topics == TopicsConfig(camera="/front/image")
    assert written.recording.bags == [str(other.absolute())]


def test_init_reports_a_missing_bag(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match=r"missing\.bag does not exist; check the path"):
        init_workspace(tmp_path / "ws", [tmp_path / "missing.bag"])
    assert not (tmp_path / "ws").exists()
