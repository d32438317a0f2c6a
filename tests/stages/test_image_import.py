"""Stage import: a folder of images, optionally with a pose CSV and a calibration file."""

from __future__ import annotations

import json
import math
import re
import warnings
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest

from cam2sim.core import frames
from cam2sim.core.config import AxisConvention, Config, FramesConfig
from cam2sim.core.dataset import Calibration, DatasetInfo
from cam2sim.core.errors import RecordingError
from cam2sim.core.table import read_table
from cam2sim.core.workspace import DatasetPaths, Workspace
from cam2sim.stages.image_import import ImportOptions, import_images, stamps_from_names
from conftest import temporary_leftovers

UTM32N = "EPSG:32632"
POSE_T0 = 1_771_283_861_205_308_914  # like the reference drive's first stamp
E0, N0 = 692932.1277, 5339068.3913
SPEED = 5.0
TURN = 0.2  # rad/s


def _png(path: Path, image: np.ndarray) -> None:
    assert cv2.imwrite(str(path), image)


def _random_image(seed: int, size: tuple[int, int] = (16, 12)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.integers(0, 256, size=(size[1], size[0], 3), dtype=np.uint8)


def _write_images(folder: Path, names: list[str], size: tuple[int, int] = (16, 12)) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for i, name in enumerate(names):
        _png(folder / name, _random_image(i, size))
        paths.append(folder / name)
    return paths


def _stamp_text(stamp_ns: int) -> str:
    return f"{stamp_ns // 1_000_000_000}.{stamp_ns % 1_000_000_000:09d}"


class ReferencePoses:
    """A 2 s curve at 5 m/s in UTM 32N, written in the reference format (x_left odometry)."""

    def __init__(self) -> None:
        self.stamp_ns = POSE_T0 + 100_000_000 * np.arange(21, dtype=np.int64)
        t = (self.stamp_ns - POSE_T0) / 1e9
        heading = 0.3 + TURN * t  # grid heading of the car's forward axis
        k = SPEED / TURN
        self.easting = np.round(E0 + k * (np.sin(heading) - math.sin(0.3)), 6)
        self.northing = np.round(N0 - k * (np.cos(heading) - math.cos(0.3)), 6)
        self.yaw = np.round(heading + math.pi / 2, 6)  # odometry x axis points left

    def write(self, path: Path) -> Path:
        lines = ["timestamp,x,y,z,yaw"]
        lines += [
            f"{_stamp_text(int(s))},{e:.6f},{n:.6f},0.000000,{y:.6f}"
            for s, e, n, y in zip(self.stamp_ns, self.easting, self.northing, self.yaw, strict=True)
        ]
        path.write_text("\n".join(lines) + "\n")
        return path

    def at(self, stamp_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """UTM positions and yaw - 90 degrees, linearly interpolated at ``stamp_ns``."""
        rel = (self.stamp_ns - POSE_T0).astype(float)
        q = (stamp_ns - POSE_T0).astype(float)
        xy = np.stack([np.interp(q, rel, self.easting), np.interp(q, rel, self.northing)], -1)
        return xy, np.interp(q, rel, self.yaw) - math.pi / 2


def _image_stamps() -> np.ndarray:
    """15 Hz from 0.3 s before to 0.3 s after the poses."""
    return POSE_T0 - 300_000_000 + 66_666_667 * np.arange(40, dtype=np.int64)


def test_import_converts_reference_poses_to_the_world_frame(tmp_path: Path) -> None:
    poses = ReferencePoses()
    stamps = _image_stamps()
    _write_images(tmp_path / "images", [f"{s}.png" for s in stamps])
    opts = ImportOptions(
        poses=poses.write(tmp_path / "poses.csv"),
        crs=UTM32N,
        axis_convention=AxisConvention.X_LEFT,
    )
    info = import_images(tmp_path / "ws", tmp_path / "images", options=opts).info
    table = read_table(DatasetPaths(tmp_path / "ws" / "dataset").poses_csv)
    inside = (stamps >= poses.stamp_ns[0]) & (stamps <= poses.stamp_ns[-1])
    np.testing.assert_array_equal(table["stamp_ns"], stamps[inside])
    world = info.world
    assert world.source_crs == UTM32N
    wf = frames.WorldFrame(world.origin_lat_deg, world.origin_lon_deg, world.origin_alt_m)  # type: ignore[arg-type]
    xyz = np.stack([table["x"], table["y"], table["z"]], -1)
    want_xy, want_heading = poses.at(table["stamp_ns"])
    assert np.abs(wf.to_crs(UTM32N, xyz)[:, :2] - want_xy).max() < 1e-3
    heading_utm = wf.heading_to_crs(UTM32N, xyz[:, :2], table["heading"])
    assert np.degrees(np.abs(frames.angle_difference(heading_utm, want_heading))).max() < 0.1
    assert not info.heading_from_motion  # the poses carry their orientation
    # The world frame starts at the first pose.
    assert np.abs(wf.from_crs(UTM32N, [[E0, N0, 0.0]])).max() < 1e-3
    # The trajectory the map, scenario and derived steering read: the images' poses in order.
    trajectory = read_table(DatasetPaths(tmp_path / "ws" / "dataset").trajectory_csv)
    np.testing.assert_array_equal(trajectory["stamp_ns"], table["stamp_ns"])
    for column in ("x", "y", "z", "qx", "qy", "qz", "qw", "heading", "speed"):
        np.testing.assert_array_equal(trajectory[column], table[column])


def test_import_drops_and_counts_images_outside_the_pose_span(tmp_path: Path) -> None:
    poses = ReferencePoses()
    stamps = _image_stamps()
    _write_images(tmp_path / "images", [f"{s}.png" for s in stamps])
    opts = ImportOptions(
        poses=poses.write(tmp_path / "poses.csv"), crs=UTM32N, axis_convention=AxisConvention.X_LEFT
    )
    info = import_images(tmp_path / "ws", tmp_path / "images", options=opts).info
    outside = int(((stamps < poses.stamp_ns[0]) | (stamps > poses.stamp_ns[-1])).sum())
    assert outside == 10  # 5 before and 5 after
    assert info.dropped == {"camera": {"outside_pose_coverage": outside}}
    assert info.counts.frames == len(stamps) - outside
    assert info.counts.pose_samples == len(poses.stamp_ns)
    frames_dir = DatasetPaths(tmp_path / "ws" / "dataset").frames_dir
    assert len(list(frames_dir.iterdir())) == len(stamps) - outside


def test_poses_whose_x_axis_points_left_are_refused_without_the_convention(
    tmp_path: Path,
) -> None:
    """The reference car's odometry (x to the left) taken as x forward would drive sideways."""
    poses = ReferencePoses()
    _write_images(tmp_path / "images", [f"{s}.png" for s in _image_stamps()])
    opts = ImportOptions(poses=poses.write(tmp_path / "poses.csv"), crs=UTM32N)
    with pytest.raises(
        RecordingError,
        match=r"90 degrees from their own direction of travel.*"
        r"--axis-convention x_left",
    ):
        import_images(tmp_path / "ws", tmp_path / "images", options=opts)
    assert not (tmp_path / "ws" / "dataset").exists()  # nothing half written


def test_import_assigns_poses_by_the_image_column(tmp_path: Path) -> None:
    _write_images(tmp_path / "images", ["frame_a.png", "frame_b.png", "frame_c.png", "extra.png"])
    csv = tmp_path / "poses.csv"
    csv.write_text(
        "stamp_ns,x,y,yaw,image\n"
        "3000000000,30.0,3.0,0.3,frame_c.png\n"
        "1000000000,10.0,1.0,0.1,sub/frame_a.png\n"
        "2000000000,20.0,2.0,0.2,frame_b.png\n"
    )
    opts = ImportOptions(poses=csv)
    info = import_images(tmp_path / "ws", tmp_path / "images", options=opts).info
    assert info.dropped == {"camera": {"no_pose_row": 1}}
    table = read_table(DatasetPaths(tmp_path / "ws" / "dataset").poses_csv)
    # Frames follow the natural file-name order: frame_a, frame_b, frame_c ("extra" has no row).
    np.testing.assert_array_equal(table["stamp_ns"], [1e9, 2e9, 3e9])
    np.testing.assert_allclose(table["x"], [10.0, 20.0, 30.0])
    np.testing.assert_allclose(table["y"], [1.0, 2.0, 3.0])
    np.testing.assert_allclose(table["heading"], [0.1, 0.2, 0.3], atol=1e-9)


def test_import_copies_png_frames_pixel_identical(tmp_path: Path) -> None:
    names = [f"{10**18 + i * 10**8}.png" for i in range(5)]
    sources = _write_images(tmp_path / "images", names)
    import_images(tmp_path / "ws", tmp_path / "images")
    paths = DatasetPaths(tmp_path / "ws" / "dataset")
    for i, src in enumerate(sources):
        on_disk = cv2.imread(str(paths.frame_file(i, "png")), cv2.IMREAD_UNCHANGED)
        np.testing.assert_array_equal(on_disk, cv2.imread(str(src), cv2.IMREAD_UNCHANGED))
        np.testing.assert_array_equal(on_disk, _random_image(i))


def test_import_without_poses_writes_a_pose_less_dataset(tmp_path: Path) -> None:
    stamps = [10**18 + i * 33_333_333 for i in range(4)]
    _write_images(tmp_path / "images", [f"{s}.png" for s in reversed(stamps)])
    info = import_images(tmp_path / "ws", tmp_path / "images").info
    assert info.pose_less
    assert info.kind == "images"
    assert info.time_base == "file"
    assert info.counts.frames == 4
    assert info.counts.pose_samples == 0
    assert not info.world.georeferenced
    paths = DatasetPaths(tmp_path / "ws" / "dataset")
    assert not paths.poses_csv.exists()
    assert not paths.trajectory_csv.exists()
    table = read_table(paths.frames_csv)
    np.testing.assert_array_equal(table["frame"], np.arange(4))
    np.testing.assert_array_equal(table["stamp_ns"], stamps)
    assert DatasetInfo.load(paths.dataset_json).pose_less


def test_import_times_frames_by_fps_without_numeric_names(tmp_path: Path) -> None:
    _write_images(tmp_path / "images", ["img2.png", "img10.png", "img1.png"])
    opts = ImportOptions(fps=10.0)
    import_images(tmp_path / "ws", tmp_path / "images", options=opts)
    paths = DatasetPaths(tmp_path / "ws" / "dataset")
    np.testing.assert_array_equal(read_table(paths.frames_csv)["stamp_ns"], [0, 10**8, 2 * 10**8])
    # Natural order: img1, img2, img10.
    np.testing.assert_array_equal(cv2.imread(str(paths.frame_file(2, "png"))), _random_image(1))


def test_import_reads_a_cam2sim_camera_json(tmp_path: Path, shared_data: Path) -> None:
    camera_json = shared_data / "reference-drives" / "camera.json"
    raw = json.loads(camera_json.read_text())["camera"]
    folder = tmp_path / "images"
    folder.mkdir()
    for i in range(2):
        _png(folder / f"{10**18 + i * 10**8}.png", np.zeros((503, 800, 3), np.uint8))
    opts = ImportOptions(calibration=camera_json)
    import_images(tmp_path / "ws", folder, options=opts)
    calib = Calibration.load(DatasetPaths(tmp_path / "ws" / "dataset").calibration_json)
    assert calib.camera is not None
    assert (calib.camera.width, calib.camera.height) == (800, 503)
    np.testing.assert_array_equal(calib.camera.K, raw["calibration"]["K"])
    np.testing.assert_array_equal(calib.camera.distortion, raw["calibration"]["distortion"])
    mount = calib.camera_mount
    assert mount.axes == "optical"
    # CARLA's y points right; the body frame's y points left.
    np.testing.assert_allclose(mount.translation_m, [0.762, 0.015, 1.21], atol=1e-12)
    q = np.asarray(mount.quat_xyzw)
    pitch = math.radians(0.6)
    optical_axis = frames.quat_rotate(q, [0.0, 0.0, 1.0])
    np.testing.assert_allclose(optical_axis, [math.cos(pitch), 0.0, math.sin(pitch)], atol=1e-12)
    image_right = frames.quat_rotate(q, [1.0, 0.0, 0.0])
    np.testing.assert_allclose(image_right, [0.0, -1.0, 0.0], atol=1e-12)


# -- errors ------------------------------------------------------------------------------------
def test_import_rejects_a_folder_without_images(tmp_path: Path) -> None:
    (tmp_path / "images").mkdir()
    (tmp_path / "images" / "notes.txt").write_text("no images here")
    with pytest.raises(RecordingError, match=r"holds no \.png/\.jpg images; pass the folder"):
        import_images(tmp_path / "ws", tmp_path / "images")


def test_import_rejects_images_of_different_sizes(tmp_path: Path) -> None:
    _write_images(tmp_path / "images", ["1.png", "2.png"])
    _png(tmp_path / "images" / "3.png", _random_image(3, (8, 6)))
    with pytest.raises(RecordingError, match=r"3\.png is 8x6 but earlier images are 16x12"):
        import_images(tmp_path / "ws", tmp_path / "images")


def test_import_rejects_a_pose_csv_missing_columns(tmp_path: Path) -> None:
    _write_images(tmp_path / "images", ["1.png", "2.png"])
    csv = tmp_path / "poses.csv"
    csv.write_text("timestamp,x,z,yaw\n1.0,0,0,0\n2.0,1,0,0\n")
    with pytest.raises(
        RecordingError, match=r"needs columns timestamp.*x, y.*found timestamp, x, z, yaw"
    ):
        import_images(tmp_path / "ws", tmp_path / "images", options=ImportOptions(poses=csv))


def test_import_rejects_a_calibration_for_another_image_shape(tmp_path: Path) -> None:
    """16:9 calibration, 4:3 frames: cropped, not resized (one of the same shape is scaled)."""
    _write_images(tmp_path / "images", ["1.png", "2.png"])
    calib = tmp_path / "calib.json"
    K = [[500.0, 0.0, 320.0], [0.0, 500.0, 180.0], [0.0, 0.0, 1.0]]
    calib.write_text(json.dumps({"K": K, "distortion": [0.1], "width": 640, "height": 360}))
    with pytest.raises(
        RecordingError,
        match=r"calibration is for 640x360 but images are 16x12; pass the calibration",
    ):
        import_images(
            tmp_path / "ws", tmp_path / "images", options=ImportOptions(calibration=calib)
        )


def test_failed_import_keeps_the_earlier_dataset(tmp_path: Path) -> None:
    _write_images(tmp_path / "good", [f"{i}.png" for i in range(1, 4)])
    import_images(tmp_path / "ws", tmp_path / "good")
    dataset = tmp_path / "ws" / "dataset"
    before = {p.relative_to(dataset): p.read_bytes() for p in dataset.rglob("*") if p.is_file()}
    _write_images(tmp_path / "bad", ["1.png"])
    _png(tmp_path / "bad" / "2.png", _random_image(2, (8, 6)))
    with pytest.raises(RecordingError, match="8x6"):
        import_images(tmp_path / "ws", tmp_path / "bad")
    after = {p.relative_to(dataset): p.read_bytes() for p in dataset.rglob("*") if p.is_file()}
    assert after == before
    record = Workspace.open(tmp_path / "ws").stage_record("extract")
    assert record is not None
    assert record.state == "failed"
    assert temporary_leftovers(tmp_path / "ws") == []


# -- real data ---------------------------------------------------------------------------------
def test_import_udacity_frames_as_a_pose_less_dataset(tmp_path: Path, shared_data: Path) -> None:
    folder = shared_data / "images" / "udacity-ch2"
    names = sorted(p.stem for p in folder.glob("*.jpg"))
    assert len(names) == 300
    # Keep the JPEG files as they are (a PNG re-encode of 300 frames is slow and not the point).
    Workspace.create(tmp_path / "ws", Config(frames=FramesConfig(format="jpeg")))
    info = import_images(tmp_path / "ws", folder).info
    assert info.pose_less
    assert info.counts.frames == 300
    paths = DatasetPaths(tmp_path / "ws" / "dataset")
    stamps = read_table(paths.frames_csv)["stamp_ns"]
    np.testing.assert_array_equal(stamps, sorted(int(n) for n in names))
    assert info.start_ns == int(stamps[0])
    assert info.end_ns == int(stamps[-1])
    assert (folder / f"{names[0]}.jpg").read_bytes() == paths.frame_file(0, "jpeg").read_bytes()


# -- KITTI's poses.txt and K.txt -------------------------------------------------------------

_B = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])  # vehicle axes, optical


def _kitti_lines(xy: np.ndarray, heading: np.ndarray, z: float) -> list[str]:
    """KITTI camera-to-world lines of vehicle poses (the first camera's frame is the world)."""
    lines = []
    for (x, y), h in zip(xy, heading, strict=True):
        c, s = math.cos(h), math.sin(h)
        r_wv = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        m = np.hstack([_B @ r_wv @ _B.T, (_B @ np.array([x, y, z]))[:, None]])
        lines.append(" ".join(f"{v:.9e}" for v in m.ravel()))
    return lines


def test_import_reads_kitti_poses_and_a_bare_K(tmp_path: Path) -> None:
    n = 12
    s = np.arange(n) * 1.0
    heading = np.where(s > 5, (s - 5) * 0.05, 0.0)  # straight, then turning left
    xy = np.cumsum(np.stack([np.cos(heading), np.sin(heading)], -1), axis=0) - [1.0, 0.0]
    poses = tmp_path / "poses.txt"
    poses.write_text("\n".join(_kitti_lines(xy, heading, 0.0)) + "\n", encoding="utf-8")
    (tmp_path / "K.txt").write_text("20 0 8\n0 20 6\n0 0 1\n", encoding="utf-8")
    _write_images(tmp_path / "images", [f"{k:06d}.png" for k in range(n + 2)])  # 2 unposed
    opts = ImportOptions(poses=poses, calibration=tmp_path / "K.txt", fps=10.0)
    info = import_images(tmp_path / "ws", tmp_path / "images", options=opts).info
    assert info.counts.frames == n
    assert not info.world.georeferenced
    paths = DatasetPaths(tmp_path / "ws" / "dataset")
    table = read_table(paths.poses_csv)
    np.testing.assert_allclose(table["x"], xy[:, 0], atol=1e-6)
    np.testing.assert_allclose(table["y"], xy[:, 1], atol=1e-6)
    np.testing.assert_allclose(table["z"], 0.0, atol=1e-6)
    np.testing.assert_allclose(table["heading"], heading, atol=1e-6)
    np.testing.assert_array_equal(table["stamp_ns"], np.arange(n) * 100_000_000)  # 10 fps
    assert paths.trajectory_csv.is_file()
    camera = Calibration.load(paths.calibration_json).camera
    assert camera is not None
    assert (camera.width, camera.height) == (16, 12)  # from the images
    assert camera.K[0][0] == 20.0
    assert "size from the images" in camera.source


def _turning_kitti_drive(tmp_path: Path, bicycle_drive: Callable, ahead_m: float) -> Path:
    """A KITTI-format drive through two turns, posed ``ahead_m`` in front of the rear axle."""
    _, xy, heading, _, _ = bicycle_drive(ahead_m)
    poses = tmp_path / f"poses-{ahead_m}.txt"
    poses.write_text("\n".join(_kitti_lines(xy, heading, 0.0)) + "\n", encoding="utf-8")
    if not (tmp_path / "images").is_dir():
        _write_images(tmp_path / "images", [f"{k:06d}.png" for k in range(len(xy))])
    return poses


def test_import_fits_where_the_poses_sit_from_the_drives_turns(
    tmp_path: Path, bicycle_drive: Callable, caplog: pytest.LogCaptureFixture
) -> None:
    """KITTI 03's camera turned like a point 0.88 m ahead of the rear axle, not the 2.19 m of
    the recipe's 0.8 m before the centre: a simulated car posed there cannot follow the turns."""
    poses = _turning_kitti_drive(tmp_path, bicycle_drive, 1.3)

    def imported(name: str, offset: tuple[float | None, float, float] | None) -> tuple:
        opts = ImportOptions(poses=poses, fps=10.0, pose_offset_m=offset)
        result = import_images(tmp_path / name, tmp_path / "images", options=opts)
        return result, Workspace.open(tmp_path / name).load_config().vehicle

    result, vehicle = imported("fit", (None, 0.0, 1.65))  # X measured, Y and Z as given
    assert result.pose_point is not None
    assert result.pose_point.ahead_m == pytest.approx(1.3, abs=0.05)
    want = (vehicle.rear_axle_x_m + 1.3, 0.0, 1.65)
    assert vehicle.reference_xyz() == pytest.approx(want, abs=0.05)
    manifest = Workspace.open(tmp_path / "fit").read_manifest()
    snapshot = manifest.config  # config.yaml as the import left it
    assert snapshot is not None
    assert snapshot["vehicle"]["reference_offset_m"] == list(vehicle.reference_xyz())

    _, vehicle = imported("none", None)  # not given: measured, at ground height
    assert vehicle.reference_xyz() == pytest.approx((vehicle.rear_axle_x_m + 1.3, 0, 0), abs=0.05)

    with caplog.at_level("WARNING", logger="cam2sim.stages.image_import"):
        _, vehicle = imported("given", (0.8, 0.0, 1.65))  # numbers are kept, and checked
    assert vehicle.reference_xyz() == (0.8, 0.0, 1.65)
    assert "1.30 +- 0.0" in caplog.text
    assert "--pose-offset fit,Y,Z" in caplog.text

    # The scenario stage checks again, for bags too, and says what to write in config.yaml.
    from cam2sim.stages.scenario import check_pose_point

    caplog.clear()
    with caplog.at_level("WARNING", logger="cam2sim.stages.scenario"):
        assert check_pose_point(Workspace.open(tmp_path / "fit")) is not None
        assert not caplog.text
        check_pose_point(Workspace.open(tmp_path / "given"))
    said = re.search(r"reference_offset_m: \[(-?[0-9.]+), 0.00, 1.65\]", caplog.text)
    assert said is not None
    assert float(said.group(1)) == pytest.approx(vehicle.rear_axle_x_m + 1.3, abs=0.05)


def test_steering_derived_on_an_import_is_the_rear_axles_turn(
    tmp_path: Path, bicycle_drive: Callable
) -> None:
    """The steering derived from a camera's poses is the command the bicycle model drove."""
    from cam2sim.core.vehicle import SteeringCalibration
    from cam2sim.stages.ads import DERIVED_STEERING, derive_steering

    poses = _turning_kitti_drive(tmp_path, bicycle_drive, 1.3)
    opts = ImportOptions(poses=poses, fps=10.0, pose_offset_m=(None, 0.0, 1.65))
    import_images(tmp_path / "ws", tmp_path / "images", options=opts)
    assert derive_steering(Workspace.open(tmp_path / "ws")) == DERIVED_STEERING
    table = read_table(DatasetPaths(tmp_path / "ws" / "dataset").signal_file(DERIVED_STEERING))
    t, _, _, _, kappa = bicycle_drive(1.3)
    driven = kappa / SteeringCalibration().curvature_per_unit
    got = np.interp(t, (table["stamp_ns"] - table["stamp_ns"][0]) / 1e9, table["value"])
    inside = (t > 1.0) & (t < t[-1] - 1.0)
    # The turns' peaks whole (the camera's own path turns 1 % less than the rear axle's), and
    # the changes of curvature followed (a 6 m window: 0.27 units off on average).
    assert got.min() == pytest.approx(driven.min(), rel=0.005)
    assert got.max() == pytest.approx(driven.max(), rel=0.005)
    assert np.abs(got[inside] - driven[inside]).mean() < 0.15


def test_import_leaves_poses_at_the_rear_axle_where_they_turn_like_it(
    tmp_path: Path, bicycle_drive: Callable
) -> None:
    poses = _turning_kitti_drive(tmp_path, bicycle_drive, 0.0)
    opts = ImportOptions(poses=poses, fps=10.0)
    result = import_images(tmp_path / "ws", tmp_path / "images", options=opts)
    assert result.pose_point is not None
    assert abs(result.pose_point.ahead_m) < 0.05
    assert Workspace.open(tmp_path / "ws").load_config().vehicle.reference == "rear_axle"


def test_a_calibration_that_is_neither_json_nor_K_says_what_is_accepted(tmp_path: Path) -> None:
    _write_images(tmp_path / "images", ["000000.png", "000001.png"])
    (tmp_path / "K.txt").write_text("20 0 8\n0 20 6\n0 0\n", encoding="utf-8")
    with pytest.raises(RecordingError, match=r"neither JSON .* nor a plain 3x3 K matrix"):
        import_images(
            tmp_path / "ws",
            tmp_path / "images",
            options=ImportOptions(calibration=tmp_path / "K.txt"),
        )


def test_import_kitti_03_as_published(tmp_path: Path, shared_data: Path) -> None:
    kitti = shared_data / "posed" / "kitti-odometry-03"
    opts = ImportOptions(poses=kitti / "poses.txt", calibration=kitti / "K.txt", fps=10.0)
    info = import_images(tmp_path / "ws", kitti / "images", options=opts).info
    assert info.counts.frames == 40
    table = read_table(DatasetPaths(tmp_path / "ws" / "dataset").poses_csv)
    # KITTI 03 starts driving straight ahead at about 35 km/h, on a level road.
    assert table["x"][-1] > 30.0
    assert abs(table["y"][-1]) < 2.0
    assert np.abs(table["z"]).max() < 1.0
    assert 8.0 < float(np.median(table["speed"])) < 11.0
    assert np.abs(table["heading"]).max() < 0.1


def test_cam2sim_run_takes_an_imported_dataset_as_extracted(tmp_path: Path) -> None:
    from cam2sim.stages.pipeline import PipelineOptions, run_pipeline

    stamps = [10**18 + i * 33_333_333 for i in range(4)]
    _write_images(tmp_path / "images", [f"{s}.png" for s in stamps])
    import_images(tmp_path / "ws", tmp_path / "images")
    ws = Workspace.open(tmp_path / "ws")
    result = run_pipeline(ws, options=PipelineOptions(steps=("extract",)))
    extract = result.outcome("extract")
    assert extract.state == "up_to_date"  # no bag to extract: the import is the dataset
    assert "cam2sim import" in extract.message
    assert not result.failed


def test_run_stops_before_the_splat_when_replay_and_drive_could_not_render(
    tmp_path: Path,
) -> None:
    """Posed frames without intrinsics: the run says to import with --calibration or --fov."""
    from cam2sim.stages.pipeline import PipelineOptions, run_pipeline

    stamps = [10**18 + i * 100_000_000 for i in range(6)]
    _write_images(tmp_path / "images", [f"{s}.png" for s in stamps])
    poses = tmp_path / "poses.csv"
    poses.write_text("stamp_ns,x,y\n" + "".join(f"{s},{2.0 * i},0\n" for i, s in enumerate(stamps)))
    import_images(tmp_path / "ws", tmp_path / "images", options=ImportOptions(poses=poses))
    ws = Workspace.open(tmp_path / "ws")
    result = run_pipeline(ws, options=PipelineOptions(steps=("splat", "replay")))
    splat = result.outcome("splat")
    assert splat.state == "failed"
    assert "--calibration" in splat.message
    assert "--fov" in splat.message
    assert result.outcome("replay").state == "skipped"
    assert not ws.splat_files.models_dir.is_dir()  # nothing trained for nothing


def test_kitti_03_import_map_from_its_path_and_scenario(tmp_path: Path, shared_data: Path) -> None:
    """A real drive with poses but no CRS and no OSM: the map is the road it drove on."""
    pytest.importorskip("carla", reason="the scenario's checks need carla (cam2sim[map])")
    from cam2sim.stages.map import build_map
    from cam2sim.stages.scenario import run_scenario

    kitti = shared_data / "posed" / "kitti-odometry-03"
    opts = ImportOptions(poses=kitti / "poses.txt", calibration=kitti / "K.txt", fps=10.0)
    import_images(tmp_path / "ws", kitti / "images", options=opts)
    ws = Workspace.open(tmp_path / "ws")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = build_map(ws)
    assert any("not geo-referenced" in str(w.message) for w in caught)
    report = result.report
    assert report.source.kind == "trajectory"
    assert not report.georeferenced
    assert report.route.covered_fraction == pytest.approx(1.0)
    assert report.route.lateral_offset.p95_m is not None
    assert report.route.lateral_offset.p95_m < 0.1
    scenario = run_scenario(ws)
    assert scenario.scenario is not None
    assert len(scenario.scenario.trajectory.t) == 40
    assert ws.scenario_path.is_file()
    # The report says where the road came from: the driven path, not OSM.
    from cam2sim.report.html import write_report

    html = write_report(ws).read_text(encoding="utf-8")
    assert "<td>map</td><td>the driven path" in html
    assert "Overpass" not in html


def test_a_grey_camera_is_recorded_grey_and_its_simulated_views_too(
    tmp_path: Path, shared_data: Path
) -> None:
    from cam2sim.core.images import as_grey, frames_are_grey

    kitti = shared_data / "posed" / "kitti-odometry-03"
    opts = ImportOptions(poses=kitti / "poses.txt", calibration=kitti / "K.txt", fps=10.0)
    import_images(tmp_path / "ws", kitti / "images", options=opts)
    calib = Calibration.load(DatasetPaths(tmp_path / "ws" / "dataset").calibration_json)
    assert calib.camera is not None
    assert calib.camera.grey
    colour = _write_images(tmp_path / "colour", ["a.png", "b.png"])
    assert not frames_are_grey(colour)
    rgb = np.array([[[255, 0, 0], [0, 255, 0], [10, 20, 30]]], np.uint8)
    grey = as_grey(rgb)
    assert grey.shape == rgb.shape
    assert (grey[..., 0] == grey[..., 2]).all()
    expect = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    assert np.abs(grey[..., 0].astype(int) - expect.astype(int)).max() <= 1


def test_import_brings_signals_and_where_the_poses_sit_on_the_car(tmp_path: Path) -> None:
    stamps = [10**18 + i * 100_000_000 for i in range(5)]
    _write_images(tmp_path / "images", [f"{s}.png" for s in stamps])
    steer = tmp_path / "steer.csv"
    rows = [f"{_stamp_text(s)},{0.1 * i}" for i, s in enumerate(reversed(stamps))]
    steer.write_text("timestamp,steering\n" + "\n".join(rows) + "\n", encoding="utf-8")
    opts = ImportOptions(signals=(("steering", steer),), pose_offset_m=(0.8, 0.0, 1.65))
    info = import_images(tmp_path / "ws", tmp_path / "images", options=opts).info
    assert info.counts.signals == {"steering": 5}
    table = read_table(DatasetPaths(tmp_path / "ws" / "dataset").signal_file("steering"))
    assert list(table["stamp_ns"]) == stamps  # in time order
    assert table["value"][0] == pytest.approx(0.4)
    vehicle = Workspace.open(tmp_path / "ws").load_config().vehicle
    assert vehicle.reference_xyz() == (0.8, 0.0, 1.65)
    bad = tmp_path / "bad.csv"
    bad.write_text("when,a,b\n1,2,3\n", encoding="utf-8")
    with pytest.raises(RecordingError, match=r"bad.csv: needs a time column"):  # before any write
        import_images(
            tmp_path / "ws2",
            tmp_path / "images",
            options=ImportOptions(signals=(("steering", bad),)),
        )
    assert not (tmp_path / "ws2").exists()


@pytest.mark.parametrize(
    ("names", "source", "first_ns", "step_ns"),
    [
        (["1479425441182877835.jpg", "1479425441232704425.jpg"], "file names (ns)",
         1479425441182877835, 49826590),
        (["center_1479425441182877835.jpg", "center_1479425441232704425.jpg"], "file names (ns)",
         1479425441182877835, 49826590),
        (["left_1541178393.125.png", "left_1541178393.225.png"], "file names (s)",
         1541178393125000000, 100000000),
        (["1418381798113072.png", "1418381798175573.png"], "file names (us)",  # RobotCar
         1418381798113072000, 62501000),
        (["1541178393125.jpg", "1541178393225.jpg"], "file names (ms)", 1541178393125000000,
         100000000),
        (["cam0_frame_000001.png", "cam0_frame_000002.png"], "frame index at 10 fps", 0, 100000000),
        (["t_1541178393_125.png", "t_1541178394_025.png"], "frame index at 10 fps", 0, 100000000),
    ],
)  # fmt: skip
def test_image_times_from_the_number_that_differs_in_their_names(
    names: list[str], source: str, first_ns: int, step_ns: int
) -> None:
    """A name's prefix (Udacity's ``center_``) does not hide its time; two numbers do."""
    stamps, where = stamps_from_names([Path(n) for n in names], fps=10.0)
    assert where == source
    assert stamps[0] == first_ns
    assert stamps[1] - stamps[0] == pytest.approx(step_ns, abs=1000)
