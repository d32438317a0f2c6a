"""comma2k19 segments as comma ships them: global_pose/ and processed_log/ numpy files."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from cam2sim.core import frames
from cam2sim.core.dataset import DatasetInfo
from cam2sim.core.errors import RecordingError
from cam2sim.core.table import read_table
from cam2sim.core.workspace import DatasetPaths
from cam2sim.recording.comma2k19 import read_log_signal
from cam2sim.recording.pose_file import read_pose_file
from cam2sim.stages.image_import import ImportOptions, import_images
from conftest import write_frames

LAT, LON, H = 37.721, -122.4723, 31.6
HEADING = np.radians(250.0)  # ENU yaw: west-south-west


def _save(path: Path, array: np.ndarray) -> None:
    """A numpy file without its suffix, as comma2k19 ships them."""
    with path.open("wb") as handle:
        np.save(handle, array)


def _synthetic_segment(root: Path, n: int = 40) -> Path:
    """A straight drive at 15 m/s heading ``HEADING``, the device pitched 3 degrees down."""
    import pyproj

    folder = root / "segment" / "global_pose"
    folder.mkdir(parents=True)
    to_ecef = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    origin = np.array(to_ecef.transform(LON, LAT, H))
    enu_from_ecef = frames.enu_from_ecef_rotation(LAT, LON)
    t = 100.0 + 0.05 * np.arange(n)  # boot clock, 20 Hz
    along = 15.0 * (t - t[0])
    enu = np.column_stack([along * np.cos(HEADING), along * np.sin(HEADING), np.zeros(n)])
    _save(folder / "frame_times", t)
    _save(folder / "frame_positions", origin + enu @ enu_from_ecef)  # ENU -> ECEF: R^T
    body = frames.quat_to_matrix(frames.quat_from_euler(0.0, np.radians(3.0), HEADING))
    ecef_from_device = enu_from_ecef.T @ body @ np.diag([1.0, -1.0, -1.0])
    xyzw = frames.quat_from_matrix(ecef_from_device)
    _save(folder / "frame_orientations", np.tile(np.roll(xyzw, 1), (n, 1)))  # (w, x, y, z)
    return folder.parent


def test_a_segments_global_pose_is_a_geographic_table_with_the_body_in_enu(
    tmp_path: Path,
) -> None:
    segment = _synthetic_segment(tmp_path)
    table = read_pose_file(segment)  # the segment folder, or its global_pose/
    assert table.kind == "comma2k19"
    assert table.geographic
    np.testing.assert_allclose(table.xyz[0], [LAT, LON, H], atol=1e-7)
    assert table.stamp_ns[1] - table.stamp_ns[0] == 50_000_000
    assert table.quat is not None
    euler = frames.euler_from_quat(table.quat)
    np.testing.assert_allclose(euler.yaw, HEADING - 2 * np.pi, atol=1e-5)  # + the meridians
    np.testing.assert_allclose(euler.pitch, np.radians(3.0), atol=1e-5)  # nose down
    np.testing.assert_allclose(euler.roll, 0.0, atol=1e-5)


def test_a_broken_global_pose_names_the_file(tmp_path: Path) -> None:
    segment = _synthetic_segment(tmp_path)
    _save(segment / "global_pose" / "frame_positions", np.zeros((40, 2)))
    with pytest.raises(RecordingError, match=r"frame_positions: an array of shape \(40, 2\)"):
        read_pose_file(segment)
    (segment / "global_pose" / "frame_positions").write_text("not numpy")
    with pytest.raises(RecordingError, match=r"frame_positions: not a numpy array file"):
        read_pose_file(segment)


def test_the_real_minute_heads_where_it_drives(shared_data: Path, tmp_path: Path) -> None:
    """The shared minute in San Francisco: orientation within 1.5 degrees of the travel."""
    comma = shared_data / "poses" / "comma2k19"
    folder = tmp_path / "global_pose"
    folder.mkdir()
    for name in ("frame_times", "frame_positions", "frame_orientations"):
        shutil.copyfile(comma / f"global_pose_{name}", folder / name)
    table = read_pose_file(folder)
    assert len(table.stamp_ns) == 1200
    assert table.quat is not None
    world = frames.WorldFrame(*table.xyz[0])
    xyz = world.from_wgs84(table.xyz[:, 0], table.xyz[:, 1], table.xyz[:, 2])
    step = np.diff(xyz[:, :2], axis=0)
    moving = np.hypot(*step.T) > 0.1
    travel = np.arctan2(step[:, 1], step[:, 0])
    off = frames.wrap_angle(frames.yaw_from_quat(table.quat)[:-1] - travel)[moving]
    assert np.degrees(np.abs(np.median(off))) < 1.5


def test_import_takes_the_segment_and_its_can_steering_as_they_come(
    shared_data: Path, tmp_path: Path
) -> None:
    """Frames (here tiny stand-ins at 5 Hz) + global_pose/ + processed_log/CAN/steering_angle/."""
    comma = shared_data / "poses" / "comma2k19"
    segment = tmp_path / "segment"
    (segment / "global_pose").mkdir(parents=True)
    for name in ("frame_times", "frame_positions", "frame_orientations"):
        shutil.copyfile(comma / f"global_pose_{name}", segment / "global_pose" / name)
    can = segment / "processed_log" / "CAN" / "steering_angle"
    can.mkdir(parents=True)
    for name in ("t", "value"):
        shutil.copyfile(comma / f"processed_log_CAN_steering_angle_{name}", can / name)
    images = tmp_path / "frames"
    write_frames(images, 300)
    opts = ImportOptions(poses=segment, fps=5.0, signals=(("steering", can),))
    result = import_images(tmp_path / "ws", images, options=opts)
    assert result.info.world.georeferenced
    assert result.info.counts.frames == 300
    assert not result.info.heading_from_motion  # the fused orientation is used
    paths = DatasetPaths(tmp_path / "ws" / "dataset")
    steering = read_table(paths.signal_file("steering"))
    t, value = read_log_signal(can)
    assert len(steering["value"]) == len(value)
    assert DatasetInfo.load(paths.dataset_json).counts.frames == 300
    # the signal stays on the poses' clock, which the frames were moved onto
    trajectory = read_table(paths.trajectory_csv)
    assert trajectory["stamp_ns"][0] == pytest.approx(t[0], abs=5e9)


def test_a_bare_video_stream_takes_its_frame_rate_from_fps(tmp_path: Path) -> None:
    """comma2k19's video.hevc has no container: FFmpeg would read it at 25 frames a second.

    A bare MJPEG stream stands in for it (OpenCV has no HEVC encoder here)."""
    stream = tmp_path / "video.mjpeg"
    with stream.open("wb") as handle:
        for i in range(40):
            ok, jpeg = cv2.imencode(".jpg", np.full((12, 16, 3), 6 * i, np.uint8))
            assert ok
            handle.write(jpeg.tobytes())
    opts = ImportOptions(fps=20.0, video_fps=10.0)
    result = import_images(tmp_path / "ws", stream, options=opts)
    assert result.info.counts.frames == 20  # every other frame of 20 a second
    frames_table = read_table(DatasetPaths(tmp_path / "ws" / "dataset").frames_csv)
    step = np.diff(frames_table["stamp_ns"])
    np.testing.assert_array_equal(step, 100_000_000)  # not the 80 ms of 25 a second
