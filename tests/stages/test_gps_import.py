"""Import with GPS poses: a CSV of fixes, KITTI raw's OXTS folder, and a real GPS drive."""

from __future__ import annotations

import math
import warnings
from typing import TYPE_CHECKING

import cv2
import numpy as np
import pyproj
import pytest

from cam2sim.core import frames
from cam2sim.core.errors import RecordingError
from cam2sim.core.table import read_table
from cam2sim.core.workspace import DatasetPaths, Workspace
from cam2sim.recording.pose_file import read_pose_file
from cam2sim.stages.image_import import ImportOptions, import_images

if TYPE_CHECKING:
    from pathlib import Path

    from cam2sim.stages.image_import import ImportResult

UTM10N = "EPSG:32610"
T0 = 1_500_000_000_000_000_000


def _images(folder: Path, names: list[str]) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    blank = np.zeros((12, 16, 3), np.uint8)
    for name in names:
        assert cv2.imwrite(str(folder / name), blank)


def _to_wgs84(crs: str, e: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    lon, lat = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True).transform(e, n)
    return np.asarray(lat), np.asarray(lon)


def _arc(n: int, speed: float = 8.0, turn: float = 0.15, dt: float = 0.1) -> tuple[np.ndarray, ...]:
    """A drive in UTM 10N (San Francisco): straight for 2 s, then a steady left turn."""
    t = np.arange(n) * dt
    heading = 0.4 + turn * np.clip(t - 2.0, 0.0, None)
    step = speed * dt * np.stack([np.cos(heading), np.sin(heading)], -1)
    xy = np.cumsum(step, axis=0) - step[0] + [551_000.0, 4_175_000.0]
    return t, xy, heading


def _import_gps(
    root: Path,
    stamps: np.ndarray,
    lat: np.ndarray,
    lon: np.ndarray,
    alt: np.ndarray | None = None,
    names: tuple[str, str, str] = ("lat", "lon", "alt"),
) -> ImportResult:
    """Write ``root/gps.csv`` (timestamp, lat, lon[, alt]) and a frame per fix; import them."""
    header = ["timestamp", *names[: 2 if alt is None else 3]]
    rows = [",".join(header)]
    for k, s in enumerate(stamps.tolist()):
        cells = [f"{s // 10**9}.{s % 10**9:09d}", f"{lat[k]:.10f}", f"{lon[k]:.10f}"]
        rows.append(",".join(cells if alt is None else [*cells, f"{alt[k]:.3f}"]))
    (root / "gps.csv").write_text("\n".join(rows) + "\n")
    _images(root / "images", [f"{s}.png" for s in stamps])
    opts = ImportOptions(poses=root / "gps.csv")
    return import_images(root / "ws", root / "images", options=opts)


def _noisy_arc(
    root: Path, seed: int
) -> tuple[np.ndarray, np.ndarray, ImportResult, dict[str, np.ndarray], np.ndarray]:
    """:func:`_arc` as 10 Hz fixes with 0.1 m of jitter, imported: the true UTM positions and
    headings, the import's result, its poses table and their UTM positions."""
    _, xy, heading = _arc(120)
    noisy = xy + np.random.default_rng(seed).normal(0.0, 0.1, xy.shape)
    lat, lon = _to_wgs84(UTM10N, noisy[:, 0], noisy[:, 1])
    stamps = T0 + np.round(np.arange(120) * 0.1 * 1e9).astype(np.int64)
    result = _import_gps(root, stamps, lat, lon)
    table = read_table(DatasetPaths(root / "ws" / "dataset").poses_csv)
    world = result.info.world
    wf = frames.WorldFrame(world.origin_lat_deg, world.origin_lon_deg)  # type: ignore[arg-type]
    utm = wf.to_crs(UTM10N, np.stack([table["x"], table["y"], table["z"]], -1))
    return xy, heading, result, table, utm


def test_a_gps_csv_is_geo_referenced_and_heads_where_it_drives(tmp_path: Path) -> None:
    """Latitude, longitude and altitude, no orientation and no --crs: the world frame starts at
    the first fix and the heading is the direction of travel."""
    t, xy, heading = _arc(60)
    lat, lon = _to_wgs84(UTM10N, xy[:, 0], xy[:, 1])
    stamps = T0 + np.round(t * 1e9).astype(np.int64)
    alt = np.full(len(stamps), 12.5)
    info = _import_gps(tmp_path, stamps, lat, lon, alt, ("latitude", "longitude", "altitude")).info
    world = info.world
    assert world.georeferenced
    assert world.source_crs == "EPSG:4326"
    assert world.origin_lat_deg == pytest.approx(lat[0], abs=1e-9)
    assert world.origin_alt_m == pytest.approx(12.5)
    table = read_table(DatasetPaths(tmp_path / "ws" / "dataset").poses_csv)
    wf = frames.WorldFrame(world.origin_lat_deg, world.origin_lon_deg, world.origin_alt_m)  # type: ignore[arg-type]
    xyz = np.stack([table["x"], table["y"], table["z"]], -1)
    assert np.abs(wf.to_crs(UTM10N, xyz)[:, :2] - xy).max() < 1e-3
    np.testing.assert_allclose(table["z"], 0.0, atol=1e-9)  # altitude relative to the origin
    grid = wf.heading_to_crs(UTM10N, xyz[:, :2], table["heading"])
    inside = slice(5, -5)  # the motion window is one-sided at the ends
    err = np.degrees(np.abs(frames.angle_difference(grid[inside], heading[inside])))
    assert err.mean() < 0.5
    assert err.max() < 1.5  # where the turn begins: the 1 s chord straddles the change
    assert float(np.median(table["speed"])) == pytest.approx(8.0, rel=0.01)
    assert info.heading_from_motion  # so the splat's preparation refines these poses


def test_gps_fixes_on_a_hill_pitch_the_car_with_the_road(tmp_path: Path) -> None:
    """Fixes that climb 5 % give poses pitched nose up by the grade (ROS pitch: negative), so
    the splat camera leans with the recorded road; the heading stays the direction of travel."""
    t, xy, _ = _arc(80, turn=0.0)
    lat, lon = _to_wgs84(UTM10N, xy[:, 0], xy[:, 1])
    travelled = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    alt = 30.0 + 0.05 * travelled
    stamps = T0 + np.round(t * 1e9).astype(np.int64)
    _import_gps(tmp_path, stamps, lat, lon, alt)
    table = read_table(DatasetPaths(tmp_path / "ws" / "dataset").poses_csv)
    quat = np.stack([table[c] for c in ("qx", "qy", "qz", "qw")], -1)
    euler = frames.euler_from_quat(quat)
    np.testing.assert_allclose(np.degrees(euler.pitch), -np.degrees(np.arctan(0.05)), atol=0.05)
    np.testing.assert_allclose(euler.roll, 0.0, atol=1e-6)
    np.testing.assert_allclose(euler.yaw, table["heading"], atol=1e-6)


def test_heading_from_noisy_gps_fixes_is_averaged_over_a_second(tmp_path: Path) -> None:
    """10 cm of GPS noise at 10 Hz and 8 m/s: a 0.2 s chord (1.6 m) turns the heading by
    several degrees at every fix; the 1 s chord keeps it within about one degree."""
    _, heading, result, table, _ = _noisy_arc(tmp_path, seed=3)
    world = result.info.world
    wf = frames.WorldFrame(world.origin_lat_deg, world.origin_lon_deg)  # type: ignore[arg-type]
    xyz = np.stack([table["x"], table["y"], table["z"]], -1)
    grid = wf.heading_to_crs(UTM10N, xyz[:, :2], table["heading"])
    err = np.degrees(np.abs(frames.angle_difference(grid[10:-10], heading[10:-10])))
    assert err.mean() < 1.5
    assert err.max() < 5.0


def test_noisy_gps_fixes_are_smoothed_and_the_import_says_so(tmp_path: Path) -> None:
    """The frames' positions and speeds come from the smoothed fixes, not the jittery ones."""
    xy, _, result, table, utm = _noisy_arc(tmp_path, seed=4)
    err = np.linalg.norm(utm[:, :2] - xy, axis=1)[5:-5]
    assert np.sqrt(np.mean(err**2)) < 0.07  # the fixes were 0.14 m off (0.1 per axis)
    assert np.abs(table["speed"][5:-5] - 8.0).max() < 0.5  # 0.2 s chords of the fixes: 1 m/s
    assert any("smoothed" in note for note in result.notes)


def test_a_gnss_heading_is_degrees_from_north_and_headers_may_carry_units(
    tmp_path: Path,
) -> None:
    """What a GNSS/INS logger writes: `Latitude (deg)`, `Heading [deg]` clockwise from north."""
    t, xy, heading = _arc(120)
    lat, lon = _to_wgs84(UTM10N, xy[:, 0], xy[:, 1])
    stamps = T0 + np.round(t * 1e9).astype(np.int64)
    compass = (90.0 - np.degrees(heading)) % 360.0
    rows = ["Time [s],Latitude (deg),Longitude (deg),Heading [deg]"]
    rows += [
        f"{s // 10**9}.{s % 10**9:09d},{a:.10f},{b:.10f},{c:.3f}"
        for s, a, b, c in zip(stamps.tolist(), lat, lon, compass, strict=True)
    ]
    (tmp_path / "ins.csv").write_text("\n".join(rows) + "\n")
    _images(tmp_path / "images", [f"{s}.png" for s in stamps])
    opts = ImportOptions(poses=tmp_path / "ins.csv")
    info = import_images(tmp_path / "ws", tmp_path / "images", options=opts).info
    assert not info.heading_from_motion  # the INS's heading is the orientation
    table = read_table(DatasetPaths(tmp_path / "ws" / "dataset").poses_csv)
    wf = frames.WorldFrame(info.world.origin_lat_deg, info.world.origin_lon_deg)  # type: ignore[arg-type]
    xyz = np.stack([table["x"], table["y"], table["z"]], -1)
    grid = wf.heading_to_crs(UTM10N, xyz[:, :2], table["heading"])
    assert np.degrees(np.abs(frames.angle_difference(grid, heading))).max() < 0.5
    # The same degrees under `yaw` (radians from east): headings that do not follow the
    # drive, which the import refuses, naming the conventions.
    (tmp_path / "bad.csv").write_text(
        "\n".join([rows[0].replace("Heading [deg]", "yaw"), *rows[1:]]) + "\n"
    )
    with pytest.raises(
        RecordingError,
        match=r"degrees from their own direction of travel.*"
        r"`heading` is read as degrees clockwise from north",
    ):
        import_images(
            tmp_path / "ws2", tmp_path / "images", options=ImportOptions(poses=tmp_path / "bad.csv")
        )


def test_gps_fixes_are_not_fitted_for_where_they_sit_on_the_car(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A heading taken from the fixes' own motion never slips in a turn, wherever the antenna
    is: ``--pose-offset fit`` says it cannot tell and takes the rear axle, and the scenario's
    check stays quiet about a pose point it could not measure."""
    from cam2sim.stages.scenario import check_pose_point

    t, xy, _ = _arc(120, turn=0.3)  # 8 m/s, a 27 m radius: a camera 1 m ahead slips 2 degrees
    lat, lon = _to_wgs84(UTM10N, xy[:, 0], xy[:, 1])
    stamps = T0 + np.round(t * 1e9).astype(np.int64)
    rows = ["timestamp,lat,lon"]
    rows += [f"{s / 1e9:.3f},{a:.10f},{b:.10f}" for s, a, b in zip(stamps, lat, lon, strict=True)]
    (tmp_path / "gps.csv").write_text("\n".join(rows) + "\n")
    _images(tmp_path / "images", [f"{s}.png" for s in stamps])
    opts = ImportOptions(poses=tmp_path / "gps.csv", pose_offset_m=(None, 0.0, 1.5))
    with caplog.at_level("WARNING", logger="cam2sim.stages.image_import"):
        result = import_images(tmp_path / "ws", tmp_path / "images", options=opts)
    assert result.pose_point is None
    assert "have no orientation" in caplog.text
    ws = Workspace.open(tmp_path / "ws")
    vehicle = ws.load_config().vehicle
    assert vehicle.reference_xyz() == pytest.approx((vehicle.rear_axle_x_m, 0.0, 1.5))
    caplog.clear()
    with caplog.at_level("WARNING", logger="cam2sim.stages.scenario"):
        assert check_pose_point(ws) is None
    assert not caplog.text


def _oxts_folder(root: Path, lat: np.ndarray, lon: np.ndarray, rpy: np.ndarray) -> Path:
    """KITTI raw's layout: oxts/data/0000000000.txt ... and oxts/timestamps.txt."""
    data = root / "oxts" / "data"
    data.mkdir(parents=True)
    for k, (a, b, (r, p, y)) in enumerate(zip(lat, lon, rpy, strict=True)):
        rest = " ".join(["0.1"] * 24)  # velocities, accelerations, accuracies, modes
        (data / f"{k:010d}.txt").write_text(f"{a:.12f} {b:.12f} 110.5 {r} {p} {y} {rest}\n")
    times = [f"2011-09-26 13:02:{25 + k * 0.1:012.9f}" for k in range(len(lat))]
    (root / "oxts" / "timestamps.txt").write_text("\n".join(times) + "\n")
    return root / "oxts"


def test_kitti_raw_oxts_gives_position_heading_pitch_and_roll(tmp_path: Path) -> None:
    t, xy, heading = _arc(30, speed=6.0)
    lat, lon = _to_wgs84(UTM10N, xy[:, 0], xy[:, 1])
    pitch, roll = 0.03, -0.02  # front down, left side down
    rpy = np.stack([np.full(len(t), roll), np.full(len(t), pitch), heading], -1)
    oxts = _oxts_folder(tmp_path, lat, lon, rpy)
    table = read_pose_file(oxts)
    assert table.kind == "kitti oxts"
    assert table.geographic
    assert table.by_index
    np.testing.assert_array_equal(table.stamp_ns, np.arange(30) * 100_000_000)
    assert table.quat is not None
    forward = frames.quat_rotate(table.quat, [1.0, 0.0, 0.0])
    left = frames.quat_rotate(table.quat, [0.0, 1.0, 0.0])
    np.testing.assert_allclose(np.arctan2(forward[:, 1], forward[:, 0]), heading, atol=1e-9)
    np.testing.assert_allclose(forward[:, 2], -math.sin(pitch), atol=1e-9)  # front down
    np.testing.assert_allclose(left[:, 2], math.sin(roll) * math.cos(pitch), atol=1e-9)

    _images(tmp_path / "image_00" / "data", [f"{k:010d}.png" for k in range(30)])
    opts = ImportOptions(poses=oxts, fps=10.0)
    info = import_images(tmp_path / "ws", tmp_path / "image_00" / "data", options=opts).info
    assert info.world.georeferenced
    assert info.counts.frames == 30
    poses = read_table(DatasetPaths(tmp_path / "ws" / "dataset").poses_csv)
    wf = frames.WorldFrame(info.world.origin_lat_deg, info.world.origin_lon_deg)  # type: ignore[arg-type]
    xyz = np.stack([poses["x"], poses["y"], poses["z"]], -1)
    assert np.abs(wf.to_crs(UTM10N, xyz)[:, :2] - xy).max() < 1e-3
    # OXTS yaw is east-north-up: the world frame's axes (its origin is the first fix), not
    # UTM's grid (0.35 degrees of meridian convergence away here).
    assert np.abs(frames.angle_difference(poses["heading"], heading)).max() < 1e-6


def test_bad_gps_inputs_say_what_to_fix(tmp_path: Path) -> None:
    _images(tmp_path / "images", ["0.png", "1.png"])
    gps = tmp_path / "gps.csv"
    gps.write_text("t,lat,lon\n0.0,37.7,-122.4\n0.1,37.70001,-122.4\n")
    with pytest.raises(RecordingError, match=r"GPS fixes .* not EPSG:32610; drop --crs"):
        import_images(
            tmp_path / "ws", tmp_path / "images", options=ImportOptions(poses=gps, crs=UTM10N)
        )
    gps.write_text("t,lat,lon\n0.0,122.4,37.7\n0.1,122.4,37.70001\n")  # swapped
    with pytest.raises(RecordingError, match=r"latitudes must lie within \+-90"):
        read_pose_file(gps)
    empty = tmp_path / "oxts"
    empty.mkdir()
    with pytest.raises(RecordingError, match=r"folder without OXTS files.*oxts/ folder"):
        read_pose_file(empty)
    (empty / "0000000000.txt").write_text("37.7 -122.4 10\n")
    with pytest.raises(RecordingError, match=r"0000000000.txt: 3 numbers; an OXTS record"):
        read_pose_file(empty)


def test_a_real_gps_drive_without_osm_gets_a_geo_referenced_road_and_a_scenario(
    tmp_path: Path, shared_data: Path
) -> None:
    """comma2k19's minute in San Francisco as GPS fixes (no orientation, no OSM offline): the
    import places it on the Earth, the map is the driven road, geo-referenced, and the steering
    derived from the fixes follows the car's measured steering."""
    pytest.importorskip("carla", reason="the scenario's checks need carla (cam2sim[map])")
    from cam2sim.stages.ads import derive_steering
    from cam2sim.stages.map import MapOptions, build_map
    from cam2sim.stages.scenario import run_scenario

    comma = shared_data / "poses" / "comma2k19"
    ecef = np.load(comma / "global_pose_frame_positions")[::4]  # 5 Hz
    times = np.load(comma / "global_pose_frame_times")[::4]
    to_geo = pyproj.Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
    lon, lat, alt = to_geo.transform(ecef[:, 0], ecef[:, 1], ecef[:, 2])
    stamps = T0 + np.round((times - times[0]) * 1e9).astype(np.int64)
    info = _import_gps(tmp_path, stamps, np.asarray(lat), np.asarray(lon), np.asarray(alt)).info
    assert info.world.georeferenced
    assert info.counts.frames == 300
    ws = Workspace.open(tmp_path / "ws")
    trajectory = read_table(DatasetPaths(ws.dataset_dir).trajectory_csv)
    length = np.hypot(np.diff(trajectory["x"]), np.diff(trajectory["y"])).sum()
    assert length == pytest.approx(1_011.0, rel=0.01)  # as the ECEF track measures it
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "the road follows the driven path"
        report = build_map(ws, options=MapOptions(road="trajectory")).report
    assert report.source.kind == "trajectory"
    assert report.georeferenced
    assert report.route.covered_fraction == pytest.approx(1.0)
    scenario = run_scenario(ws).scenario
    assert scenario is not None
    assert scenario.world.proj_string == info.world.proj_string

    signal = read_table(DatasetPaths(ws.dataset_dir).signal_file(derive_steering(ws)))
    can_t = np.load(comma / "processed_log_CAN_steering_angle_t")
    can = np.load(comma / "processed_log_CAN_steering_angle_value")
    at = (signal["stamp_ns"] - T0) / 1e9 + times[0]
    measured = np.interp(at, can_t, can)
    # A drive that never turns the wheel more than 5 degrees: GPS noise is a large part of the
    # derived curvature (0.81 here with the 3 m window of headings from motion, 0.80 with 1 m,
    # 0.64 with a 0.2 s heading window; 0.996 on the reference drives' turns).
    assert np.corrcoef(measured, signal["value"])[0, 1] > 0.75


def _kitti_raw_calibration(folder: Path) -> Path:
    """KITTI raw's three files: the Velodyne 0.81 m ahead of, 0.32 m right of and 0.80 m above
    the GPS/IMU; camera 00 0.27 m ahead of and 0.08 m below the Velodyne; camera 01 0.54 m to
    the right of camera 00 (rectified; tiny 16x12 images)."""
    folder.mkdir(parents=True)

    def line(key: str, values: list[float]) -> str:
        return f"{key}: " + " ".join(f"{v:.6e}" for v in values)

    p0 = [20.0, 0.0, 8.0, 0.0, 0.0, 20.0, 6.0, 0.0, 0.0, 0.0, 1.0, 0.0]
    p1 = [*p0[:3], -20.0 * 0.54, *p0[4:]]
    cams = [
        "calib_time: 09-Jan-2012 13:57:47",
        line("S_rect_00", [16, 12]),
        line("R_rect_00", [1, 0, 0, 0, 1, 0, 0, 0, 1]),
        line("P_rect_00", p0),
        line("S_rect_01", [16, 12]),
        line("P_rect_01", p1),
    ]
    (folder / "calib_cam_to_cam.txt").write_text("\n".join(cams) + "\n")
    velo = ["calib_time: 15-Mar-2012 11:37:16", line("R", [0, -1, 0, 0, 0, -1, 1, 0, 0])]
    velo.append(line("T", [0.0, -0.08, -0.27]))
    (folder / "calib_velo_to_cam.txt").write_text("\n".join(velo) + "\n")
    imu = [line("R", [1, 0, 0, 0, 1, 0, 0, 0, 1]), line("T", [-0.81, 0.32, -0.80])]
    (folder / "calib_imu_to_velo.txt").write_text("\n".join(imu) + "\n")
    return folder


def test_kitti_raw_calibration_places_each_camera_on_the_gps_imu(tmp_path: Path) -> None:
    from cam2sim.core.dataset import Calibration
    from cam2sim.recording.kitti_calibration import read_kitti_raw_calibration

    calib = _kitti_raw_calibration(tmp_path / "2011_09_26")
    left = read_kitti_raw_calibration(calib, "00")
    np.testing.assert_allclose(left.T_imu_cam[:3, 3], [1.08, -0.32, 0.72], atol=1e-9)
    np.testing.assert_allclose(left.T_imu_cam[:3, 2], [1.0, 0.0, 0.0], atol=1e-9)  # looks ahead
    np.testing.assert_allclose(left.T_imu_cam[:3, 0], [0.0, -1.0, 0.0], atol=1e-9)  # x right
    right = read_kitti_raw_calibration(calib, "01")
    np.testing.assert_allclose(right.T_imu_cam[:3, 3], [1.08, -0.86, 0.72], atol=1e-9)
    assert (right.width, right.height) == (16, 12)
    assert right.K[0, 0] == 20.0

    _, xy, heading = _arc(10)
    lat, lon = _to_wgs84(UTM10N, xy[:, 0], xy[:, 1])
    rpy = np.stack([np.zeros(10), np.zeros(10), heading], -1)
    drive = tmp_path / "2011_09_26" / "2011_09_26_drive_0001_sync"
    oxts = _oxts_folder(drive, lat, lon, rpy)
    images = drive / "image_01" / "data"
    _images(images, [f"{k:010d}.png" for k in range(10)])
    opts = ImportOptions(poses=oxts, calibration=calib, fps=10.0, pose_offset_m=(0.0, 0.0, 0.93))
    import_images(tmp_path / "ws", images, options=opts)
    saved = Calibration.load(DatasetPaths(tmp_path / "ws" / "dataset").calibration_json)
    assert saved.camera is not None
    assert "rectified camera 01" in saved.camera.source
    np.testing.assert_allclose(saved.camera_mount.translation_m, [1.08, -0.86, 0.72], atol=1e-9)
    assert saved.camera_mount.axes == "optical"

    (tmp_path / "empty").mkdir()
    with pytest.raises(RecordingError, match=r"folder without KITTI raw's calib_cam_to_cam.txt"):
        import_images(
            tmp_path / "ws2", images, options=ImportOptions(calibration=tmp_path / "empty")
        )
    (calib / "calib_cam_to_cam.txt").write_text("P_rect_00: 1 2 3\n")
    with pytest.raises(RecordingError, match=r"calib_cam_to_cam.txt: P_rect_00 must be 12"):
        read_kitti_raw_calibration(calib, "00")


def test_pose_times_may_be_iso_dates(tmp_path: Path) -> None:
    """GPS logs often write times as dates: without a zone they are UTC, every digit kept."""
    csv = tmp_path / "gps.csv"
    csv.write_text(
        "time,lat,lon\n"
        "2011-09-26 13:02:25.964389445,49.0,8.4\n"
        "2011-09-26T13:02:26.064389445Z,49.00001,8.4\n"
        "2011-09-26T15:02:26.164389445+02:00,49.00002,8.4\n"
    )
    table = read_pose_file(csv)
    start = 1_317_042_145_964_389_445  # 2011-09-26 13:02:25.964389445 UTC
    np.testing.assert_array_equal(table.stamp_ns, start + np.arange(3) * 100_000_000)
    assert table.quat is None
